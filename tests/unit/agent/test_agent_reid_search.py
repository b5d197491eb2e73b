"""Search cheaply, verify richly (issue 32): searching frames at a reduced setting (fewer pixels and
keypoints) with their own tau and gate thresholds, the rest at the full setting; the settings'
resolution from the calibration file, keypoints back in the frame's pixels, the policy reading each
frame against its own setting's tau, and the full setting twice being today's agent exactly."""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import numpy as np
import pytest

from agent.config import AgentConfig, PolicyConfig
from agent.memory import HomeMemory
from agent.policy import ModIINAgent
from agent.reid import Features, Matches, ReIDConfig, ReIdentifier
from agent.reid.base import extract_at
from agent.reid.identifier import on_full_scale, resolve_exit_threshold, resolve_gate_threshold, resolve_search
from agent.segmentation import SegmentationConfig
from agent.types import Pose2D
from tests.helpers.agent_runs import run_decisions
from tests.helpers.agent_scenes import GOAL_RGB, PaintedWorld, two_rooms
from tests.helpers.reid_views import goal_and_views


class PaintMatcher:
    """Keypoints on the goal's red pixels (row-major, at most ``max_keypoints``); every goal
    keypoint matches a frame keypoint with confidence 1, so a frame scores its red keypoints (at
    most the goal's). Keeps the (height, width) of every image it extracted."""

    name = "paint"

    def __init__(self) -> None:
        self.sizes: list[tuple[int, int]] = []

    def extract(self, rgb, max_keypoints):
        self.sizes.append(rgb.shape[:2])
        yx = np.argwhere(np.all(rgb == GOAL_RGB, axis=2))[:max_keypoints]
        # identical descriptors: the gate's mutual-nearest count is 1 for any frame with a keypoint
        return Features(yx[:, ::-1].astype(np.float32), np.ones((len(yx), 4), np.float32), (rgb.shape[1], rgb.shape[0]))

    def match(self, goal, obs):
        i = np.arange(min(len(goal), len(obs)), dtype=np.int64)
        return Matches(i, i, np.ones(len(i), np.float32))


class RedGoalWorld(PaintedWorld):
    """The painted two-room world with a red goal photo (what ``PaintMatcher`` matches)."""

    def observe(self):
        obs = super().observe()
        obs.goal_image[:] = GOAL_RGB
        return obs


def calibration(tmp_path, search: dict | None = None, **full) -> str:
    data = {"matcher": "xfeat_lighterglue", "score": "conf", "tau": 75.0, "gate_threshold": 20.0}
    data.update(gate_min_cosine=0.82, gate_exit_layer=2, gate_exit_threshold=6.0, **full)
    if search is not None:
        data["search"] = search
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(data))
    return str(path)


SEARCH_BLOCK = {
    "max_side_px": 480,
    "max_keypoints": 512,
    "goal_max_side_px": 640,
    "goal_max_keypoints": 1024,
    "tau": 40.0,
    "gate_threshold": 11.0,
    "gate_min_cosine": 0.82,
    "gate_exit_layer": 2,
    "gate_exit_threshold": 3.5,
}


# --- the settings ------------------------------------------------------------------------------


def test_the_search_setting_resolves_from_its_own_block_of_the_calibration(tmp_path, caplog):
    cal = calibration(tmp_path, SEARCH_BLOCK)
    cfg = ReIDConfig(calibration_file=cal, search_max_side_px=480, search_max_keypoints=512)
    s = resolve_search(cfg)
    assert s is not None and (s.name, s.max_side_px, s.max_keypoints) == ("search", 480, 512)
    assert (s.tau, s.gate_threshold, s.exit_threshold) == (40.0, 11.0, 3.5)
    # the full setting's thresholds are untouched by the block
    assert (resolve_gate_threshold(cfg), resolve_exit_threshold(cfg)) == (20.0, 6.0)
    # explicit values win, and need no block
    explicit = dataclasses.replace(cfg, search_tau=45.0, search_gate_threshold=9.0, search_gate_exit_threshold=2.0)
    s = resolve_search(explicit)
    assert s is not None and (s.tau, s.gate_threshold, s.exit_threshold) == (45.0, 9.0, 2.0)
    # an explicit search tau below the block's: the block's gate stages are off (with a warning), never wrong
    with caplog.at_level(logging.WARNING):
        s = resolve_search(dataclasses.replace(cfg, search_tau=30.0))
    assert s is not None and (s.tau, s.gate_threshold, s.exit_threshold) == (30.0, None, None)
    assert "reid.search_tau 30 is below the tau 40" in caplog.text
    # a block calibrated after another exit layer: the exit stage is off
    other_layer = calibration(tmp_path, {**SEARCH_BLOCK, "gate_exit_layer": 3})
    s = resolve_search(dataclasses.replace(cfg, calibration_file=other_layer))
    assert s is not None and (s.gate_threshold, s.exit_threshold) == (11.0, None)
    # the gate off: no gate stages in either setting
    s = resolve_search(dataclasses.replace(cfg, gate=False))
    assert s is not None and (s.tau, s.gate_threshold, s.exit_threshold) == (40.0, None, None)


