"""Multi-goal sets (``imgnav episodes --goals N``, issue 31): deterministic files, goals of the
kinds they claim, single-goal sets untouched."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from console.cli import main
from sim.episodes import load_episode_set
from sim.sequence_gen import SequenceGenConfig, generate_sequence_set
from sim.sequences import load_any_set, load_sequence_set, subtask_id
from sim.world import SimWorld


def _files(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_same_seed_gives_an_identical_multi_goal_set(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    argv = ["episodes", "--split", "train", "--seed", "11", "--count", "1", "--goals", "2"]
    assert main([*argv, "--out", str(a)]) == 0
    assert main([*argv, "--out", str(b)]) == 0
    files = _files(a)
    assert files == _files(b)
    seq = load_sequence_set(a).episodes[0]
    assert sorted(files) == [
        "episodes.json",
        f"goals/{subtask_id(seq.episode_id, 0)}.png",
        f"goals/{subtask_id(seq.episode_id, 1)}.png",
    ]
    doc = json.loads(files["episodes.json"])
    assert doc["format"] == "imgnav-sequences" and doc["goals_per_episode"] == 2 and doc["count"] == 1
    # the stored first start and shortest path are a single-goal episode's (the later starts are
    # not stored: they are where the robot ends up)
    assert seq.geodesic_distance_m >= 1.5 and "start_pose_world" not in doc["episodes"][0]["goals"][1]
    # a multi-goal set is no single-goal set: a clear error, not a KeyError
    with pytest.raises(ValueError, match="multi-goal"):
        load_episode_set(a)


def test_goals_are_of_the_kind_they_claim(small_sequence_set: Path) -> None:
    ss = load_any_set(small_sequence_set)
    assert len(ss) == 2 and len({s.scene_seed for s in ss}) == 1
    world = SimWorld.from_seed(ss.episodes[0].scene_seed)
    try:
        for seq in ss:
            assert len(seq.goals) == 3 and seq.goals[0].kind == "new" and seq.goals[0].of_goal is None
            assert not world.collides(seq.start_pose_world.x_m, seq.start_pose_world.y_m)
            for k, goal in enumerate(seq.goals):
                assert len(goal.viewpoints_xy_m) >= 8
                assert world.home.instance(goal.goal_instance_id).category == goal.goal_category
                assert ss.load_goal_image(seq, k).shape == (512, 512, 3)
                earlier = seq.goals[:k]
                if goal.kind == "new":
                    assert goal.goal_category not in {g.goal_category for g in earlier}
                elif goal.kind == "lookalike":
                    assert goal.of_goal is not None and seq.goals[goal.of_goal].goal_category == goal.goal_category
                    assert goal.goal_instance_id not in {g.goal_instance_id for g in earlier}
                else:
                    assert goal.kind == "repeat" and goal.of_goal is not None and goal.of_goal <= k - 2
                    assert seq.goals[goal.of_goal].goal_instance_id == goal.goal_instance_id
            # consecutive goals differ (a repeat of the goal just before would be there already)
            ids = [g.goal_instance_id for g in seq.goals]
            assert all(x != y for x, y in zip(ids, ids[1:], strict=False))
    finally:
        world.close()


def test_a_repeat_is_a_new_photo_from_elsewhere(tmp_path: Path) -> None:
    cfg = SequenceGenConfig(goals=3, repeat_share=1.0)
    (seq,) = generate_sequence_set("train", 12, 1, tmp_path, cfg, progress=False)
    kinds = [g.kind for g in seq.goals]
    # goal 1 cannot repeat goal 0 (the robot stands at it), so a new goal comes first
    assert kinds == ["new", "new", "repeat"] and seq.goals[2].of_goal == 0
    assert seq.goals[2].goal_instance_id == seq.goals[0].goal_instance_id
    eye0, eye2 = (np.asarray(seq.goals[i].info["goal_camera"]["eye_xyz_m"]) for i in (0, 2))
    assert math.dist(eye0, eye2) >= cfg.repeat_min_eye_shift_m
    ss = load_sequence_set(tmp_path)
    assert not np.array_equal(ss.load_goal_image(seq, 0), ss.load_goal_image(seq, 2))


def test_goals_1_is_the_single_goal_set(tmp_path: Path) -> None:
    argv = ["episodes", "--split", "val", "--seed", "7", "--count", "1", "--per-scene", "1"]
    assert main([*argv, "--out", str(tmp_path / "plain")]) == 0
    assert main([*argv, "--goals", "1", "--out", str(tmp_path / "one")]) == 0
    assert _files(tmp_path / "plain") == _files(tmp_path / "one")
    assert json.loads((tmp_path / "one" / "episodes.json").read_text())["format"] == "imgnav-episodes"
    assert main([*argv, "--goals", "0", "--out", str(tmp_path / "none")]) == 2
