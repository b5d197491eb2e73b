"""``imgnav eval --memory`` on multi-goal sets (issue 31), its records and refusals, with a
scripted agent: without ``--memory`` the records are today's plus ``memory: false``; ``--memory``
is refused on single-goal sets and for agents that keep no memory; a resumed run refuses to mix
sequences run with and without it. (The real agent with its memory:
tests/integration/sim_agent/test_memory_multigoal_eval.py.)"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from agent.memory import HomeMemory
from agent.types import Action, AgentRecord, Observation
from console.cli import main
from sim.evaluation import registry
from sim.evaluation.runner import run_evaluation

# a subtask's fields before --memory existed (test_sim_multigoal_eval.py's records)
SUBTASK_FIELDS = {
    "goal_index",
    "subtask_id",
    "kind",
    "of_goal",
    "goal_instance_id",
    "start_pose_world",
    "category",
    "success",
    "spl",
    "ne",
    "steps",
    "path_length_m",
    "shortest_path_m",
    "max_steps_reached",
    "called_stop",
    "stop_reason",
    "stop_to_viewpoint_m",
    "difficulty",
    "trajectory",
    "timing",
    "error",
}
SEQUENCE_RECORD_FIELDS = {
    "episode_id",
    "scene_seed",
    "agent",
    "goals",
    "subtask_budget",
    "success",
    "subtasks_succeeded",
    "spl",
    "steps",
    "error",
    "timing",
    "subtasks",
}


class _Turner:
    """Turns left until the budget ends the subtask; has a place for a memory of the home."""

    def __init__(self) -> None:
        self.home_memory: HomeMemory | None = None
        self._record: AgentRecord | None = None

    def reset(self, goal_image: np.ndarray) -> None:
        pass

    def act(self, obs: Observation) -> Action:
        self._record = AgentRecord(step=obs.step, action=Action.TURN_LEFT, pose=obs.pose, mode="test", reason="")
        return Action.TURN_LEFT

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record


@pytest.fixture(autouse=True)
def _turner_spec():
    spec = registry.AgentSpec(
        "test-turner", "turns left", lambda args, oracle: _Turner(), make_memory=lambda args: HomeMemory()
    )
    registry.register(spec)
    yield
    registry._REGISTRY.pop("test-turner", None)


def _records(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]


def test_without_memory_the_records_are_todays(small_sequence_set: Path, tmp_path: Path) -> None:
    summary = run_evaluation(
        small_sequence_set, "test-turner", argparse.Namespace(subtask_budget=2), tmp_path / "o", progress=False
    )
    records = _records(tmp_path / "o")
    assert len(records) == 2
    for rec in records:
        assert set(rec) == SEQUENCE_RECORD_FIELDS | {"memory"} and rec["memory"] is False
        assert all(set(s) == SUBTASK_FIELDS for s in rec["subtasks"])
    assert summary["memory"] is False and "memory_use" not in summary
    assert summary["first_goal"]["episodes"] == 2 and summary["later_goals"]["episodes"] == 4


def test_with_memory_every_subtask_records_the_memory(small_sequence_set: Path, tmp_path: Path) -> None:
    args = argparse.Namespace(subtask_budget=2, memory=True)
    summary = run_evaluation(small_sequence_set, "test-turner", args, tmp_path / "m", limit=1, progress=False)
    (rec,) = _records(tmp_path / "m")
    assert set(rec) == SEQUENCE_RECORD_FIELDS | {"memory"} and rec["memory"] is True
    for k, s in enumerate(rec["subtasks"]):
        assert set(s) == SUBTASK_FIELDS | {"memory"}
        # this agent never begins a goal in the memory: the frame is recorded, the goal's figures are None
        assert s["memory"]["frame_origin"][:2] == [0.0, 0.0]  # two left turns of 30 deg per subtask, in place
        assert s["memory"]["frame_origin"][2] == pytest.approx(math.remainder(k * math.radians(60), math.tau), abs=1e-4)
        assert s["memory"]["keyframes_at_start"] is None and s["memory"]["keyframes"] == 0
    assert summary["memory"] is True and summary["memory_use"]["later_goals"] == 2


def test_memory_is_refused_where_it_cannot_apply(
    small_sequence_set: Path, small_episode_set: Path, tmp_path: Path
) -> None:
    base = ["eval", "--agent", "oracle", "--memory"]
    # a single-goal set; an agent that keeps no memory of a home
    assert main([*base, "--episodes", str(small_episode_set), "--out", str(tmp_path / "a")]) == 2
    assert main([*base, "--episodes", str(small_sequence_set), "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b" / "episodes.jsonl").exists()
    # resuming never mixes sequences run with and without a memory
    for first, then in ((True, False), (False, True)):
        out = tmp_path / f"r-{first}"
        run_evaluation(
            small_sequence_set,
            "test-turner",
            argparse.Namespace(subtask_budget=2, memory=first),
            out,
            limit=1,
            progress=False,
        )
        before = (out / "episodes.jsonl").read_text()
        with pytest.raises(ValueError, match="--memory"):
            run_evaluation(
                small_sequence_set,
                "test-turner",
                argparse.Namespace(subtask_budget=2, memory=then),
                out,
                progress=False,
            )
        assert (out / "episodes.jsonl").read_text() == before