def test_the_search_setting_equal_to_the_full_one_is_the_full_one(tmp_path):
    cal = calibration(tmp_path, SEARCH_BLOCK)
    for cfg in (
        ReIDConfig(calibration_file=cal),
        ReIDConfig(calibration_file=cal, search_max_side_px=640, search_max_keypoints=1024),
    ):
        assert resolve_search(cfg) is None
    with pytest.raises(ValueError, match="search setting is the full one"):
        resolve_search(ReIDConfig(calibration_file=cal, search_tau=40.0))
    with pytest.raises(ValueError, match="within the full one"):
        resolve_search(ReIDConfig(calibration_file=cal, search_max_side_px=800))
    with pytest.raises(ValueError, match="within the full one"):
        resolve_search(ReIDConfig(calibration_file=cal, search_max_keypoints=2048))


def test_a_calibration_without_a_search_block_or_for_another_setting(tmp_path, caplog):
    # no block (an operator's own calibration): warning, searching frames get the full setting
    no_block = ReIDConfig(calibration_file=calibration(tmp_path), search_max_side_px=480, search_max_keypoints=512)
    with caplog.at_level(logging.WARNING):
        assert resolve_search(no_block) is None
    assert "has no tau for them" in caplog.text and "the search setting is off" in caplog.text
    # a block for another setting: a clear error (frames or the goal)
    cal = calibration(tmp_path, SEARCH_BLOCK)
    for wrong in (
        ReIDConfig(calibration_file=cal, search_max_side_px=320, search_max_keypoints=512),
        ReIDConfig(calibration_file=cal, search_max_side_px=480, search_max_keypoints=256),
        ReIDConfig(calibration_file=cal, search_max_side_px=480, search_max_keypoints=512, goal_max_keypoints=512),
    ):
        with pytest.raises(ValueError, match="imgnav calibrate --search"):
            resolve_search(wrong)
    # an explicit search tau with a block without gate thresholds: the search gate is off, with a warning
    bare = calibration(tmp_path, {k: v for k, v in SEARCH_BLOCK.items() if not k.startswith("gate")})
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        s = resolve_search(dataclasses.replace(no_block, calibration_file=bare, search_tau=40.0))
    assert s is not None and (s.tau, s.gate_threshold, s.exit_threshold) == (40.0, None, None)
    assert "has no gate_threshold" in caplog.text and "has no gate_exit_threshold" in caplog.text


def test_scores_move_to_the_full_scale_as_shares_of_tau_and_never_across_it():
    assert on_full_scale(33.3, 75.0, 75.0) == 33.3  # one setting: the score itself
    assert on_full_scale(20.0, 40.0, 80.0) == pytest.approx(40.0)
    for tau_s, tau_f in ((40.1, 75.3), (3.0, 7.0), (0.3, 0.7)):
        for k in range(1, 2000):
            s = tau_s * k / 1000.0
            full = on_full_scale(s, tau_s, tau_f)
            assert (full >= tau_f) == (s >= tau_s)
        assert on_full_scale(tau_s, tau_s, tau_f) >= tau_f
        assert on_full_scale(np.nextafter(tau_s, 0.0), tau_s, tau_f) < tau_f


# --- extraction -----------------------------------------------------------------------------------


def test_keypoints_of_a_reduced_setting_are_in_the_frames_own_pixels():
    rgb = np.zeros((160, 90, 3), np.uint8)
    rgb[40:80, 20:60] = GOAL_RGB
    m = PaintMatcher()
    full = extract_at(m, rgb, 160, 10_000)
    half = extract_at(m, rgb, 80, 10_000)
    assert m.sizes == [(160, 90), (80, 45)]
    assert half.image_size_wh == full.image_size_wh == (90, 160)
    # the reduced frame's red pixels, scaled back by 2, cover the same square
    assert len(half) == pytest.approx(len(full) / 4, rel=0.1)
    lo, hi = half.keypoints_xy.min(axis=0), half.keypoints_xy.max(axis=0)
    assert np.all(np.abs(lo - [20, 40]) <= 2) and np.all(np.abs(hi - [58, 78]) <= 2)


