"""The memory of a home across goals (agent/memory.py): what it costs per step, how large it grows,
what scoring a new goal against it costs, and whether a goal seen before is found from it.

    .venv/bin/python benchmarks/bench_memory.py [--episodes DIR] [--count 1] [--steps 150] [--steps-b 150]

For each of the first ``--count`` episodes (one per home): goal A is the episode, run by the default
agent (agent/configs/sim.yaml) with a ``HomeMemory`` for at most ``--steps`` steps. Then every
other goal instance of the home that was in view during A (at least ``--seen-px`` pixels in some
frame) becomes goal B in turn: a goal image of it is rendered, a fresh agent on the same memory is
reset with it (the memory as A left it, restored for each B) and runs from where A ended, for
at most ``--steps-b`` steps (at most ``--max-b`` goals B; with ``--fresh`` each also without
memory, from the same start, for the paired figures). Poses stay in goal A's frame across the goals, as the memory
requires: B's backend starts where A ended and its poses are re-expressed in A's start frame.

Prints: the keyframe step's cost (median, p90 of ``timings_ms["memory"]``: the depth lift of the
keypoints and the store), the memory's size (keyframes, bytes, the map's bytes), and per goal B:
the recall's cost and best score, the views it added, the first decision's mode, the outcome
(success: the simulator's metric) and the steps taken. Timings from a loaded machine are not final.
"""

from __future__ import annotations

import argparse
import copy
import logging
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.episode_sets import load_or_generate  # noqa: E402


class Watch:
    """A sink: the largest number of pixels of each instance in a frame (with an oracle), each
    step's mode and keyframe cost."""

    def __init__(self, oracle) -> None:
        self.oracle = oracle
        self.seen: dict[int, int] = {}
        self.memory_ms: list[float] = []
        self.modes: list[str] = []

    def before_apply(self, s) -> None:
        import numpy as np

        if self.oracle is not None:
            ids = self.oracle.instance_ids()
            for iid, n in zip(*np.unique(ids[ids >= 0], return_counts=True)):
                self.seen[int(iid)] = max(self.seen.get(int(iid), 0), int(n))
        if s.record is not None:
            self.modes.append(s.record.mode)
            if "memory" in s.record.timings_ms:
                self.memory_ms.append(float(s.record.timings_ms["memory"]))

    def step(self, s) -> None:
        pass


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", default=None, help="episode set (default: generate train episodes into a temp dir)")
    p.add_argument("--count", type=int, default=1)
    p.add_argument("--steps", type=int, default=150, help="goal A's steps at most")
    p.add_argument("--steps-b", type=int, default=150, help="each goal B's steps at most")
    p.add_argument("--seen-px", type=int, default=4000, help="pixels of an instance that count as in view")
    p.add_argument("--max-b", type=int, default=3, help="goals B per home at most")
    p.add_argument("--fresh", action="store_true", help="also run each goal B without memory, from the same start")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)

    import torch

    from agent.config import load_agent_config
    from agent.loop import run_loop
    from agent.memory import HomeMemory, InHomeFrame
    from agent.policy import ModIINAgent
    from agent.reid.identifier import make_matcher
    from sim.backend import SimBackend
    from sim.goals import sample_goal_images
    from sim.world import SimWorld

    torch.set_num_threads(args.threads)
    es, tmp = load_or_generate(args.episodes, "train", 0, args.count)
    cfg = load_agent_config("sim")
    cfg = replace(cfg, reid=replace(cfg.reid, num_threads=args.threads))
    matcher = make_matcher(cfg.reid)
    for ep in list(es.episodes)[: args.count]:
        world = SimWorld.from_seed(ep.scene_seed)
        home = HomeMemory(cfg.memory)
        backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep), max_steps=args.steps)
        watch = Watch(backend.oracle)
        agent = ModIINAgent(cfg, matcher=matcher, home_memory=home)
        result = run_loop(backend, agent, args.steps, sinks=(watch,))
        seen, memory_ms = watch.seen, watch.memory_ms
        m = backend.result()
        end_world, start_world = backend.pose_world, backend.start_pose_world
        backend.close()
        ms = sorted(memory_ms)
        print(
            f"{ep.episode_id} ({ep.goal_category}, instance {ep.goal_instance_id}): goal A {result.n_steps} steps, "
            f"success {m.success if m is not None else None}; keyframe step {statistics.median(ms):.1f} ms median, "
            f"{ms[int(0.9 * (len(ms) - 1))]:.1f} ms p90 over {len(ms)} searching steps; memory: {len(home)} keyframes, "
            f"{home.size_bytes / 1e6:.1f} MB ({home.size_bytes / max(1, len(home)) / 1e3:.0f} kB each), "
            f"map {home.map_bytes / 1e6:.1f} MB"
        )
        after_a = copy.deepcopy(home)
        others = [
            o.object_id
            for o in world.home.instances
            if o.object_id != ep.goal_instance_id and seen.get(o.object_id, 0) >= args.seen_px
        ]
        for iid in others[: args.max_b]:
            obj = world.home.instance(iid)
            images = sample_goal_images(world, iid, 1, (ep.scene_seed, iid, 31))
            if not images:
                print(f"  B: instance {iid} ({obj.category}): no goal image")
                continue
            home_b = copy.deepcopy(after_a)
            b = SimBackend(world, images[0].rgb, end_world, goal_instance_id=iid, max_steps=args.steps_b, episode=None)
            agent_b = ModIINAgent(cfg, matcher=matcher, home_memory=home_b)
            watch_b = Watch(None)
            t0 = time.perf_counter()
            res = run_loop(InHomeFrame(b, end_world.relative_to(start_world)), agent_b, args.steps_b, sinks=(watch_b,))
            modes = watch_b.modes
            wall = time.perf_counter() - t0
            mb = b.result()
            g = home_b.goals[-1]
            best = "-" if g.recall_best_score is None else f"{g.recall_best_score:.1f}"
            print(
                f"  B: instance {iid} ({obj.category}, seen {seen[iid]} px): recall {g.recall_ms:.0f} ms, best "
                f"{best}, {g.recalled_views} views added; first modes {modes[:3]}; {res.n_steps} steps "
                f"({wall:.0f} s), looked around {modes.count('look_around')}, explored {modes.count('explore')}; "
                f"final {g.final_mode}/{g.final_event}, success {mb.success if mb is not None else None}"
            )
            b.close()
            if args.fresh:
                b = SimBackend(world, images[0].rgb, end_world, goal_instance_id=iid, max_steps=args.steps_b)
                watch_b = Watch(None)
                res = run_loop(b, ModIINAgent(cfg, matcher=matcher), args.steps_b, sinks=(watch_b,))
                mb = b.result()
                print(
                    f"     without memory: {res.n_steps} steps, looked around {watch_b.modes.count('look_around')}, "
                    f"explored {watch_b.modes.count('explore')}; success {mb.success if mb is not None else None}"
                )
                b.close()
        world.close()
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
