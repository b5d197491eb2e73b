"""`imgnav eval` on multi-goal sets (issue 31): every subtask scored from where the last one
ended, with its own budget; one record per sequence; resume; the oracle reaches every goal."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from agent.types import Action, AgentRecord, Observation, Pose2D
from console.cli import main
from sim.evaluation import registry
from sim.evaluation.multigoal import SubtaskHandoff, agent_for_goal, run_sequence
from sim.evaluation.runner import run_evaluation
from sim.navigation import GRID_RESOLUTION_M, geodesic_at, geodesic_field
from sim.sequences import load_sequence_set
from sim.world import SimWorld

MADE: list[object] = []  # agents made by the throwaway spec, in order


class _Spinner:
    """Turns left forever (so only the budget ends a subtask), or stops after ``stop_after``."""

    def __init__(self, stop_after: int | None = None) -> None:
        self.stop_after, self.k, self._record = stop_after, 0, None
        MADE.append(self)

    def reset(self, goal_image: np.ndarray) -> None:
        self.k = 0

    def act(self, obs: Observation) -> Action:
        action = Action.STOP if self.stop_after is not None and self.k >= self.stop_after else Action.TURN_LEFT
        self._record = AgentRecord(step=obs.step, action=action, pose=obs.pose, mode="test", reason="")
        self.k += 1
        return action

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record


@pytest.fixture(autouse=True)
def _spinner_spec():
    registry.register(registry.AgentSpec("test-spinner", "turns left", lambda args, oracle: _Spinner()))
    MADE.clear()
    yield
    registry._REGISTRY.pop("test-spinner", None)


def _poses(sub: dict) -> list[list[float]]:
    return sub["trajectory"]["poses_world"]


def test_the_oracle_reaches_every_goal_of_a_sequence(small_sequence_set: Path, tmp_path: Path) -> None:
    """The solvability check: ``--agent oracle`` on a sequence succeeds on every subtask, each
    starting where the one before ended (the chain the generator checked)."""
    out = tmp_path / "oracle"
    argv = ["eval", "--episodes", str(small_sequence_set), "--agent", "oracle", "--limit", "1", "--out", str(out)]
    assert main(argv) == 0
    (rec,) = [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]
    subs = rec["subtasks"]
    assert rec["goals"] == len(subs) == 3 and rec["subtask_budget"] == 1000
    assert [s["goal_index"] for s in subs] == [0, 1, 2]
    assert all(s["success"] and s["stop_reason"] == "stop" and s["spl"] >= 0.8 for s in subs), subs
    assert rec["success"] and rec["subtasks_succeeded"] == 3
    assert rec["steps"] == sum(s["steps"] for s in subs)
    for prev, sub in zip(subs, subs[1:], strict=False):
        assert _poses(sub)[0] == _poses(prev)[-1] == sub["start_pose_world"]
        assert sub["shortest_path_m"] > 0.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sequences"] == 1 and summary["episodes"] == 3 and summary["sr"] == 1.0
    assert summary["first_goal"]["sr"] == summary["later_goals"]["sr"] == 1.0
    assert summary["first_goal"]["episodes"] == 1 and summary["later_goals"]["episodes"] == 2
    assert summary["sequence"]["all_goals_sr"] == 1.0 and summary["sequence"]["goals_reached"] == 3.0
    # throughput per sequence and per subtask (issue 32); CPU seconds in the sequence and its subtasks
    t = summary["throughput"]
    assert t["sequences"] == 1 and t["subtasks"] == 3 and t["workers"] == 1 and t["scene_builds"] == 1
    assert t["subtasks_per_cpu_hour"] == pytest.approx(3 * t["sequences_per_cpu_hour"], rel=1e-3)
    assert t["cpu_s"] > 0 and 0 < t["busy_share"] <= 1 and t["subtasks_per_wall_hour"] > 0
    assert rec["timing"]["cpu_s"] >= sum(s["timing"]["cpu_s"] for s in subs) > 0


def test_each_subtask_has_its_budget_and_starts_where_the_last_ended(small_sequence_set: Path, tmp_path: Path) -> None:
    args = argparse.Namespace(subtask_budget=3)
    summary = run_evaluation(small_sequence_set, "test-spinner", args, tmp_path / "s", limit=1, progress=False)
    (rec,) = [json.loads(x) for x in (tmp_path / "s" / "episodes.jsonl").read_text().splitlines()]
    seq = load_sequence_set(small_sequence_set).episodes[0]
    subs = rec["subtasks"]
    assert rec["subtask_budget"] == 3 and len(subs) == 3 and not rec["success"]
    for s in subs:  # the budget ends every subtask, not the sequence's first one only
        assert s["steps"] == 3 and s["max_steps_reached"] and s["stop_reason"] == "max_steps" and not s["success"]
    # subtask k starts where k - 1 ended: three left turns of 30 deg later, at the same spot
    start = seq.start_pose_world
    assert _poses(subs[0])[0] == [start.x_m, start.y_m, start.yaw_rad]
    world = SimWorld.from_seed(seq.scene_seed)
    try:
        grid = world.navigable_grid(GRID_RESOLUTION_M)
        for k in (1, 2):
            x, y, yaw = subs[k]["start_pose_world"]
            assert _poses(subs[k])[0] == _poses(subs[k - 1])[-1] == [x, y, yaw]
            turned = math.remainder(yaw - start.yaw_rad - k * math.radians(90), 2 * math.pi)
            assert (x, y) == (start.x_m, start.y_m) and abs(turned) < 1e-3
            # SPL's shortest path is the later goal's from this actual start, not the first start's
            field = geodesic_field(grid, seq.goals[k].viewpoints_array())
            assert subs[k]["shortest_path_m"] == pytest.approx(geodesic_at(field, grid, x, y), abs=1e-3)
    finally:
        world.close()
    assert len(MADE) == 3 and len({id(a) for a in MADE}) == 3  # a fresh agent per goal, for now
    assert summary["first_goal"]["sr"] == 0.0 and summary["later_goals"]["episodes"] == 2
    assert summary["max_st"] == 1.0 and summary["subtask_budget"] == [3]


def test_a_finished_sequence_is_skipped_on_resume(small_sequence_set: Path, tmp_path: Path) -> None:
    out = tmp_path / "r"
    args = argparse.Namespace(subtask_budget=2)
    run_evaluation(small_sequence_set, "test-spinner", args, out, limit=1, progress=False)
    first = (out / "episodes.jsonl").read_text().splitlines()
    assert len(first) == 1 and len(MADE) == 3
    summary = run_evaluation(small_sequence_set, "test-spinner", args, out, limit=2, progress=False)
    lines = (out / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 2 and lines[0] == first[0]  # kept as it was
    assert len({json.loads(x)["episode_id"] for x in lines}) == 2
    assert len(MADE) == 6 and summary["sequences"] == 2 and summary["episodes"] == 6
    run_evaluation(small_sequence_set, "test-spinner", args, out, limit=2, progress=False)
    assert len(MADE) == 6 and len((out / "episodes.jsonl").read_text().splitlines()) == 2  # nothing re-run
    # sequences run with another budget are not mixed in, nor is the budget taken for a single-goal set
    with pytest.raises(ValueError, match="subtask-budget"):
        run_evaluation(small_sequence_set, "test-spinner", argparse.Namespace(subtask_budget=5), out, progress=False)


def test_the_hook_gets_the_previous_agent_and_where_it_stopped(small_sequence_set: Path) -> None:
    """``agent_for_goal`` is where memory will plug in: each goal's call gets the agent of the
    goal before and the previous end pose in the previous subtask's frame."""
    ss = load_sequence_set(small_sequence_set)
    seq = ss.episodes[0]
    spec = registry.AgentSpec("test-stopper", "turns twice, stops", lambda args, oracle: _Spinner(stop_after=2))
    calls: list[tuple[object | None, SubtaskHandoff]] = []

    def hook(previous, spec_, args, oracle, handoff):
        calls.append((previous, handoff))
        return agent_for_goal(previous, spec_, args, oracle, handoff)

    world = SimWorld.from_seed(seq.scene_seed)
    try:
        images = [ss.goal_image_path(seq, k) for k in range(len(seq.goals))]
        rec = run_sequence(world, seq, images, spec, argparse.Namespace(), next_agent=hook)
    finally:
        world.close()
    assert [s["steps"] for s in rec["subtasks"]] == [3, 3, 3]  # two turns and STOP each
    assert [h.goal_index for _, h in calls] == [0, 1, 2]
    assert calls[0] == (None, SubtaskHandoff(0, None))
    for k in (1, 2):
        previous, handoff = calls[k]
        assert previous is MADE[k - 1]
        end = handoff.previous_end_pose
        assert isinstance(end, Pose2D) and abs(end.x_m) < 1e-9 and abs(end.y_m) < 1e-9
        assert end.yaw_rad == pytest.approx(math.radians(60))


def test_subtask_budget_is_for_multi_goal_sets_only(small_episode_set: Path, tmp_path: Path) -> None:
    argv = ["eval", "--episodes", str(small_episode_set), "--agent", "oracle", "--subtask-budget", "10"]
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
