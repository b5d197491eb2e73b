"""Shutting the console's server down while a page follows a run (``console.server.ConsoleServer``,
as Ctrl-C on ``imgnav console``): the run is stopped while the page still hears of it, then the
page's status stream ends, and the server stops (uvicorn waits for open responses before the app's
own shutdown, and a status stream never ends by itself)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

from console.context import Console, ConsoleConfig
from console.store import RunStore
from tests.helpers.console_live import LiveServer, poll
from tests.helpers.console_testkit import ScriptedProvider, encode, textured_rgb


class StatusStream:
    """A page's status stream (``/api/events``), read on a thread: its events, and whether it ended."""

    def __init__(self, url: str) -> None:
        import httpx

        self.events: list[dict] = []
        self.ended = threading.Event()
        self._opened = threading.Event()

        def read() -> None:
            try:
                with httpx.stream("GET", f"{url}/api/events", timeout=httpx.Timeout(5.0, read=None)) as resp:
                    assert resp.status_code == 200, resp.status_code
                    self._opened.set()
                    for line in resp.iter_lines():
                        if line.startswith("data: "):
                            self.events.append(json.loads(line[len("data: ") :]))
            finally:
                self.ended.set()

        self.thread = threading.Thread(target=read, name="status-stream", daemon=True)
        self.thread.start()
        assert self._opened.wait(30), "the status stream did not open"

    def statuses(self, run_id: str) -> list[str]:
        return [e["status"] for e in list(self.events) if e.get("run_id") == run_id and e["kind"] == "status"]


def test_shutdown_stops_the_run_tells_the_page_and_ends_its_stream(tmp_path: Path) -> None:
    import httpx

    provider = ScriptedProvider(stop_after=1000, step_s=0.05)  # a run that only a stop ends soon
    data = tmp_path / "data"
    server = LiveServer(Console(ConsoleConfig(data_dir=data, viewer=None), {"scripted": provider}))
    closed = False
    try:
        stream = StatusStream(server.url)
        resp = httpx.post(
            f"{server.url}/api/runs",
            files={"goal_image": ("goal.png", encode(textured_rgb(), "PNG"), "image/png")},
            data={"backend": "scripted"},
        )
        assert resp.status_code == 201, resp.text
        run_id = resp.json()["id"]
        # the page follows the run's steps
        poll(lambda: [e for e in list(stream.events) if e["kind"] == "step"], bool, 30, "a step on the stream")

        server.close()  # as Ctrl-C: asserts that the server stopped, with the page still connected
        closed = True
        assert stream.ended.wait(30), "the page's status stream is still open"
        # the run was stopped (its backend closed: the robot stopped), and the page was told so
        assert provider.sessions[0].backend.closed
        statuses = stream.statuses(run_id)
        assert statuses[-2:] == ["stopping", "stopped"], statuses
        store = RunStore(data / "console.sqlite3")
        try:
            row = store.get_run(run_id)
        finally:
            store.close()
        assert row is not None and row["status"] == "stopped", row
    finally:
        if not closed:
            server.close()
