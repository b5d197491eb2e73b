"""Simulator benchmarks (issue 2). Prints medians over several runs.

1. one step: ``SimBackend.apply(action)`` + ``observe()`` (360 x 640 RGB-D render).
   Target: <= 100 ms median on the 2-core reference machine.
2. a goal render: 512 x 512 at 75 deg HFOV.
3. building a home: ``SimWorld.from_seed`` with the texture cache warm, and cold.
4. generating an episode: ``imgnav episodes`` work per episode (its share of the home
   build, viewpoints, lattice validation, goal image), one home of 5 episodes per run.
5. the render per part and the evaluation's simulator step, before and after issue 32, back to
   back (``--issue32``): recorded agent runs (``docs/results/i29_consolidation/after_train10``)
   are replayed exactly, frame by frame. Parts: the room culling, the matrices, TinyRenderer's
   pass (and the same pass without the segmentation buffer), RGB, depth, the goal mask the
   evaluation reads every step, keeping a frame. Then whole steps (goal mask + apply +
   observe), the render before issue 32 against today's with its reuse of frames, episode by
   episode in alternating order; the observations of both are checked equal (a hash per step).
   CPU time is the figure to compare on a shared machine; ratios are after / before.

Usage:  .venv/bin/python benchmarks/bench_sim.py [--runs 5] [--steps 60]
        .venv/bin/python benchmarks/bench_sim.py --issue32 [--runs 3] [--replay-episodes 4]
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import math
import os
import statistics
import sys
import tempfile
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import pybullet as pb  # noqa: E402

from agent.types import Action, Pose2D  # noqa: E402
from sim.backend import SimBackend  # noqa: E402
from sim.camera import SIM_CAMERA, CameraSpec, Render, camera_axes, depth_buffer_to_metres, rgba_to_rgb  # noqa: E402
from sim.episodes import scene_seed_for  # noqa: E402
from sim.render_reference import depth_plain, render_plain  # noqa: E402
from sim.world import _LIGHT, SimWorld  # noqa: E402

T = TypeVar("T")
REPLAY = ROOT / "docs" / "results" / "i29_consolidation" / "after_train10" / "episodes.jsonl"


def _largest_home(candidates: int = 8) -> int:
    """The val home with the most objects among the first few (a representative large home)."""
    from sim.scene_gen import generate_home

    seeds = [scene_seed_for("val", 0, k) for k in range(candidates)]
    return max(seeds, key=lambda s: len(generate_home(s).objects))


SEED = _largest_home()


class _Clock:
    """Wall and process-CPU time of a block: on a shared machine the CPU time is close to
    what a quiet machine's wall time would be (rendering is single-threaded)."""

    def __enter__(self) -> _Clock:
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall, self.cpu = time.perf_counter() - self.w, time.process_time() - self.c


def _ms(samples: list[tuple[float, float]]) -> str:
    wall = sorted(s[0] for s in samples)
    cpu = sorted(s[1] for s in samples)
    p90 = wall[min(len(wall) - 1, int(math.ceil(0.9 * len(wall))) - 1)]
    return (
        f"median {1000 * statistics.median(wall):8.1f} ms wall ({1000 * statistics.median(cpu):7.1f} ms CPU)"
        f"   p90 {1000 * p90:8.1f} ms wall   (n={len(wall)})"
    )


