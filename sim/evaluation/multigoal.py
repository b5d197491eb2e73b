"""Evaluating multi-goal sets (issue 31): one record per sequence, every subtask scored.

A sequence (``sim.sequences``) is run goal after goal in one built home. Subtask 0 starts at
the sequence's start; subtask k starts where the robot stood at the end of subtask k - 1,
whatever happened there (a stop, the budget, an error), and its SPL uses the shortest path
from that actual start. Each subtask is a single-goal run on its own ``SimBackend`` (its own
step budget, ``--subtask-budget``, the single-goal budget by default; its own start-relative
frame, or with ``--memory`` the sequence's, below), through ``runner.run_on_backend``, so it is
scored and observed exactly as a single-goal episode (the Mod-IIN failure attribution included).

The agent of each subtask comes from a hook between goals (``NextAgent``). Without
``--memory``, ``agent_for_goal`` makes a fresh agent per goal: every subtask starts from nothing,
as a single-goal episode, in its own start-relative frame. With ``--memory`` (agents whose spec
has ``make_memory``: ``modiin``), ``SharedHomeMemory`` gives every goal's agent the same memory of
the home (``agent.memory.HomeMemory``: the map, keyframes, earlier goals), one per sequence, never
shared between sequences, and the agent works in ONE frame across the subtasks: the frame of the
first subtask's start. Subtask k's backend gives its poses in that frame (``SimBackend``'s
``frame_origin``): its origin is the composition of the believed end poses handed over,
``origin_k = origin_(k-1) * end_(k-1)`` (``SubtaskHandoff.previous_end_pose``, ``origin_0`` the
identity). They are beliefs, never the truth: under a realism profile the simulator restarts the
pose estimate at each subtask's true start, and the agent's belief goes on from where it believed
it ended, as a robot's odometry does. Metrics use the true poses, as always; the failure
attribution puts the agent's poses, points and map in the world through ``SimOracle.frame_world``
(the world pose of that frame as this subtask's estimate places it).

``OUT/episodes.jsonl`` holds one record per sequence: its id, home, budget, sequence figures
(``success``: every goal reached; ``subtasks_succeeded``; ``spl``: the mean of its subtasks'),
``memory`` (true: run with ``--memory``; a resumed run refuses to mix the two), the fields every
subtask shares (``variant``, ``agent_config``, ``realism``) and ``subtasks``: one entry per goal
with what a single-goal record holds (metrics, trajectory, stop reason, timings, the agent
observer's fields such as ``failure_cause`` and ``modiin``) and the goal's index, kind (new,
repeat, look-alike), instance and start pose; with ``--memory`` also ``memory``
(``memory_figures``: the subtask's frame origin, the keyframes it started with, what recall gave
it, whether it skipped the look-around, the memory's size at its end). ``summary.json``
(``summarize_sequences``): the figures over all subtasks, the first goal against the later
ones, per goal index and kind, and the sequences, SR and SPL with 95% intervals from a
bootstrap over homes (with ``--memory``, ``memory_use`` over the later goals); its
``throughput`` (``schedule.throughput``) is given per sequence and per subtask. The runner hands
sequences to workers as it hands out episodes (``workers.run_unit``), a sequence's estimated
cost being the sum over its goals.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.types import MAX_STEPS, Agent, Pose2D
from sim.backend import GoalScoring, SimBackend
from sim.episodes import r4, read_rgb
from sim.evaluation.cli import realism_of
from sim.evaluation.registry import AgentSpec
from sim.evaluation.runner import run_on_backend
from sim.metrics import aggregate, bootstrap_ci
from sim.navigation import GRID_RESOLUTION_M, geodesic_at, geodesic_field
from sim.sequences import SequenceEpisode
from sim.world import SimWorld

if TYPE_CHECKING:
    from agent.memory import HomeMemory

log = logging.getLogger(__name__)

# Fields of a subtask's record that are the sequence's (kept once, in the sequence's record).
SEQUENCE_FIELDS = ("episode_id", "scene_seed", "agent", "realism", "variant", "agent_config")


def uses_memory(args: argparse.Namespace) -> bool:
    """``--memory``: the goals of a sequence share a memory of the home (module docstring)."""
    return bool(getattr(args, "memory", False))


def subtask_budget(args: argparse.Namespace) -> int:
    """Steps per subtask: ``--subtask-budget``, else the single-goal budget."""
    budget = getattr(args, "subtask_budget", None)
    budget = MAX_STEPS if budget is None else int(budget)
    if budget <= 0:
        raise ValueError("--subtask-budget must be positive")
    return budget


@dataclass(frozen=True, slots=True)
class SubtaskHandoff:
    """What the agent of a goal may know about the goals before it (never ground truth).

    goal_index: this goal's index in the sequence (0: the first).
    previous_end_pose: where the previous subtask ended as the agent believed it, in that
        subtask's start-relative frame, i.e. the origin of this subtask's frame in the previous
        one (None for the first goal). Under a realism profile the simulator restarts the pose
        estimate at each subtask's true start, so this is the belief, not the truth."""

    goal_index: int
    previous_end_pose: Pose2D | None


