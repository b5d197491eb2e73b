"""Simulator benchmarks (issue 2). Prints medians over several runs.

1. one step: ``SimBackend.apply(action)`` + ``observe()`` (360 x 640 RGB-D render).
   Target: <= 100 ms median on the 2-core reference machine.
2. a goal render: 512 x 512 at 75 deg HFOV.
3. building a home: ``SimWorld.from_seed`` with the texture cache warm, and cold.
4. generating an episode: ``imgnav episodes`` work per episode (its share of the home
   build, viewpoints, lattice validation, goal image), one home of 5 episodes per run.

Usage:  .venv/bin/python benchmarks/bench_sim.py [--runs 5] [--steps 60]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from agent.types import Action, Pose2D  # noqa: E402
from sim.backend import SimBackend  # noqa: E402
from sim.camera import CameraSpec  # noqa: E402
from sim.episodes import scene_seed_for  # noqa: E402
from sim.world import SimWorld  # noqa: E402


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
    import numpy as np

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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--steps", type=int, default=60)
    args = ap.parse_args()
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
