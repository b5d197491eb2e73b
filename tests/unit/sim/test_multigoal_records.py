"""Multi-goal sequences (issue 31) on hand-built data: the file's round trip, a subtask as a
single-goal episode, and the summary of sequence records (first goal against later goals)."""

from __future__ import annotations

from typing import Any

import pytest

from agent.types import Pose2D
from sim.evaluation.multigoal import subtask_rows, summarize_sequences
from sim.evaluation.registry import AgentSpec
from sim.sequences import SequenceEpisode, SequenceGoal


def _sequence() -> SequenceEpisode:
    goals = (
        SequenceGoal(3, "chair", "goals/s-g0.png", ((1.0, 2.0), (1.1, 2.0)), "new", None, {"goal_camera": {"a": 1}}),
        SequenceGoal(5, "bed", "goals/s-g1.png", ((4.0, 4.0),), "new"),
        SequenceGoal(4, "chair", "goals/s-g2.png", ((0.5, 0.5),), "lookalike", 0),
        SequenceGoal(3, "chair", "goals/s-g3.png", ((1.0, 2.0),), "repeat", 0, {"goal_camera": {"a": 2}}),
    )
    return SequenceEpisode("s", "val", 100, Pose2D(1.5, -2.0, 0.25), 3.2, goals, {"difficulty": "easy"})


def test_a_sequence_round_trips_and_its_subtasks_are_episodes() -> None:
    seq = _sequence()
    again = SequenceEpisode.from_json(seq.to_json())
    assert again == seq and again.goals[3].info == {"goal_camera": {"a": 2}}
    # goal k starts wherever it is told (where the robot ended goal k - 1)
    here = Pose2D(7.0, 1.0, -1.0)
    ep = seq.subtask(3, here, 2.5)
    assert ep.episode_id == "s-g3" and ep.start_pose_world == here and ep.geodesic_distance_m == 2.5
    assert ep.goal_instance_id == 3 and ep.goal_image == "goals/s-g3.png" and ep.viewpoints_xy_m == ((1.0, 2.0),)
    assert ep.info["goal_camera"] == {"a": 2} and ep.info["kind"] == "repeat" and ep.info["of_goal"] == 0
    assert "difficulty" not in ep.info and seq.subtask(0, seq.start_pose_world, 3.2).info["difficulty"] == "easy"
    with pytest.raises(ValueError, match="malformed sequence"):
        SequenceEpisode.from_json({**seq.to_json(), "goals": []})


def _sub(k: int, success: bool, kind: str = "new") -> dict[str, Any]:
    return {
        "goal_index": k,
        "subtask_id": f"g{k}",
        "kind": kind,
        "category": "chair",
        "success": success,
        "spl": 0.5 if success else 0.0,
        "ne": 0.05 if success else "inf",
        "steps": 10,
        "max_steps_reached": not success,
        "failure_cause": None if success else "exploration",
    }


def _record(seq: str, home: int, subs: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "episode_id": seq,
        "scene_seed": home,
        "agent": "x",
        "variant": "v1",
        "goals": len(subs),
        "subtask_budget": 500,
        "success": all(s["success"] for s in subs),
        "subtasks_succeeded": sum(s["success"] for s in subs),
        "spl": sum(s["spl"] for s in subs) / len(subs),
        "steps": sum(s["steps"] for s in subs),
        "subtasks": subs,
    }


def test_the_summary_sets_the_first_goal_against_the_later_ones() -> None:
    # three homes: the first goal always fails, the later ones succeed but for one repeat
    records = [
        _record("a", 1, [_sub(0, False), _sub(1, True), _sub(2, True, "repeat")]),
        _record("b", 2, [_sub(0, False), _sub(1, True), _sub(2, False, "repeat")]),
        _record("c", 3, [_sub(0, False), _sub(1, True, "lookalike"), _sub(2, True)]),
    ]
    seen: list[list[dict[str, Any]]] = []

    def agent_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
        seen.append(rows)
        return {"failure_causes": sorted({r["failure_cause"] for r in rows if r["failure_cause"]})}

    spec = AgentSpec("x", "", lambda a, o: None, summarize=agent_summary)  # type: ignore[arg-type,return-value]
    s = summarize_sequences(records, spec)
    assert s["sequences"] == 3 and s["episodes"] == 9 and s["homes"] == 3
    assert s["sr"] == pytest.approx(5 / 9) and s["ne_unreachable"] == 4
    first, later = s["first_goal"], s["later_goals"]
    assert first["episodes"] == 3 and first["sr"] == 0.0 and first["sr_ci95"] == [0.0, 0.0]
    assert later["episodes"] == 6 and later["sr"] == pytest.approx(5 / 6) and later["spl"] == pytest.approx(5 / 12)
    lo, hi = later["sr_ci95"]
    assert 0.0 < lo <= 5 / 6 <= hi == 1.0 and later["homes"] == 3 and "spl_ci95" in later
    assert s["by_goal_index"]["2"]["sr"] == pytest.approx(2 / 3)
    assert s["by_kind"]["repeat"]["episodes"] == 2 and s["by_kind"]["repeat"]["sr"] == 0.5
    assert "new" in s["by_kind"] and s["by_kind"]["lookalike"]["sr"] == 1.0
    seq = s["sequence"]
    assert seq["all_goals_sr"] == 0.0 and seq["goals_reached"] == pytest.approx(5 / 3) and seq["homes"] == 3
    assert seq["spl_ci95"][0] <= seq["spl"] <= seq["spl_ci95"][1] and seq["steps"] == 30
    assert s["goals_per_sequence"] == [3] and s["subtask_budget"] == [500]
    # the agent's own summary gets every subtask as a single-goal record, with its sequence's fields
    assert s["failure_causes"] == ["exploration"] and len(seen[0]) == 9
    assert all(r["variant"] == "v1" and r["scene_seed"] in (1, 2, 3) for r in seen[0])
    assert [r["episode_id"] for r in subtask_rows(records[:1])] == ["g0", "g1", "g2"]