def agent_for_goal(
    previous: Agent | None, spec: AgentSpec, args: argparse.Namespace, oracle: Any, handoff: SubtaskHandoff
) -> Agent:
    """The agent for the next goal of a sequence, given the previous goal's agent (None before
    the first goal or when making it failed): THE hook between goals.

    Without ``--memory`` every goal starts from scratch: the previous agent is dropped and a fresh
    one is made (``oracle`` is this subtask's ``SimOracle``; only oracle agents and ablations read
    it). With it, ``run_sequence`` uses ``SharedHomeMemory`` instead. Note that the loop calls
    ``reset`` with the new goal image before the first step, so an agent kept across goals must
    keep its memory through ``reset``."""
    return spec.make_agent(args, oracle)


NextAgent = Callable[[Agent | None, AgentSpec, argparse.Namespace, Any, SubtaskHandoff], Agent]


class SharedHomeMemory:
    """The hook between goals with ``--memory`` (a ``NextAgent``): one memory of the home for one
    sequence (``spec.make_memory``), set as the ``home_memory`` of every goal's agent before the
    loop resets it (``ModIINAgent``'s ``reset`` then begins the next goal in it: the remembered
    map, recall against the keyframes). Each goal still gets a fresh agent, as a reset agent would
    be apart from the memory, made for this subtask's oracle (an observer may key on it). The
    poses the agent gets are in the memory's frame because the backend gives them so
    (``run_sequence``); this hook does not touch frames."""

    def __init__(self, spec: AgentSpec, args: argparse.Namespace) -> None:
        if spec.make_memory is None:
            raise ValueError(f"--memory: the agent {spec.name!r} keeps no memory of a home")
        self.memory: HomeMemory = spec.make_memory(args)

    def __call__(
        self, previous: Agent | None, spec: AgentSpec, args: argparse.Namespace, oracle: Any, handoff: SubtaskHandoff
    ) -> Agent:
        agent = spec.make_agent(args, oracle)
        if not hasattr(agent, "home_memory"):
            raise ValueError(f"--memory: the {spec.name!r} agent has no home_memory to give the memory to")
        agent.home_memory = self.memory  # type: ignore[attr-defined]
        return agent


