"""The status event hub: thread-safe publish, per-run subscription, latest-state replay."""

from __future__ import annotations

import asyncio
import json
import threading

from console.events import EventHub


def test_events_reach_subscribers_from_another_thread() -> None:
    hub = EventHub()

    async def main() -> list[dict]:
        got: list[dict] = []
        stream = hub.subscribe("r1")
        assert (await stream.__anext__()).startswith("retry:")

        def produce() -> None:
            hub.publish("step", "r2", {"step": 99})  # another run: filtered out
            for i in range(3):
                hub.publish("step", "r1", {"step": i})

        while hub.n_subscribers == 0:
            await asyncio.sleep(0)
        threading.Thread(target=produce).start()
        while len(got) < 3:
            text = await asyncio.wait_for(stream.__anext__(), 10)
            data = text.split("data: ", 1)[1]
            got.append(json.loads(data))
        await stream.aclose()
        return got

    got = asyncio.run(main())
    assert [g["step"] for g in got] == [0, 1, 2]
    assert hub.n_subscribers == 0


def test_late_subscriber_gets_the_latest_state_first() -> None:
    hub = EventHub()
    hub.publish("status", "r1", {"status": "running"})
    hub.publish("step", "r1", {"step": 4})

    async def main() -> str:
        stream = hub.subscribe("r1")
        await stream.__anext__()
        first = await stream.__anext__()
        await stream.aclose()
        return first

    assert '"step": 4' in asyncio.run(main())
