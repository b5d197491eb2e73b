"""Console benchmarks (issue 4), with the real simulator and the real Mod-IIN agent.

1. upload -> first action: POST /api/runs with a goal photo until the robot's first
   action has been applied (server-side clock: request received -> first ``apply``
   returned), and the client-side time until the first step event arrives on the status
   stream. Broken down into backend+agent construction and reset.
2. viewer publishing cost per step: ``Viewer.publish`` on records of a real run, without
   and with the map; and ``Viewer.offer`` (all the control loop pays).
3. status-stream latency with 20 concurrent SSE clients: publish -> receipt, per event.
4. replay: what a run stores per step (JPEG thumbnail, per-step JSON, map snapshots every
   10 steps), extrapolated to a 1000-step run; the time to open a replay (timeline + first
   step + its picture + its map, as the page does) and to move to another step.
5. calibration from photos: simulator goal images standing in for the operator's photos
   (3 objects x 3 views), every pair scored with the deployment's matcher.

The simulator home stays built between runs (``sim_adapter.WorldCache``), so "warm" runs
pay only the backend and agent construction; the warm-up before the first run is timed.

Prints medians (and p90) over several repetitions. Usage:

    .venv/bin/python benchmarks/bench_console.py [--runs 5] [--clients 20]
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import logging
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from console.api import create_app  # noqa: E402
from console.context import Console, ConsoleConfig  # noqa: E402
from console.options import RunForm  # noqa: E402
from console.session import StepRecord  # noqa: E402
from console.sim_provider import SimProvider, SimProviderConfig  # noqa: E402
from console.viewer import Viewer, ViewerConfig  # noqa: E402

log = logging.getLogger("bench_console")


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def line(name: str, values: list[float], unit: str) -> str:
    return f"{name:<48} median {statistics.median(values):9.2f} {unit}   p90 {pct(values, 90):9.2f} {unit}   (n={len(values)})"


class Capture:
    """A viewer sink that keeps the records (to replay them into the real viewer)."""

    def __init__(self) -> None:
        self.records: list[StepRecord] = []

    def run_started(self, run_id, goal_rgb, info) -> None:
        pass

    def offer(self, rec: StepRecord) -> None:
        self.records.append(rec)

    def run_ended(self, run_id, status, outcome) -> None:
        pass


class Server:
    def __init__(self, console: Console) -> None:
        import uvicorn

        self.console = console
        self.server = uvicorn.Server(uvicorn.Config(create_app(console), host="127.0.0.1", port=0, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        while not self.server.started:
            time.sleep(0.01)
        self.url = f"http://127.0.0.1:{self.server.servers[0].sockets[0].getsockname()[1]}"

    def close(self) -> None:
        self.server.should_exit = True
        self.thread.join(30)
        self.console.close()


def wait_final(client, run_id: str, timeout_s: float = 300.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        row = client.get(f"/api/runs/{run_id}").json()
        if row["status"] in ("finished", "stopped", "failed"):
            return row
        time.sleep(0.02)
    raise TimeoutError(run_id)


def bench_first_action(server: Server, runs: int) -> None:
    import httpx

    client = httpx.Client(base_url=server.url, timeout=60)
    home = client.get("/api/backends/sim").json()["homes"][0]
    png = client.get(home["gallery"][0]["url"]).content
    server_s, client_s, open_s, reset_s = [], [], [], []
    for k in range(runs + 1):  # the first run loads the matcher weights: reported apart
        got_step = threading.Event()
        first_step_at: list[float] = []

        def listen(run_id: str) -> None:
            with httpx.stream("GET", f"{server.url}/api/runs/{run_id}/events", timeout=120) as resp:
                for raw in resp.iter_lines():
                    if raw.startswith("event: step"):
                        first_step_at.append(time.perf_counter())
                        got_step.set()
                        return

        t0 = time.perf_counter()
        resp = client.post("/api/runs", files={"goal_image": ("g.png", png, "image/png")}, data={"max_steps": "3"})
        resp.raise_for_status()
        run_id = resp.json()["id"]
        listener = threading.Thread(target=listen, args=(run_id,), daemon=True)
        listener.start()
        row = wait_final(client, run_id)
        listener.join(10)
        t = row["timings"]
        if k == 0:
            print(f"  cold first run (matcher weights load): upload->first action {t['upload_to_first_action_s'] * 1000:.0f} ms")
            continue
        server_s.append(1000 * t["upload_to_first_action_s"])
        open_s.append(1000 * t["open_s"])
        reset_s.append(1000 * t["reset_s"])
        if first_step_at:
            client_s.append(1000 * (first_step_at[0] - t0))
    print(line("upload -> first action applied (server)", server_s, "ms"))
    if client_s:
        print(line("upload -> first step event at client", client_s, "ms"))
    print(line("  of which: backend + agent (home kept built)", open_s, "ms"))
    print(line("  of which: backend.reset + agent.reset", reset_s, "ms"))
    rest = [s - o - r for s, o, r in zip(server_s, open_s, reset_s)]
    print(line("  of which: request, photo, first agent step", rest, "ms"))


def bench_viewer(data_dir: Path, steps: int) -> None:
    capture = Capture()
    provider = SimProvider(data_dir, SimProviderConfig(home_seeds=(0,)))
    console = Console(ConsoleConfig(data_dir=data_dir, viewer=None), {"sim": provider})
    console.manager.viewer = capture
    try:
        from console.photos import decode_photo

        home = provider.describe()["homes"][0]
        g = home["gallery"][0]
        png = (data_dir / "sim" / home["id"] / g["url"].rsplit("/", 1)[1]).read_bytes()
        photo = decode_photo(png)
        resolved = provider.resolve(RunForm(start="r0", max_steps=steps), photo.dhash, photo.sha256)
        run_id = console.manager.start(resolved, photo, png, time.time())
        console.manager.wait(run_id, 600)
    finally:
        console.close()
    recs = capture.records
    viewer = Viewer(ViewerConfig(port=0))
    try:
        viewer.run_started(recs[0].run_id, recs[0].goal_rgb, {"backend": "sim"})
        no_map, with_map, offer = [], [], []
        for rec in recs:
            t0 = time.perf_counter()
            viewer.publish(rec, with_map=False)
            no_map.append(1000 * (time.perf_counter() - t0))
        for rec in recs:
            t0 = time.perf_counter()
            viewer.publish(rec, with_map=True)
            with_map.append(1000 * (time.perf_counter() - t0))
        for rec in recs:
            t0 = time.perf_counter()
            viewer.offer(rec)
            offer.append(1e6 * (time.perf_counter() - t0))
        snap = next((r.record.map for r in reversed(recs) if r.record is not None and r.record.map is not None), None)
        shape = None if snap is None else snap.explored.shape
    finally:
        viewer.close()
    print(f"  {len(recs)} steps of a real run; final map {shape} cells")
    print(line("viewer publish, pose + images (up to 10 Hz)", no_map, "ms"))
    print(line("viewer publish, pose + images + map (1-2 Hz)", with_map, "ms"))
    print(line("viewer offer (what the control loop pays)", offer, "us"))


def bench_replay(data_dir: Path, steps: int, opens: int) -> None:
    """Storage per step of a real run, and opening its replay through the API."""
    from fastapi.testclient import TestClient

    from console.photos import decode_photo

    provider = SimProvider(data_dir, SimProviderConfig(home_seeds=(0,)))
    console = Console(ConsoleConfig(data_dir=data_dir, viewer=None, allowed_hosts=("testserver",)), {"sim": provider})
    try:
        home = provider.describe()["homes"][0]
        g = home["gallery"][0]
        png = (data_dir / "sim" / home["id"] / g["url"].rsplit("/", 1)[1]).read_bytes()
        photo = decode_photo(png)
        resolved = provider.resolve(RunForm(start=g.get("default_start") or "r0", max_steps=steps), photo.dhash, photo.sha256)
        run_id = console.manager.start(resolved, photo, png, time.time())
        console.manager.wait(run_id, 3600)
        sizes = console.store.replay_bytes(run_id)
        n = sizes["steps"]
        per_step = {k: sizes[k] / n for k in ("frames", "extras")}
        maps_per_snapshot = sizes["maps"] / max(sizes["n_maps"], 1)
        # a 1000-step run: 1000 frames and JSONs, 100 cadence maps + first detection + last
        per_1000 = 1000 * (per_step["frames"] + per_step["extras"]) + 102 * maps_per_snapshot
        print(f"  {n} steps stored: frames {sizes['frames'] / 1e3:.0f} kB, per-step JSON {sizes['extras'] / 1e3:.0f} kB, "
              f"{sizes['n_maps']} maps {sizes['maps'] / 1e3:.0f} kB")
        print(f"  per step: thumbnail {per_step['frames'] / 1e3:.1f} kB, JSON {per_step['extras'] / 1e3:.2f} kB; "
              f"per map snapshot {maps_per_snapshot / 1e3:.1f} kB")
        print(f"  replay storage per 1000 steps (extrapolated): {per_1000 / 1e6:.1f} MB")
        client = TestClient(create_app(console, close_on_shutdown=False))
        open_ms, move_ms = [], []
        for k in range(opens):
            t0 = time.perf_counter()
            index = client.get(f"/api/runs/{run_id}/replay").json()
            first = client.get(f"/api/runs/{run_id}/replay/0").json()
            client.get(first["frame_url"]).raise_for_status()
            client.get(first["map_url"]).raise_for_status()
            open_ms.append(1000 * (time.perf_counter() - t0))
            step = (k * 7 + 5) % len(index["steps"])
            t0 = time.perf_counter()
            s = client.get(f"/api/runs/{run_id}/replay/{step}").json()
            client.get(s["frame_url"]).raise_for_status()
            client.get(s["map_url"]).raise_for_status()
            move_ms.append(1000 * (time.perf_counter() - t0))
        print(line(f"open a replay ({n} steps: timeline, step, picture, map)", open_ms, "ms"))
        print(line("move to another step (step, picture, map)", move_ms, "ms"))
    finally:
        console.close()


def bench_calibration(data_dir: Path, objects: int, views: int) -> None:
    from PIL import Image

    from console.calibration import Calibrator, LabelledPhoto
    from console.photos import decode_photo
    from console.sim_adapter import _world
    from sim.goals import sample_goal_images

    world = _world(0, 3)
    photos = []
    try:
        for inst in world.home.instances:
            images = sample_goal_images(world, inst.object_id, views, (0, inst.object_id, 7))
            if len(images) < views:
                continue
            for goal in images:
                buf = io.BytesIO()
                Image.fromarray(goal.rgb).save(buf, format="JPEG", quality=90)
                photos.append(LabelledPhoto(f"{inst.category} {inst.object_id}", "x.jpg", decode_photo(buf.getvalue())))
            if len({p.object_label for p in photos}) == objects:
                break
    finally:
        world.close()
    calibrator = Calibrator(data_dir)
    job = calibrator.start("stretch", photos)
    calibrator.wait(3600)
    r = job.result
    n_pairs = r["same_pairs"] + r["different_pairs"]
    print(f"  {len(photos)} photos of {objects} objects, {n_pairs} pairs: {job.seconds:.1f} s "
          f"(extract {r['extract_ms_per_photo']:.0f} ms per photo, match {r['match_ms_per_pair']:.0f} ms per pair); "
          f"proposed tau {r['proposal']['tau']:.1f}, max F {r['proposal']['max_f']:.2f}")


def bench_stream(server: Server, n_clients: int, n_events: int) -> None:
    import httpx

    latencies: list[float] = []

    async def client_task(k: int) -> None:
        async with httpx.AsyncClient(timeout=60) as client:
            async with client.stream("GET", f"{server.url}/api/events") as resp:
                async for raw in resp.aiter_lines():
                    if raw.startswith("data: "):
                        now = time.time()
                        data = json.loads(raw[6:])
                        if data.get("kind") == "log" and data.get("bench"):
                            if data.get("last"):
                                return
                            latencies.append(1000 * (now - data["t_s"]))

    async def clients() -> None:
        await asyncio.gather(*(client_task(k) for k in range(n_clients)))

    thread = threading.Thread(target=lambda: asyncio.run(clients()), daemon=True)
    thread.start()
    while server.console.hub.n_subscribers < n_clients:  # every client is subscribed
        time.sleep(0.01)
    for i in range(n_events):  # at the step rate of a fast run (20 Hz)
        server.console.hub.publish("log", None, {"message": f"bench {i}", "bench": True, "t_s": time.time()})
        time.sleep(0.05)
    server.console.hub.publish("log", None, {"message": "bench done", "bench": True, "last": True, "t_s": time.time()})
    thread.join(60)
    print(f"  {n_clients} clients x {n_events} events")
    print(line(f"status stream latency, {n_clients} concurrent clients", latencies, "ms"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5, help="repetitions of the upload benchmark")
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--events", type=int, default=100)
    parser.add_argument("--viewer-steps", type=int, default=40)
    parser.add_argument("--replay-steps", type=int, default=100, help="length of the run whose replay is measured")
    parser.add_argument("--replay-opens", type=int, default=5)
    parser.add_argument("--calibration-objects", type=int, default=3)
    parser.add_argument("--calibration-views", type=int, default=3)
    parser.add_argument("--only", nargs="*", default=None, help="run only these parts: first_action stream viewer replay calibration")
    args = parser.parse_args()
    want = (lambda part: args.only is None or part in args.only)
    logging.basicConfig(level=logging.WARNING)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        t0 = time.perf_counter()
        provider = SimProvider(data, SimProviderConfig(home_seeds=(0,)))
        provider.prepare()
        print(f"prepared simulator home and gallery in {time.perf_counter() - t0:.1f} s")
        if want("first_action") or want("stream"):
            sim = SimProvider(data, SimProviderConfig(home_seeds=(0,)))
            server = Server(Console(ConsoleConfig(data_dir=data, viewer=None), {"sim": sim}))
            try:
                if want("first_action"):
                    print("1. upload -> first action")
                    print(f"  warm-up before the first run: home built in {sim.warm_up():.2f} s")
                    bench_first_action(server, args.runs)
                if want("stream"):
                    print("3. status stream")
                    bench_stream(server, args.clients, args.events)
            finally:
                server.close()
        if want("viewer"):
            print("2. viewer publishing")
            bench_viewer(data, args.viewer_steps)
        if want("replay"):
            print("4. replay")
            bench_replay(data, args.replay_steps, args.replay_opens)
        if want("calibration"):
            print("5. calibration from photos")
            bench_calibration(data, args.calibration_objects, args.calibration_views)
    return 0


if __name__ == "__main__":
    sys.exit(main())