def memory_figures(memory: HomeMemory, goals_before: int, origin: Pose2D | None) -> dict[str, Any]:
    """A subtask's ``memory`` entry: ``frame_origin`` (its start in the memory's frame, as the
    agent believed it), from the goal's summary (None when the goal never began: its agent failed
    before ``reset``) ``keyframes_at_start`` (scored against the new goal), ``recalled_views``
    (remembered views that added goal points), ``recall_candidate`` (so the goal had a candidate
    before its first step), ``recall_best_score``, ``recall_ms``, ``first_mode`` and
    ``look_around_skipped`` (its first step was not the look-around), and the memory at the
    subtask's end: ``keyframes``, ``keyframe_bytes``, ``map_bytes``."""
    o = Pose2D() if origin is None else origin
    goal = memory.goals[-1] if len(memory.goals) > goals_before else None
    out: dict[str, Any] = {"frame_origin": [r4(o.x_m), r4(o.y_m), r4(o.yaw_rad)]}
    if goal is None:
        out.update(dict.fromkeys(("keyframes_at_start", "recalled_views", "recall_candidate", "recall_best_score")))
        out.update(dict.fromkeys(("recall_ms", "first_mode", "look_around_skipped")))
    else:
        out.update(
            {
                "keyframes_at_start": goal.keyframes_at_start,
                "recalled_views": goal.recalled_views,
                "recall_candidate": goal.recalled_views > 0,
                "recall_best_score": None if goal.recall_best_score is None else round(goal.recall_best_score, 1),
                "recall_ms": round(goal.recall_ms, 1),
                "first_mode": goal.first_mode,
                "look_around_skipped": goal.first_mode is not None and goal.first_mode != "look_around",
            }
        )
    out.update({"keyframes": len(memory), "keyframe_bytes": memory.size_bytes, "map_bytes": memory.map_bytes})
    return out


def _subtask_backend(
    world: SimWorld,
    seq: SequenceEpisode,
    goal_index: int,
    start_pose_world: Pose2D,
    goal_image: np.ndarray,
    args: argparse.Namespace,
    budget: int,
    frame_origin: Pose2D | None = None,
) -> tuple[SimBackend, Any]:
    """The backend of one subtask and its single-goal ``Episode`` (``SequenceEpisode.subtask``);
    ``frame_origin``: the pose of its start in the frame its poses are to be given in (None: its
    own start-relative frame)."""
    goal = seq.goals[goal_index]
    vp = goal.viewpoints_array()
    if goal_index == 0:  # the stored shortest path, as a single-goal episode uses it
        episode = seq.subtask(0, start_pose_world, seq.geodesic_distance_m)
        backend = SimBackend(
            world,
            goal_image,
            start_pose_world,
            goal.goal_instance_id,
            vp,
            seq.geodesic_distance_m,
            max_steps=budget,
            episode=episode,
            realism=realism_of(args),
            frame_origin=frame_origin,
        )
        return backend, episode
    # later goals: the shortest path from where the robot actually is (the geodesic field to the
    # stored viewpoints, computed once and handed to the backend for NE and the oracle)
    grid = world.navigable_grid(GRID_RESOLUTION_M)
    field = geodesic_field(grid, vp)
    shortest_m = r4(geodesic_at(field, grid, start_pose_world.x_m, start_pose_world.y_m))
    if not math.isfinite(shortest_m):
        log.warning("%s goal %d: no path from %s to the goal", seq.episode_id, goal_index, start_pose_world)
    episode = seq.subtask(goal_index, start_pose_world, shortest_m)
    backend = SimBackend(
        world,
        goal_image,
        start_pose_world,
        goal.goal_instance_id,
        shortest_path_m=shortest_m,
        max_steps=budget,
        episode=episode,
        scoring=lambda: GoalScoring(vp, field),
        realism=realism_of(args),
        frame_origin=frame_origin,
    )
    return backend, episode


