"""Console benchmarks (issue 4), with the real simulator and the real Mod-IIN agent.

1. upload -> first action: POST /api/runs with a goal photo until the robot's first
   action has been applied (server-side clock: request received -> first ``apply``
   returned), and the client-side time until the first step event arrives on the status
   stream. Broken down into consecutive parts that add up to it (``FIRST_ACTION_PARTS``:
   request, photo, run record, backend and agent construction, resets, first act and apply),
   for the same start each run and for random starts (whose first frame is rendered).
2. viewer publishing cost per step: ``Viewer.publish`` on records of a real run, without
   and with the map; and ``Viewer.offer`` (all the control loop pays).
3. status-stream latency with 20 concurrent SSE clients: publish -> receipt, per event.
4. replay: what a run stores per step (JPEG thumbnail, per-step JSON, map snapshots every
   10 steps), extrapolated to a 1000-step run; the time to open a replay (timeline + first
   step + its picture + its map, as the page does) and to move to another step.
5. calibration from photos: simulator goal images standing in for the operator's photos
   (3 objects x 3 views), every pair scored with the deployment's matcher.

The simulator home stays built between runs (``console.sim_cache.WorldCache``), with its
start frames and the scoring data of its targets, so "warm" runs pay only the backend and
agent construction; the warm-up before the first run is timed. torch's OpenMP threads wait
passively, as in ``imgnav console`` (``console.agents.passive_openmp_wait``; an explicit
``OMP_WAIT_POLICY`` in the environment wins).

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

from console.agents import passive_openmp_wait  # noqa: E402
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


# The server-side parts of upload -> first action, in order; they add up to the total
# (run timings written by console.manager; "other" is what none of them covers).
FIRST_ACTION_PARTS = (
    ("request: HTTP, upload, form", None),
    ("photo decode (EXIF, hashes)", "decode_s"),
    ("options and target (resolve)", "resolve_s"),
    ("run record: upload's file, SQLite row", "record_s"),
    ("run status row and event", "prepare_s"),
    ("backend construction (home kept built)", "open_backend_s"),
    ("agent construction", "open_agent_s"),
    ("agent config row, viewer", "setup_s"),
    ("backend.reset: the first frame", "reset_backend_s"),
    ("agent.reset: goal features, new map", "reset_agent_s"),
    ("first agent.act", "first_act_s"),
    ("first backend.apply", "first_apply_s"),
)


def first_action_parts(t: dict) -> dict[str, float]:
    """A run's upload -> first action in ms, by part (``FIRST_ACTION_PARTS``), plus "other"."""
    ms = {key: 1000.0 * float(t.get(key) or 0.0) for _, key in FIRST_ACTION_PARTS if key}
    out = {}
    for label, key in FIRST_ACTION_PARTS:
        if key is None:  # what the request spent beyond the parts it timed (incl. the worker's start)
            out[label] = 1000.0 * t["request_s"] - ms["decode_s"] - ms["resolve_s"] - ms["record_s"]
        else:
            out[label] = ms[key]
    out["other (between the parts)"] = 1000.0 * t["upload_to_first_action_s"] - sum(out.values())
    return out


def first_action_client(url: str, starts: list[str | None]) -> list[tuple[dict, list[dict], float | None]]:
    """Upload the first gallery photo once per entry of ``starts``, one run after the other,
    and return each run's server timings, steps and the client-side time to its first step
    event. Runs in a process of its own (``bench_first_action``), as a phone would: an HTTP
    client in the console's process (a new httpx client per stream loads its CA bundle;
    polling every 20 ms) took the GIL and cores from the run it measured."""
    import httpx

    out = []
    with httpx.Client(base_url=url, timeout=120) as client:
        home = client.get("/api/backends/sim").json()["homes"][0]
        png = client.get(home["gallery"][0]["url"]).content
        for start in starts:
            t0 = time.perf_counter()
            data = {"max_steps": "3", **({"start": start} if start else {})}
            resp = client.post("/api/runs", files={"goal_image": ("g.png", png, "image/png")}, data=data)
            resp.raise_for_status()
            run_id = resp.json()["id"]
            first_step_ms, kind = None, ""
            with client.stream("GET", f"/api/runs/{run_id}/events") as stream:  # to the run's final status
                for raw in stream.iter_lines():
                    if raw.startswith("event: "):
                        kind = raw[7:]
                        if kind == "step" and first_step_ms is None:
                            first_step_ms = 1000 * (time.perf_counter() - t0)
                    elif raw.startswith("data: ") and kind == "status":
                        if json.loads(raw[6:]).get("status") in ("finished", "stopped", "failed"):
                            break
            row = wait_final(client, run_id)  # the final row is written just before its event
            steps = client.get(f"/api/runs/{run_id}?steps=true").json().get("steps") or []
            out.append((row["timings"], steps, first_step_ms))
    return out