def bench_step(world: SimWorld, steps: int) -> list[float]:
    grid = world.navigable_grid(0.05)
    ij = np.argwhere(grid.navigable)
    x, y = grid.ij_to_xy(ij[len(ij) // 2][None])[0]
    backend = SimBackend(world, np.zeros((512, 512, 3), np.uint8), Pose2D(float(x), float(y), 0.3), max_steps=10**6)
    backend.reset()
    cycle = [
        Action.MOVE_FORWARD,
        Action.MOVE_FORWARD,
        Action.TURN_LEFT,
        Action.MOVE_FORWARD,
        Action.TURN_RIGHT,
        Action.TURN_RIGHT,
    ]
    out = []
    for k in range(steps):
        with _Clock() as c:
            backend.apply(cycle[k % len(cycle)])
            backend.observe()
        out.append((c.wall, c.cpu))
    return out


def bench_goal_render(world: SimWorld, runs: int) -> list[float]:
    cam = CameraSpec(512, 512, 75.0)
    inst = world.home.instances[0]
    cx, cy, cz = inst.center_xyz_m()
    out = []
    for k in range(runs):
        a = 2 * math.pi * k / runs
        eye = (cx + 2 * math.cos(a), cy + 2 * math.sin(a), 1.4)
        with _Clock() as c:
            world.render_view(eye, a + math.pi, 0.2, cam)
        out.append((c.wall, c.cpu))
    return out


def bench_build(runs: int, cold: bool) -> list[float]:
    out = []
    for k in range(runs):
        seed = SEED + 1000 + k if cold else SEED
        with _Clock() as c:
            SimWorld.from_seed(seed).close()
        out.append((c.wall, c.cpu))
    return out


def bench_episode(runs: int) -> list[float]:
    from sim.episode_gen import EpisodeGenConfig, generate_episode_set

    out = []
    for k in range(runs):
        with tempfile.TemporaryDirectory() as d:
            with _Clock() as c:
                eps = generate_episode_set("val", 900 + k, 5, d, EpisodeGenConfig(episodes_per_scene=5), progress=False)
            out.append((c.wall / max(len(eps), 1), c.cpu / max(len(eps), 1)))
    return out


# --- issue 32: the render per part, before and after ------------------------------------


def _timed(parts: dict[str, list[float]], name: str, fn: Callable[[], T]) -> T:
    """Run ``fn``, adding its process CPU time to ``parts[name]`` (one sample per frame)."""
    c = time.process_time()
    out = fn()
    parts.setdefault(name, []).append(time.process_time() - c)
    return out


def _render_view_before(
    world: SimWorld, eye_xyz: tuple | np.ndarray, yaw_rad: float, pitch_rad: float, camera: CameraSpec
) -> Render:
    """``SimWorld.render_view`` before issue 32 (``sim.render_reference``)."""
    rgb, depth_m, seg = render_plain(world, eye_xyz, yaw_rad, pitch_rad, camera)
    return Render(rgb, depth_m, seg, world._seg_lut)


def _replays(count: int) -> list[dict]:
    """Recorded agent runs on train10: scene, start pose (exact: stored rounded), actions, goal
    category."""
    out = []
    with open(REPLAY) as f:
        for line in f:
            r = json.loads(line)
            out.append(
                {
                    "episode_id": r["episode_id"],
                    "scene_seed": r["scene_seed"],
                    "category": r["category"],
                    "start": Pose2D(*r["trajectory"]["poses_world"][0]),
                    "actions": [Action(a) for a in r["trajectory"]["actions"]],
                }
            )
    return out[:count]


def _poses(world: SimWorld, replay: dict) -> list[Pose2D]:
    """The distinct consecutive poses of a replayed run (a blocked move renders nothing new)."""
    p = replay["start"]
    poses = [p]
    for a in replay["actions"]:
        p, _ = world.move(p, a)
        if p != poses[-1]:
            poses.append(p)
    return poses


def _goal_id(world: SimWorld, category: str) -> int:
    return next(o.object_id for o in world.home.instances if o.category == category)


def _parts_of_frame(
    world: SimWorld, pose: Pose2D, goal: int, before: dict[str, list[float]], after: dict[str, list[float]], first: str
) -> None:
    """One frame's render, part by part, by the code before issue 32 and by today's, in the
    order ``first`` says; the after parts are the pieces ``SimWorld.render_view`` is made of."""
    cam = SIM_CAMERA
    eye = np.array([pose.x_m, pose.y_m, cam.height_m])
    xy = (pose.x_m, pose.y_m)

    def run_before() -> None:
        _timed(before, "cull", lambda: world._show(world._visible(xy, pose.yaw_rad, cam.pitch_rad, cam)))
        forward, up = camera_axes(pose.yaw_rad, cam.pitch_rad)
        c = world._client

        def matrices() -> tuple:
            view = pb.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), up.tolist(), physicsClientId=c)
            proj = pb.computeProjectionMatrixFOV(
                cam.vfov_deg, cam.width_px / cam.height_px, cam.near_m, cam.far_m, physicsClientId=c
            )
            return view, proj

        view, proj = _timed(before, "matrices", matrices)
        w, h, rgba, depth, seg = _timed(
            before,
            "TinyRenderer pass",
            lambda: pb.getCameraImage(
                cam.width_px,
                cam.height_px,
                view,
                proj,
                renderer=pb.ER_TINY_RENDERER,
                shadow=0,
                physicsClientId=c,
                **_LIGHT,
            ),
        )
        rgb = _timed(before, "rgb", lambda: np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3].copy())
        dm = _timed(
            before,
            "depth",
            lambda: depth_plain(np.asarray(depth, dtype=np.float32).reshape(h, w), cam.near_m, cam.far_m),
        )
        r = Render(rgb, dm, np.asarray(seg).reshape(h, w), world._seg_lut)
        _timed(before, "goal mask", lambda: r.instance_ids == goal)

    def run_after() -> None:
        _timed(after, "cull", lambda: world._show(world._visible(xy, pose.yaw_rad, cam.pitch_rad, cam)))
        view = _timed(
            after, "matrices", lambda: (world._view(eye, pose.yaw_rad, cam.pitch_rad), world._projection(cam))
        )
        rgba, depth, seg = _timed(after, "TinyRenderer pass", lambda: world._raster(cam, view[0]))
        rgb = _timed(after, "rgb", lambda: rgba_to_rgb(rgba))
        dm = _timed(after, "depth", lambda: depth_buffer_to_metres(depth, cam.near_m, cam.far_m))
        r = Render(rgb, dm, seg, world._seg_lut)
        _timed(after, "goal mask", lambda: r.mask_of(goal))
        _timed(after, "keep the frame (a copy)", r.copy)
        before.setdefault("keep the frame (a copy)", []).append(0.0)  # nothing was kept before

    for which in (first, "after" if first == "before" else "before"):
        run_before() if which == "before" else run_after()
    # the same pass without the segmentation buffer: what leaving segmentation out would save
    view = world._view(eye, pose.yaw_rad, cam.pitch_rad)
    proj = list(world._projection(cam))
    passes = [(0, "pass with segmentation"), (pb.ER_NO_SEGMENTATION_MASK, "pass without segmentation")]
    for flags, part in passes if first == "before" else passes[::-1]:
        kw = dict(_LIGHT, renderer=pb.ER_TINY_RENDERER, shadow=0, flags=flags, physicsClientId=world._client)
        _timed(after, part, functools.partial(pb.getCameraImage, cam.width_px, cam.height_px, list(view), proj, **kw))