def run_sequence(
    world: SimWorld,
    seq: SequenceEpisode,
    goal_images: Sequence[np.ndarray | str | Path],
    spec: AgentSpec,
    args: argparse.Namespace,
    fail_fast: bool = False,
    next_agent: NextAgent | None = None,
    sinks_for: Callable[[int], Sequence[Any]] | None = None,
) -> dict[str, Any]:
    """Run every goal of ``seq`` in an already built world, each from where the last ended;
    returns the sequence's record (module docstring). goal_images: one per goal, arrays or PNG paths.
    ``next_agent``: the hook between goals (default: ``SharedHomeMemory`` with ``--memory``, a new
    one for this sequence, else ``agent_for_goal``); with ``--memory`` the subtasks share one
    frame whatever the hook, and the memory's figures are recorded when the hook has a
    ``memory``. ``sinks_for(goal_index)``: more step sinks for that goal's loop (a tracing
    tool's)."""
    t0, c0 = time.perf_counter(), time.process_time()
    budget = subtask_budget(args)
    memory_on = uses_memory(args)
    hook: NextAgent = next_agent or (SharedHomeMemory(spec, args) if memory_on else agent_for_goal)
    memory: HomeMemory | None = getattr(hook, "memory", None) if memory_on else None
    pose = seq.start_pose_world
    agent: Agent | None = None
    previous_end: Pose2D | None = None
    origin: Pose2D | None = None  # this subtask's start in the memory's frame (None: the identity)
    subtasks: list[dict[str, Any]] = []
    shared: dict[str, Any] = {}
    for g, goal in enumerate(seq.goals):
        image = goal_images[g]
        image = read_rgb(image) if isinstance(image, (str, Path)) else image
        if memory_on and previous_end is not None:  # the belief goes on where it ended (docstring)
            origin = previous_end if origin is None else origin.compose(previous_end)
        backend, episode = _subtask_backend(world, seq, g, pose, image, args, budget, origin)
        handoff = SubtaskHandoff(g, previous_end)
        previous = agent
        goals_before = len(memory.goals) if memory is not None else 0

        def make(oracle: Any, previous: Agent | None = previous, handoff: SubtaskHandoff = handoff) -> Agent:
            return hook(previous, spec, args, oracle, handoff)

        sinks = sinks_for(g) if sinks_for is not None else ()
        rec, agent = run_on_backend(backend, episode, spec, args, make, fail_fast, sinks=sinks)
        believed = backend.estimate_world
        previous_end = (
            Pose2D() if believed == backend.start_pose_world else believed.relative_to(backend.start_pose_world)
        )
        p = backend.start_pose_world
        entry: dict[str, Any] = {
            "goal_index": g,
            "subtask_id": episode.episode_id,
            "kind": goal.kind,
            "of_goal": goal.of_goal,
            "goal_instance_id": goal.goal_instance_id,
            "start_pose_world": [r4(p.x_m), r4(p.y_m), r4(p.yaw_rad)],
        }
        for key in SEQUENCE_FIELDS:
            if key in rec:
                shared.setdefault(key, rec[key])
        entry.update({k: v for k, v in rec.items() if k not in SEQUENCE_FIELDS})
        if memory is not None:
            entry["memory"] = memory_figures(memory, goals_before, origin)
        subtasks.append(entry)
        pose = backend.pose_world  # the next goal starts where this one ended
    steps = sum(s["steps"] for s in subtasks)
    errors = [f"goal {s['goal_index']}: {s['error']}" for s in subtasks if s.get("error")]

    def per_step(key: str) -> float:
        return r4(sum(s["timing"][key] * s["steps"] for s in subtasks) / max(steps, 1))

    record: dict[str, Any] = {
        "episode_id": seq.episode_id,
        "scene_seed": seq.scene_seed,
        "agent": spec.name,
        "goals": len(seq.goals),
        "subtask_budget": budget,
        "memory": memory_on,
        "success": all(s["success"] for s in subtasks),
        "subtasks_succeeded": sum(bool(s["success"]) for s in subtasks),
        "spl": r4(sum(s["spl"] for s in subtasks) / len(subtasks)),
        "steps": steps,
        "error": errors[0] if errors else None,
        **{k: v for k, v in shared.items() if k not in ("episode_id", "scene_seed", "agent")},
        "timing": {
            "wall_s": r4(time.perf_counter() - t0),
            "cpu_s": r4(time.process_time() - c0),
            "agent_ms_per_step": per_step("agent_ms_per_step"),
            "sim_ms_per_step": per_step("sim_ms_per_step"),
        },
        "subtasks": subtasks,
    }
    return record


# --- summary ---------------------------------------------------------------------------------


