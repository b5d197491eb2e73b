"""What the Mod-IIN agent decided at each step of a stretch of one episode, and why.

Runs the agent on one episode with ``imgnav eval``'s own flags (``--realism stretch``,
``--realism-only actuation``, ``--modiin-set ...``: the same episode and seed give the same run)
and prints, for steps FROM to FROM+COUNT-1, one line each:

    step  action (the plan's own action when the motion memory changed it)  mode  event
    pose (x, y, heading in deg; the agent's frame)  target and geodesic distance
    obstacle cells added / removed by the step  turns to and fro so far

and with ``--moves`` the forward moves remembered as failed from the robot's cell (30-degree
heading bins) and the bins whose 0.25 m step the map shows free. At the end: the longest run of
alternating left and right turns in the stretch.

    python benchmarks/trace_steps.py --episodes data/episodes/train30s1 --agent modiin --out runs/x \\
        --realism stretch --realism-only actuation --moves -- train-s1-0008-0 160 40

This is how the to-and-fro loop of docs/experiments/refused-move-remark.md was found.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.loop import LoopStep, run_loop  # noqa: E402
from agent.motion import N_HEADINGS, move_key  # noqa: E402
from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG  # noqa: E402
from benchmarks.map_at_step import episode_run  # noqa: E402
from sim.evaluation.cli import add_arguments  # noqa: E402
from sim.evaluation.compare import to_and_fro_runs  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("episode_id")
    parser.add_argument("start", type=int, help="first step to print")
    parser.add_argument("count", type=int, help="steps to print")
    parser.add_argument("--moves", action="store_true", help="also the failed and the free moves from the cell")
    args = parser.parse_args()
    _, world, backend, agent = episode_run(args)
    last = {"obstacle": None}
    turns: list[int] = []

    class Printer:
        def step(self, s: LoopStep) -> None:
            if s.step < args.start:
                return
            d, grid, pose = agent.last_decision, agent.grid, s.obs.pose
            assert d is not None
            obstacle = grid.layers.obstacle.copy()
            prev = last["obstacle"]
            change = (
                f"+{int((obstacle & ~prev).sum())}/-{int((prev & ~obstacle).sum())}"
                if prev is not None and prev.shape == obstacle.shape
                else "-"
            )
            last["obstacle"] = obstacle
            action = s.action.name
            if d.plan is not None and d.plan.action != s.action:
                action += f" (plan {d.plan.action.name})"
            target = (
                f"target ({d.plan.target_xy_m[0]:.2f}, {d.plan.target_xy_m[1]:.2f}) at {d.plan.distance_m:.2f} m"
                if d.plan is not None
                else "no plan"
            )
            turns.append(int(s.action))
            print(
                f"{s.step:4d} {action:34s} {d.mode.value:11s} {d.event.value:28s} "
                f"pose ({pose.x_m:.2f}, {pose.y_m:.2f}, {math.degrees(pose.yaw_rad):6.1f})  {target}  "
                f"obstacles {change}  to-and-fro {agent._state.motion.alternating_turns}",
                flush=True,
            )
            if args.moves and d.plan is not None:
                here = np.array([pose.x_m, pose.y_m])
                field = agent.planner.distance_field(grid, pose)
                free = []
                for b in range(N_HEADINGS):
                    yaw = math.radians(TURN_ANGLE_DEG * b)
                    ahead = here + FORWARD_STEP_M * np.array([math.cos(yaw), math.sin(yaw)])
                    if agent.planner.line_free(grid, field, here, ahead):
                        free.append(b)
                i, j, _ = move_key(grid, pose)
                failed = sorted(h for (a, b_, h) in agent._state.motion.blocked if (a, b_) == (i, j))
                print(f"{'':5s}failed from this cell: bins {failed}; free on the map: bins {free}")

    run_loop(backend, agent, args.start + args.count, (Printer(),), should_stop=lambda: backend.done)
    print(f"longest run of turns to and fro in these steps: {max(to_and_fro_runs(turns), default=0)}")
    backend.close()
    world.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
