"""The evaluation runner's agent registry and hooks, with throwaway agents."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from agent.types import Action, AgentRecord, Observation
from sim.evaluation import registry
from sim.evaluation.runner import run_evaluation


class _TurnThenStop:
    def __init__(self, turns: int, explode: bool = False) -> None:
        self.turns, self.explode, self.k, self._record = turns, explode, 0, None

    def reset(self, goal_image: np.ndarray) -> None:
        self.k = 0

    def act(self, obs: Observation) -> Action:
        if self.explode and self.k == 1:
            raise RuntimeError("planner exploded")
        action = Action.TURN_LEFT if self.k < self.turns else Action.STOP
        self._record = AgentRecord(
            step=obs.step, action=action, pose=obs.pose, mode="test", reason="", reid_score=0.1 * self.k
        )
        self.k += 1
        return action

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record


class _Observer:
    def __init__(self, args, episode, oracle) -> None:
        self.scores: list[float] = []
        self.goal_pixels = 0
        self.oracle = oracle

    def on_step(self, obs, action, record) -> None:
        self.scores.append(record.reid_score)
        self.goal_pixels += int(self.oracle.goal_mask().sum())

    def finish(self, episode_record):
        return {
            "failure_cause": "never moved" if episode_record["path_length_m"] == 0 else "other",
            "max_reid": max(self.scores),
            "goal_pixels_seen": self.goal_pixels,
        }


@pytest.fixture(autouse=True)
def _specs():
    registry.register(
        registry.AgentSpec(
            "test-turner",
            "turns then stops",
            lambda args, oracle: _TurnThenStop(args.turner_turns),
            add_arguments=lambda g: g.add_argument("--turner-turns", type=int, default=2),
            make_observer=_Observer,
            summarize=lambda recs: {"causes": sorted({r["failure_cause"] for r in recs})},
        )
    )
    registry.register(
        registry.AgentSpec("test-exploder", "raises", lambda args, oracle: _TurnThenStop(3, explode=True))
    )
    yield
    registry._REGISTRY.pop("test-turner", None)
    registry._REGISTRY.pop("test-exploder", None)


def test_hooks_add_fields_to_records_and_summary(small_episode_set: Path, tmp_path: Path) -> None:
    args = argparse.Namespace(turner_turns=3)
    summary = run_evaluation(small_episode_set, "test-turner", args, tmp_path / "t", limit=2, progress=False)
    recs = [json.loads(x) for x in (tmp_path / "t" / "episodes.jsonl").read_text().splitlines()]
    assert [r["steps"] for r in recs] == [4, 4] and all(not r["success"] for r in recs)
    assert all(r["failure_cause"] == "never moved" and r["max_reid"] == pytest.approx(0.3) for r in recs)
    assert all(r["goal_pixels_seen"] >= 0 for r in recs)
    assert summary["causes"] == ["never moved"] and summary["sr"] == 0.0 and summary["episodes"] == 2
    # another agent cannot append to these results
    with pytest.raises(ValueError):
        run_evaluation(small_episode_set, "oracle", args, tmp_path / "t", limit=2, progress=False)


def test_agent_errors_are_recorded_not_swallowed(small_episode_set: Path, tmp_path: Path) -> None:
    summary = run_evaluation(
        small_episode_set, "test-exploder", argparse.Namespace(), tmp_path / "e", limit=1, progress=False
    )
    rec = json.loads((tmp_path / "e" / "episodes.jsonl").read_text())
    assert rec["error"] == "RuntimeError: planner exploded" and rec["stop_reason"] == "error" and not rec["success"]
    assert summary["errors"] == 1
    with pytest.raises(RuntimeError):
        run_evaluation(
            small_episode_set,
            "test-exploder",
            argparse.Namespace(),
            tmp_path / "f",
            limit=1,
            progress=False,
            fail_fast=True,
        )


def test_plugins_are_optional_but_not_their_imports(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(registry, "PLUGIN_MODULES", ("sim.evaluation.no_such_plugin",))
    monkeypatch.setattr(registry, "_plugins_loaded", False)
    registry.load_plugins()  # a missing plugin module is skipped
    assert "oracle" in registry.agent_names()