def test_a_match_at_the_search_setting_localises_to_the_same_pixels():
    """XFeat + LighterGlue: a view of the goal at 320 px / 512 keypoints (half the frame's side)
    against the goal at the full setting: its matched keypoints, in the frame's own 360 x 640
    pixels, follow the known warp nearly as well as at the full setting."""
    goal, same, _, to_view = goal_and_views()
    reid = ReIdentifier(
        ReIDConfig(tau=1.0, num_threads=1, gate=False, search_max_side_px=320, search_max_keypoints=512, search_tau=1.0)
    )
    reid.set_goal(goal)
    full, search = reid.compare(same, setting="full"), reid.compare(same, setting="search")
    assert (full.setting, search.setting) == ("full", "search")
    assert full.features is not None and search.features is not None
    assert search.features.image_size_wh == full.features.image_size_wh == (360, 640)
    assert len(search.features) <= 512 and search.features.extra["size_resized_wh"] == (180, 320)
    assert len(search.matches) >= 50
    err_full = np.linalg.norm(to_view(full.goal_xy) - full.obs_xy, axis=1)
    err_search = np.linalg.norm(to_view(search.goal_xy) - search.obs_xy, axis=1)
    # at half the side a keypoint is placed to about twice the pixels: within 12 px of the warp
    assert np.mean(err_search < 12.0) > 0.8
    assert np.median(err_search) < 2.5 * max(np.median(err_full), 1.0)
    # the search setting's keypoints span the frame, not its top-left quarter
    assert search.obs_xy[:, 0].max() > 200 and search.obs_xy[:, 1].max() > 400


def test_the_identifier_extracts_and_gates_each_setting_apart():
    calls = []

    class Counting(PaintMatcher):
        def extract(self, rgb, max_keypoints):
            calls.append(max_keypoints)
            return super().extract(rgb, max_keypoints)

    cfg = ReIDConfig(
        tau=100.0, gate=True, gate_threshold=5.0, gate_exit_threshold=6.0, max_side_px=160, obs_max_keypoints=300,
        goal_max_keypoints=400, search_max_side_px=80, search_max_keypoints=50, search_tau=25.0,
        search_gate_threshold=2.0, search_gate_exit_threshold=3.0,
    )  # fmt: skip
    reid = ReIdentifier(cfg, matcher=Counting(), min_score_ratio=0.5)
    # each setting's thresholds, scaled to potential evidence; no exit stage without exit layers
    assert (reid.full.gate_threshold, reid.search.gate_threshold) == (2.5, 1.0)
    assert (reid.full.exit_threshold, reid.search.exit_threshold) == (None, None)
    assert reid.search.tau == 25.0 and reid.full.tau is None and reid.gate_threshold == 2.5
    goal = np.zeros((64, 64, 3), np.uint8)
    goal[:] = GOAL_RGB
    reid.set_goal(goal)
    frame = np.zeros((160, 90, 3), np.uint8)
    frame[20:140, 10:80] = GOAL_RGB
    gated_full = reid.compare(frame, setting="full")  # gate score 1 < 2.5: stopped
    r_search = reid.compare(frame, setting="search")  # 1 >= 1.0: matched
    r_full = reid.compare(frame, use_gate=False, setting="full")
    assert calls == [400, 300, 50, 300]
    assert (gated_full.full_matcher, gated_full.score, gated_full.gate_score) == (False, 0.0, 1.0)
    assert (r_search.setting, r_search.score, r_search.full_matcher) == ("search", 50.0, True)
    assert (r_full.setting, r_full.score) == ("full", 300.0)
    assert reid.matcher.sizes[1:] == [(160, 90), (80, 45), (160, 90)]
    # equal settings: one setting (the same object), searching frames scored as full ones
    plain = dataclasses.replace(
        cfg, search_max_side_px=None, search_max_keypoints=None, search_tau=None, search_gate_threshold=None,
        search_gate_exit_threshold=None,
    )  # fmt: skip
    one = ReIdentifier(plain, matcher=PaintMatcher(), min_score_ratio=0.5)
    assert one.search is one.full
    one.set_goal(goal)
    assert one.compare(frame, use_gate=False, setting="search").setting == "full"


# --- the policy -----------------------------------------------------------------------------------