def _replay_steps(world: SimWorld, replay: dict, goal: int, before: bool) -> tuple[list[float], list[str]]:
    """The evaluation's simulator work per step of a recorded run (the attribution's goal mask,
    apply, observe), by the render before issue 32 or today's (its kept frames cleared first).
    Returns the CPU seconds per step and a hash of each observation (outside the timing)."""
    world._frames.clear()
    if before:
        world.render_view = types.MethodType(_render_view_before, world)  # type: ignore[method-assign]
    backend = SimBackend(
        world, np.zeros((8, 8, 3), np.uint8), replay["start"], goal, viewpoints_xy_m=np.zeros((0, 2)), max_steps=10**6
    )
    times, hashes = [], []
    try:
        obs = backend.reset()
        for action in replay["actions"]:
            c = time.process_time()
            mask = backend.oracle.instance_ids() == goal if before else backend.oracle.goal_mask()
            t = time.process_time() - c
            frame = obs.rgb.tobytes() + obs.depth_m.tobytes() + np.packbits(mask).tobytes()
            hashes.append(hashlib.blake2b(frame, digest_size=16).hexdigest())
            c = time.process_time()
            backend.apply(action)
            if not backend.done:
                obs = backend.observe()
            times.append(t + time.process_time() - c)
    finally:
        if before:
            del world.render_view
    return times, hashes


def _ratio_row(name: str, b: list[float], a: list[float]) -> str:
    mb, ma = statistics.median(b), statistics.median(a)
    ratio = f"{ma / mb:5.2f}" if mb > 0 else "    -"
    return f"  {name:36s} {1000 * mb:8.2f} {1000 * ma:8.2f}   {ratio}"