def subtask_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every subtask of the sequence records as a single-goal record would hold it: with its
    sequence's shared fields (home, agent, variant, ...) and ``ne`` as a float."""
    rows = []
    for r in records:
        shared = {k: r[k] for k in SEQUENCE_FIELDS if k in r}
        for s in r["subtasks"]:
            rows.append(
                {**shared, **s, "episode_id": s["subtask_id"], "sequence_id": r["episode_id"], "ne": float(s["ne"])}
            )
    return rows


def _group(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """SR, SPL (with intervals over homes), NE, Max-ST of some subtasks, without the categories."""
    block = aggregate(rows)
    block.pop("per_category")
    return block


def summarize_sequences(records: list[dict[str, Any]], spec: AgentSpec | None = None) -> dict[str, Any]:
    """summary.json of a multi-goal run: ``sr``, ``spl``, ``ne``, ``max_st`` and ``episodes``
    over all subtasks (``episodes`` counts subtasks, ``sequences`` sequences), per category;
    ``first_goal`` against ``later_goals``; ``by_goal_index``; ``by_kind`` (later goals);
    ``sequence`` (all goals reached, goals reached, mean SPL, steps); ``memory`` (whether the run
    used ``--memory``) and then ``memory_use`` (``memory_use``); and the agent's own summary
    (``spec.summarize``) over the subtasks."""
    rows = subtask_rows(records)
    out = aggregate(rows)
    homes = [r["scene_seed"] for r in records]
    seq_success = [float(bool(r["success"])) for r in records]
    seq_spl = [float(r["spl"]) for r in records]
    n = max(len(records), 1)
    out.update(
        {
            "sequences": len(records),
            "goals_per_sequence": sorted({int(r["goals"]) for r in records}),
            "subtask_budget": sorted({int(r["subtask_budget"]) for r in records}),
            "first_goal": _group([r for r in rows if r["goal_index"] == 0]),
            "later_goals": _group([r for r in rows if r["goal_index"] > 0]),
            "by_goal_index": {
                str(g): _group([r for r in rows if r["goal_index"] == g])
                for g in sorted({r["goal_index"] for r in rows})
            },
            "by_kind": {
                kind: _group([r for r in rows if r["goal_index"] > 0 and r["kind"] == kind])
                for kind in sorted({r["kind"] for r in rows if r["goal_index"] > 0})
            },
            "sequence": {
                "sequences": len(records),
                "homes": len(set(homes)),
                "all_goals_sr": sum(seq_success) / n,
                "all_goals_sr_ci95": list(bootstrap_ci(seq_success, homes)),
                "goals_reached": sum(int(r["subtasks_succeeded"]) for r in records) / n,
                "spl": sum(seq_spl) / n,
                "spl_ci95": list(bootstrap_ci(seq_spl, homes)),
                "steps": sum(int(r["steps"]) for r in records) / n,
            },
        }
    )
    out["memory"] = any(bool(r.get("memory")) for r in records)
    if out["memory"]:
        out["memory_use"] = memory_use(rows)
    if spec is not None and spec.summarize and rows:
        out.update(dict(spec.summarize(rows)))
    return out


def memory_use(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """What the memory gave the later goals (``subtask_rows`` of a ``--memory`` run): how many had a
    candidate from recall and skipped the look-around (shares of those whose goal began), the
    keyframes they started with (mean), recall's milliseconds (median) and the largest memory
    (keyframe bytes) at a subtask's end."""
    later = [r["memory"] for r in rows if r["goal_index"] > 0 and isinstance(r.get("memory"), dict)]
    began = [m for m in later if m.get("first_mode") is not None]
    n = max(len(began), 1)
    return {
        "later_goals": len(later),
        "recall_candidate_share": sum(bool(m["recall_candidate"]) for m in began) / n,
        "look_around_skipped_share": sum(bool(m["look_around_skipped"]) for m in began) / n,
        "keyframes_at_start_mean": sum(int(m["keyframes_at_start"]) for m in began) / n,
        "recall_ms_median": float(np.median([m["recall_ms"] for m in began])) if began else None,
        "keyframe_bytes_max": max((int(m["keyframe_bytes"]) for m in later), default=0),
    }
