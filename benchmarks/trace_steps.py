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

A goal of a multi-goal sequence is SEQUENCE-gK: the goals before it run first, as ``imgnav eval``
runs them (with ``--memory`` they share the memory), and goal K's steps are printed:

    python benchmarks/trace_steps.py --episodes data/episodes/trainseq10s2 --agent modiin --out runs/x \\
        --memory -- train-s2-0006-q0-g0 0 40

This is how the to-and-fro loop of docs/experiments/refused-move-remark.md was found.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.loop import LoopStep, run_loop  # noqa: E402
from agent.motion import N_HEADINGS, move_key  # noqa: E402
from agent.policy import ModIINAgent  # noqa: E402
from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG  # noqa: E402
from benchmarks.map_at_step import episode_run  # noqa: E402
from sim.evaluation.cli import add_arguments  # noqa: E402
from sim.evaluation.compare import to_and_fro_runs  # noqa: E402
from sim.evaluation.multigoal import NextAgent, SharedHomeMemory, agent_for_goal, run_sequence, uses_memory  # noqa: E402
from sim.evaluation.registry import get_spec  # noqa: E402
from sim.sequences import SequenceSet, load_any_set, load_sequence_set  # noqa: E402
from sim.world import SimWorld  # noqa: E402


class Printer:
    """A loop sink printing steps ``start`` to ``start + count - 1`` of the agent ``get_agent()``."""

    def __init__(self, get_agent: Callable[[], ModIINAgent], start: int, count: int, moves: bool) -> None:
        self.get_agent, self.start, self.end, self.moves = get_agent, start, start + count, moves
        self.obstacle: np.ndarray | None = None
        self.turns: list[int] = []

    def step(self, s: LoopStep) -> None:
        if not self.start <= s.step < self.end:
            return
        agent = self.get_agent()
        d, grid, pose = agent.last_decision, agent.grid, s.obs.pose
        assert d is not None
        obstacle = grid.layers.obstacle.copy()
        prev = self.obstacle
        change = (
            f"+{int((obstacle & ~prev).sum())}/-{int((prev & ~obstacle).sum())}"
            if prev is not None and prev.shape == obstacle.shape
            else "-"
        )
        self.obstacle = obstacle
        action = s.action.name
        if d.plan is not None and d.plan.action != s.action:
            action += f" (plan {d.plan.action.name})"
        target = (
            f"target ({d.plan.target_xy_m[0]:.2f}, {d.plan.target_xy_m[1]:.2f}) at {d.plan.distance_m:.2f} m"
            if d.plan is not None
            else "no plan"
        )
        self.turns.append(int(s.action))
        print(
            f"{s.step:4d} {action:34s} {d.mode.value:11s} {d.event.value:28s} "
            f"pose ({pose.x_m:.2f}, {pose.y_m:.2f}, {math.degrees(pose.yaw_rad):6.1f})  {target}  "
            f"obstacles {change}  to-and-fro {agent._state.motion.alternating_turns}",
            flush=True,
        )
        if self.moves and d.plan is not None:
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


def trace_subtask(args: argparse.Namespace, printer_of: Callable[[Callable[[], ModIINAgent]], Printer]) -> Printer:
    """Goal K of a sequence (``args.episode_id`` = ``SEQUENCE-gK``): the goals before it run first,
    as ``imgnav eval`` runs them (sharing the memory with ``--memory``), then goal K is traced."""
    es = load_sequence_set(args.episodes)
    seq_id, _, k = args.episode_id.rpartition("-g")
    if not seq_id or not k.isdigit():
        raise SystemExit(f"{args.episode_id!r}: a goal of a sequence is SEQUENCE-gK, e.g. train-s2-0006-q0-g2")
    g = int(k)
    seq = es.by_id(seq_id)
    if g >= len(seq.goals):
        raise SystemExit(f"{seq_id} has {len(seq.goals)} goals")
    seq = replace(seq, goals=seq.goals[: g + 1])
    spec = get_spec("modiin")
    base: NextAgent = SharedHomeMemory(spec, args) if uses_memory(args) else agent_for_goal
    holder: list[ModIINAgent] = []

    def hook(*a: Any) -> Any:
        agent = base(*a)
        holder[:] = [agent]
        return agent

    printer = printer_of(lambda: holder[0])
    with SimWorld.from_seed(seq.scene_seed) as world:
        images = [es.goal_image_path(seq, i) for i in range(g + 1)]
        run_sequence(world, seq, images, spec, args, next_agent=hook, sinks_for=lambda i: (printer,) if i == g else ())
    return printer


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("episode_id", help="an episode, or a goal of a sequence: SEQUENCE-gK (with --memory: shared)")
    parser.add_argument("start", type=int, help="first step to print")
    parser.add_argument("count", type=int, help="steps to print")
    parser.add_argument("--moves", action="store_true", help="also the failed and the free moves from the cell")
    args = parser.parse_args()

    def printer_of(get_agent: Callable[[], ModIINAgent]) -> Printer:
        return Printer(get_agent, args.start, args.count, args.moves)

    if isinstance(load_any_set(args.episodes), SequenceSet):
        printer = trace_subtask(args, printer_of)
    else:
        _, world, backend, agent = episode_run(args)
        printer = printer_of(lambda: agent)
        run_loop(backend, agent, args.start + args.count, (printer,), should_stop=lambda: backend.done)
        backend.close()
        world.close()
    print(f"longest run of turns to and fro in these steps: {max(to_and_fro_runs(printer.turns), default=0)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