def bench_issue32(runs: int, n_episodes: int) -> None:
    replays = _replays(n_episodes)
    before: dict[str, list[float]] = {}
    after: dict[str, list[float]] = {}
    step_b: list[float] = []
    step_a: list[float] = []
    reused = rendered = 0
    for k, rp in enumerate(replays):
        world = SimWorld.from_seed(rp["scene_seed"])
        try:
            goal = _goal_id(world, rp["category"])
            poses = _poses(world, rp)
            for run in range(runs):
                for i, pose in enumerate(poses):
                    _parts_of_frame(world, pose, goal, before, after, "before" if (i + run) % 2 == 0 else "after")
            for run in range(runs):
                order = (True, False) if (run + k) % 2 == 0 else (False, True)
                out = {}
                for is_before in order:
                    r0 = world.frames_reused
                    out[is_before] = _replay_steps(world, rp, goal, is_before)
                    if not is_before:
                        reused += world.frames_reused - r0
                        rendered += len(poses)  # the frames the run asks the world for
                if out[True][1] != out[False][1]:
                    raise AssertionError(f"{rp['episode_id']}: observations differ before and after issue 32")
                step_b += out[True][0]
                step_a += out[False][0]
        finally:
            world.close()
        print(f"  replayed {rp['episode_id']}: {len(rp['actions'])} steps, {len(poses)} frames", flush=True)
    n_frames = len(before["rgb"])
    print(f"render per part over {n_frames} frames ({len(replays)} recorded runs x {runs}), median CPU ms")
    print(f"  {'part':36s} {'before':>8s} {'after':>8s}   ratio after/before")
    parts = [p for p in before]
    total_b = [sum(before[p][i] for p in parts) for i in range(n_frames)]
    total_a = [sum(after[p][i] for p in parts) for i in range(n_frames)]
    for part in parts:
        print(_ratio_row(part, before[part], after[part]))
    print(_ratio_row("render, a new frame (sum of the parts)", total_b, total_a))
    rest_b = [t - p for t, p in zip(total_b, before["TinyRenderer pass"])]
    rest_a = [t - p for t, p in zip(total_a, after["TinyRenderer pass"])]
    print(_ratio_row("  of which not the TinyRenderer pass", rest_b, rest_a))
    print("the TinyRenderer pass, segmentation buffer left out (ER_NO_SEGMENTATION_MASK) / in")
    print(_ratio_row("", after["pass with segmentation"], after["pass without segmentation"]))
    mean_b, mean_a = statistics.fmean(step_b), statistics.fmean(step_a)
    print(
        f"evaluation's simulator step (goal mask + apply + observe), {len(step_a)} steps each, observations equal; "
        f"frames reused {reused} of {rendered} ({100 * reused / max(rendered, 1):.1f}%)"
    )
    print(f"  {'':36s} {'before':>8s} {'after':>8s}   ratio after/before")
    print(_ratio_row("median CPU ms per step", step_b, step_a))
    print(f"  {'mean CPU ms per step':36s} {1000 * mean_b:8.2f} {1000 * mean_a:8.2f}   {mean_a / mean_b:5.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument(
        "--issue32", action="store_true", help="only the render per part and the step, before and after issue 32"
    )
    ap.add_argument("--replay-episodes", type=int, default=4, help="recorded runs replayed by --issue32")
    args = ap.parse_args()
    if args.issue32:
        print(f"issue 32 (load average {os.getloadavg()[0]:.1f}, {os.cpu_count()} CPUs)")
        bench_issue32(args.runs, args.replay_episodes)
        return 0
    print(f"simulator benchmarks (home {SEED}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f})")
    world = SimWorld.from_seed(SEED)
    try:
        print(
            f"{len(world.home.rooms)} rooms, {len(world.home.objects)} objects, {len(world.home.materials)} materials"
        )
        bench_step(world, 5)  # warm up
        print(f"one step (apply + observe 360x640)   {_ms(bench_step(world, args.steps))}")
        print(f"goal render (512x512)                {_ms(bench_goal_render(world, max(args.runs, 8)))}")
    finally:
        world.close()
    print(f"build a home (textures cached)       {_ms(bench_build(args.runs, cold=False))}")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["IMGNAV_CACHE_DIR"] = cache
        print(f"build a home (cold texture cache)    {_ms(bench_build(min(args.runs, 3), cold=True))}")
        print(f"generate an episode (per episode)    {_ms(bench_episode(min(args.runs, 3)))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