def bench_first_action(server: Server, runs: int, fresh_runs: int) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        # the first run loads the matcher weights: reported apart
        results = pool.submit(first_action_client, server.url, [None] * (runs + 1) + ["random"] * fresh_runs).result()
    print(
        f"  cold first run (matcher weights load): upload->first action {results[0][0]['upload_to_first_action_s'] * 1000:.0f} ms"
    )
    print("  warm: the same photo and start each run (start frame and scoring data kept from the run before)")
    report_first_action(results[1 : runs + 1])
    if fresh_runs:
        print("  warm, start 'random' (a new heading each run: its first frame is rendered, not kept)")
        report_first_action(results[runs + 1 :])


def report_first_action(results: list[tuple[dict, list[dict], float | None]]) -> None:
    totals = [1000 * t["upload_to_first_action_s"] for t, _, _ in results]
    print(line("upload -> first action applied (server)", totals, "ms"))
    client_ms = [c for _, _, c in results if c is not None]
    if client_ms:
        print(line("upload -> first step event at client", client_ms, "ms"))
    parts = [first_action_parts(t) for t, _, _ in results]
    mid = sorted(range(len(totals)), key=totals.__getitem__)[len(totals) // 2]  # the median run (odd n)
    print(f"  {'part':<46} {'median':>8} {'median run':>11}")
    for label in parts[0]:
        print(f"  {label:<46} {statistics.median(p[label] for p in parts):8.1f} {parts[mid][label]:11.1f} ms")
    print(f"  {'sum (the median run: its total)':<46} {'':>8} {sum(parts[mid].values()):11.1f} ms")
    # the first act by the agent's own parts (its record's timings, ms)
    first = [steps[0]["timings"] for _, steps, _ in results if steps]
    if first:
        keys = [k for k in first[0] if k not in ("step_ms", "total")]
        print(
            "  first act by agent part (median): "
            + ", ".join(f"{k} {statistics.median(float(f.get(k) or 0.0) for f in first):.0f}" for k in keys)
            + " ms"
        )


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
        resolved = provider.resolve(
            RunForm(start=g.get("default_start") or "r0", max_steps=steps), photo.dhash, photo.sha256
        )
        run_id = console.manager.start(resolved, photo, png, time.time())
        console.manager.wait(run_id, 3600)
        sizes = console.store.replay_bytes(run_id)
        n = sizes["steps"]
        per_step = {k: sizes[k] / n for k in ("frames", "extras")}
        maps_per_snapshot = sizes["maps"] / max(sizes["n_maps"], 1)
        # a 1000-step run: 1000 frames and JSONs, 100 cadence maps + first detection + last
        per_1000 = 1000 * (per_step["frames"] + per_step["extras"]) + 102 * maps_per_snapshot
        print(
            f"  {n} steps stored: frames {sizes['frames'] / 1e3:.0f} kB, per-step JSON {sizes['extras'] / 1e3:.0f} kB, "
            f"{sizes['n_maps']} maps {sizes['maps'] / 1e3:.0f} kB"
        )
        print(
            f"  per step: thumbnail {per_step['frames'] / 1e3:.1f} kB, JSON {per_step['extras'] / 1e3:.2f} kB; "
            f"per map snapshot {maps_per_snapshot / 1e3:.1f} kB"
        )
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
    print(
        f"  {len(photos)} photos of {objects} objects, {n_pairs} pairs: {job.seconds:.1f} s "
        f"(extract {r['extract_ms_per_photo']:.0f} ms per photo, match {r['match_ms_per_pair']:.0f} ms per pair); "
        f"proposed tau {r['proposal']['tau']:.1f}, max F {r['proposal']['max_f']:.2f}"
    )


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
    parser.add_argument(
        "--fresh-runs", type=int, default=3, help="upload repetitions from a random start (start frame rendered)"
    )
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--events", type=int, default=100)
    parser.add_argument("--viewer-steps", type=int, default=40)
    parser.add_argument("--replay-steps", type=int, default=100, help="length of the run whose replay is measured")
    parser.add_argument("--replay-opens", type=int, default=5)
    parser.add_argument("--calibration-objects", type=int, default=3)
    parser.add_argument("--calibration-views", type=int, default=3)
    parser.add_argument(
        "--only", nargs="*", default=None, help="run only these parts: first_action stream viewer replay calibration"
    )
    args = parser.parse_args()
    passive_openmp_wait()  # as `imgnav console` does, before torch is imported

    def want(part: str) -> bool:
        return args.only is None or part in args.only

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
                    bench_first_action(server, args.runs, args.fresh_runs)
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