def paint_agent(**reid) -> tuple[ModIINAgent, PaintMatcher]:
    """The painted world's agent with the paint matcher through the real identifier: tau 100,
    potential evidence at tau/2, gate off; frames 90 x 160 (the full setting's side 160)."""
    matcher = PaintMatcher()
    cfg = AgentConfig(
        reid=ReIDConfig(tau=100.0, gate=False, max_side_px=160, **reid),
        policy=PolicyConfig(reid_source="matcher", localisation_source="goal_mask", potential_tau_ratio=0.5),
        segmentation=SegmentationConfig(source="oracle"),
    )
    agent = ModIINAgent(cfg, matcher=matcher, goal_mask_fn=lambda img: np.ones(img.shape[:2], bool))
    return agent, matcher


def paint_run(**reid):
    """A run in the painted two rooms, starting with the goal behind the robot (a few searching
    frames before it is seen)."""
    boxes, goal, decoy = two_rooms()
    world = RedGoalWorld(boxes, Pose2D(-1.5, -1.0, math.pi), goal, decoy=decoy)
    agent, matcher = paint_agent(**reid)
    return run_decisions(agent, world, max_steps=400), world, matcher


def same_records(a, b) -> bool:
    """Two records equal field for field apart from their timings."""
    for f in dataclasses.fields(a):
        if f.name == "timings_ms":
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(x):
            if not same_records(x, y):
                return False
        elif isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (x is not None and y is not None and np.array_equal(x, y)):
                return False
        elif x != y:
            return False
    return True


def test_the_search_setting_equal_to_the_full_one_reproduces_the_agent_exactly():
    default, _, m0 = paint_run()
    explicit, world, m1 = paint_run(search_max_side_px=160, search_max_keypoints=1024)
    assert len(default) == len(explicit) and m0.sizes == m1.sizes
    assert all(same_records(a, b) for (_, a), (_, b) in zip(default, explicit))
    assert {r.reid_setting for _, r in explicit} == {"full"} and {r.reid_tau for _, r in explicit} == {100.0}
    assert set(m1.sizes) == {(160, 90), (64, 64)}  # every frame and the goal photo at the full setting
    assert explicit[-1][1].mode == "stopped" and world.distance_to_goal() < 1.0


def test_searching_frames_are_read_against_the_search_tau_and_kept_on_the_full_scale():
    """Searching frames at half the side (a quarter of the red pixels, tau 25), the approach at the
    full setting (tau 100): each record's score is read against its own setting's tau, and the
    candidates' evidence is on the full scale (a search score of s counts as 4 s)."""
    steps, world, matcher = paint_run(search_max_side_px=80, search_tau=25.0)
    recs = [r for _, r in steps]
    # a step is scored in the mode the step before decided on (the first: looking around)
    searching = [prev is None or prev.mode in ("look_around", "explore", "rescan") for prev in [None, *recs[:-1]]]
    assert sum(searching) >= 3 and not all(searching)
    for was_searching, r in zip(searching, recs):
        assert r.reid_setting == ("search" if was_searching else "full")
        assert r.reid_tau == (25.0 if was_searching else 100.0)
        assert r.goal_detected == (r.reid_score >= r.reid_tau)
    assert (80, 45) in matcher.sizes and (160, 90) in matcher.sizes
    # the first searching frame that localised (potential evidence: half its own tau): its
    # candidate's best score is its search score x 4, below the full tau, so potential
    first = next(i for i, r in enumerate(recs) if searching[i] and r.reid_score >= 0.5 * r.reid_tau)
    assert recs[first].reid_score < 25.0 and not recs[first].goal_detected
    (cand,) = [c for c in recs[first].candidates if c.id == recs[first].candidate_id]
    assert cand.best_score == pytest.approx(4 * recs[first].reid_score) and cand.state == "potential"
    # confirmed later at the full setting, and found
    assert any(r.goal_detected and r.reid_setting == "full" for r in recs)
    assert recs[-1].mode == "stopped" and world.distance_to_goal() < 1.0


def test_a_home_memory_with_a_reduced_search_setting_is_refused():
    agent, _ = paint_agent(search_max_side_px=80, search_tau=25.0)
    agent.home_memory = HomeMemory()
    with pytest.raises(ValueError, match="home memory"):
        agent.reset(np.zeros((64, 64, 3), np.uint8))
    same, _ = paint_agent(search_max_side_px=160)
    same.home_memory = HomeMemory()
    same.reset(np.zeros((64, 64, 3), np.uint8))  # one setting: the memory works as before
