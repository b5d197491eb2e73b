"""The re-ID gate (agent/reid/gate.py): mutual-nearest-neighbour counts on hand-made descriptor
sets, its threshold calibration, and the identifier skipping the full matcher below it."""

import json
from dataclasses import replace

import numpy as np
import pytest

from agent.reid import ReIDConfig, ReIdentifier
from agent.reid.base import Features, Matches
from agent.reid.gate import MNNGate, gate_threshold_for, mnn_count
from agent.reid.identifier import resolve_gate_threshold


def unit_rows(rng, n, d=64):
    x = rng.normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_mnn_counts_only_mutual_and_similar_pairs():
    e = np.eye(4, dtype=np.float32)
    goal = e[[0, 1, 2]]
    # obs row 0 = goal 0 exactly; rows 1 and 2 both nearest to goal 1 (only one is mutual);
    # row 3 is orthogonal to every goal row (similarity 0, below the threshold)
    obs = np.stack([e[0], 0.9 * e[1] + 0.1 * e[2], 0.95 * e[1] + 0.05 * e[3], e[3]])
    obs /= np.linalg.norm(obs, axis=1, keepdims=True)
    sim = obs @ goal.T
    assert mnn_count(sim, 0.82) == 2  # (0, 0) and (2, 1); row 1 loses goal 1 to row 2
    assert mnn_count(sim, 0.999) == 1  # only the exact copy
    # no similarity bound: still 2, goal 2's nearest row (1) prefers goal 1, and row 3's nearest
    # goal (0) prefers row 0
    assert mnn_count(sim, -1.0) == 2


def test_gate_passes_a_view_of_the_goal_and_gates_an_unrelated_one():
    rng = np.random.default_rng(0)
    goal = unit_rows(rng, 300)
    # a view of the goal: 120 of its descriptors, perturbed (viewpoint change), among 400 others
    seen = goal[rng.choice(300, 120, replace=False)] + rng.normal(scale=0.04, size=(120, 64)).astype(np.float32)
    view = np.vstack([seen, unit_rows(rng, 400)])
    unrelated = unit_rows(rng, 520)
    gate = MNNGate(0.82)
    gate.set_goal(goal)
    s_view, s_unrelated = gate.score(view), gate.score(unrelated)
    assert s_view >= 110  # (almost) all 120 shared descriptors are mutual and similar
    assert s_unrelated == 0  # random 64-d unit vectors never reach cosine 0.82
    # descriptors need not be normalised (SIFT's are not): the score is scale-free
    assert gate.score(3.0 * view) == s_view
    assert gate.score(np.zeros((0, 64), np.float32)) == 0.0


def test_gate_needs_a_goal_first():
    with pytest.raises(RuntimeError):
        MNNGate().score(np.ones((3, 8), np.float32))


def test_threshold_drops_at_most_the_allowed_share_of_positives():
    rng = np.random.default_rng(1)
    # gate score about twice the full score (as on goal-image pairs), 3300 frames, tau 75
    full = np.concatenate([rng.uniform(80, 400, 300), rng.uniform(0, 70, 3000)])
    gate = np.floor(full * rng.uniform(1.8, 2.2, len(full)))
    thr, stats = gate_threshold_for(full, gate, tau=75.0, max_drop=0.01)
    pos_gate = gate[full >= 75.0]
    assert np.mean(pos_gate < thr) <= 0.01
    assert stats["positives"] == 300 and stats["dropped_share"] == pytest.approx(np.mean(pos_gate < thr))
    # the direct estimate is the largest threshold within the bound: one more drops more than 1%
    assert np.mean(pos_gate < stats["direct"] + 1) > 0.01
    # the ratio bound: 1.8 x 75 = 135 at worst; both estimates near it, the smaller one wins
    assert 125 <= stats["bound"] <= 135 and thr == min(stats["direct"], stats["bound"])
    assert 0 < stats["pass_share"] < 1
    with pytest.raises(ValueError, match="no frame reaches tau"):
        gate_threshold_for(np.zeros(5), np.zeros(5), tau=1.0)


def test_few_positives_are_covered_by_the_ratio_bound():
    # 20 positives that all happen to score high, but frames just below tau show that a frame
    # reaching tau can have a gate score of only half its full score
    full = np.array([100.0] * 20 + [60.0] * 50)
    gate = np.array([200.0] * 20 + [30.0] * 50)
    thr, stats = gate_threshold_for(full, gate, tau=75.0, max_drop=0.01)
    assert stats["direct"] == 200.0  # what the positives alone would say
    assert stats["bound"] == 37.0 and thr == 37.0  # floor(0.5 x 75)


class VectorMatcher:
    """Features are given descriptor sets; ``match`` pairs identical rows (confidence 1) and
    counts its calls, so a test sees whether the full matcher ran."""

    name = "xfeat_lighterglue"

    def __init__(self, images):
        self.images = images  # id -> (N, D) descriptors
        self.match_calls = 0

    def extract(self, rgb, max_keypoints):
        desc = self.images[int(rgb[0, 0, 0])]
        return Features(np.zeros((len(desc), 2), np.float32), desc, (rgb.shape[1], rgb.shape[0]))

    def match(self, goal, obs):
        self.match_calls += 1
        sim = obs.descriptors @ goal.descriptors.T
        i_obs, i_goal = np.nonzero(sim > 0.999)
        return Matches(i_goal.astype(np.int64), i_obs.astype(np.int64), np.ones(len(i_goal), np.float32))


def image(k):
    return np.full((4, 4, 3), k, np.uint8)


def test_identifier_skips_the_full_matcher_below_the_gate_and_runs_it_above():
    rng = np.random.default_rng(2)
    goal = unit_rows(rng, 50)
    imgs = {0: goal, 1: np.vstack([goal[:30], unit_rows(rng, 20)]), 2: unit_rows(rng, 50)}
    m = VectorMatcher(imgs)
    reid = ReIdentifier(ReIDConfig(tau=5.0, gate=True, gate_threshold=10.0), matcher=m)
    reid.set_goal(image(0))
    r_goal = reid.compare(image(1))
    assert r_goal.full_matcher and r_goal.gate_score == 30 and r_goal.score == 30 and m.match_calls == 1
    r_other = reid.compare(image(2))
    assert not r_other.full_matcher and r_other.gate_score == 0 and r_other.score == 0.0
    assert len(r_other.matches) == 0 and r_other.obs_xy.shape == (0, 2) and m.match_calls == 1
    # the caller can ask for the full matcher whatever the gate says (the agent near a candidate)
    forced = reid.compare(image(2), use_gate=False)
    assert forced.full_matcher and forced.gate_score == 0 and m.match_calls == 2
    m.match_calls = 1
    # gate off: the full matcher runs on every frame; shadow mode still reports the gate score
    off = ReIdentifier(ReIDConfig(tau=5.0, gate=False, gate_shadow=True), matcher=m)
    off.set_goal(image(0))
    r = off.compare(image(2))
    assert r.full_matcher and r.gate_score == 0 and m.match_calls == 2
    plain = ReIdentifier(ReIDConfig(tau=5.0, gate=False), matcher=m)
    plain.set_goal(image(0))
    assert plain.compare(image(2)).gate_score is None and m.match_calls == 3


def test_gate_is_scaled_down_when_the_caller_needs_scores_below_tau():
    # potential evidence (scores from a share of tau up) must pass the gate as detections do
    rng = np.random.default_rng(3)
    goal = unit_rows(rng, 50)
    imgs = {0: goal, 1: np.vstack([goal[:12], unit_rows(rng, 38)])}  # 12 mutual neighbours
    m = VectorMatcher(imgs)
    full = ReIdentifier(ReIDConfig(tau=5.0, gate=True, gate_threshold=20.0), matcher=m)
    half = ReIdentifier(ReIDConfig(tau=5.0, gate=True, gate_threshold=20.0), matcher=m, min_score_ratio=0.5)
    assert full.gate_threshold == 20.0 and half.gate_threshold == 10.0
    for r in (full, half):
        r.set_goal(image(0))
    assert not full.compare(image(1)).full_matcher
    assert half.compare(image(1)).full_matcher and half.compare(image(1)).score == 12
    with pytest.raises(ValueError):
        ReIdentifier(ReIDConfig(tau=5.0), matcher=m, min_score_ratio=0.0)


def test_gate_threshold_from_config_or_calibration_file(tmp_path):
    assert resolve_gate_threshold(ReIDConfig(gate=False)) is None
    assert resolve_gate_threshold(ReIDConfig(gate=True, gate_threshold=12.0)) == 12.0
    f = tmp_path / "cal.json"
    # an operator's calibration without a gate threshold: gate off (never a changed decision)
    f.write_text(json.dumps({"matcher": "xfeat_lighterglue", "score": "conf", "tau": 70.0}))
    assert resolve_gate_threshold(ReIDConfig(gate=True, calibration_file=str(f))) is None
    f.write_text(
        json.dumps(
            {
                "matcher": "xfeat_lighterglue",
                "score": "conf",
                "tau": 70.0,
                "gate_threshold": 21.0,
                "gate_min_cosine": 0.82,
            }
        )
    )
    assert resolve_gate_threshold(ReIDConfig(gate=True, calibration_file=str(f))) == 21.0
    # the threshold holds for its tau or a higher one, not for a lower explicit tau
    assert resolve_gate_threshold(ReIDConfig(gate=True, calibration_file=str(f), tau=90.0)) == 21.0
    assert resolve_gate_threshold(ReIDConfig(gate=True, calibration_file=str(f), tau=6.0)) is None
    with pytest.raises(ValueError, match="min_cosine"):
        resolve_gate_threshold(ReIDConfig(gate=True, calibration_file=str(f), gate_min_cosine=0.9))


def test_both_deployments_gate_by_default_and_the_packaged_calibration_has_a_threshold():
    from agent.config import load_agent_config

    for name in ("sim", "stretch"):
        cfg = load_agent_config(name).reid
        assert cfg.gate is True
        assert resolve_gate_threshold(cfg) > 0


def _views():
    import cv2
    import skimage.data

    goal = cv2.resize(skimage.data.astronaut(), (512, 512))
    same = cv2.resize(
        cv2.warpAffine(goal, cv2.getRotationMatrix2D((256, 256), 10, 0.8), (512, 512))[60:460, 100:330], (360, 640)
    )
    other = cv2.resize(skimage.data.coffee(), (360, 640))
    return goal, same, other


@pytest.mark.parametrize("exit_keypoints", [0, 384])
def test_exit_stage_stops_an_unrelated_frame_and_leaves_a_matching_one_untouched(exit_keypoints):
    """The gate's second stage: LighterGlue's head after layer 2 scores the frame (on all keypoints,
    or on each side's top 384); below the exit threshold the frame stops there (score 0, full
    matcher False, its exit score recorded); above it, the frame gets exactly the score it gets
    without the stage."""
    from agent.reid.identifier import make_matcher

    goal, same, other = _views()
    cfg = ReIDConfig(
        tau=5.0,
        gate=True,
        gate_threshold=0.0,
        gate_exit_threshold=5.0,
        num_threads=1,
        gate_exit_keypoints=exit_keypoints,
    )
    matcher = make_matcher(cfg)
    assert matcher.exit_layer == 2
    gated = ReIdentifier(cfg, matcher=matcher)
    plain = ReIdentifier(ReIDConfig(tau=5.0, num_threads=1), matcher=make_matcher(ReIDConfig(num_threads=1)))
    for r in (gated, plain):
        r.set_goal(goal)
    assert gated.exit_threshold == 5.0 and plain.exit_threshold is None
    o = gated.compare(other)
    assert not o.full_matcher and o.score == 0.0 and len(o.matches) == 0 and o.exit_score < 5.0
    assert matcher.layers_run == 2
    s, s_plain = gated.compare(same), plain.compare(same)
    assert s.full_matcher and s.exit_score >= 5.0 and matcher.layers_run == 6
    assert s.score == s_plain.score > 100 and np.array_equal(s.matches.idx_obs, s_plain.matches.idx_obs)
    # near a candidate (use_gate=False) neither stage acts: every layer, no exit score
    forced = gated.compare(other, use_gate=False)
    assert forced.full_matcher and forced.exit_score is None and forced.score == plain.compare(other).score
    # scaled for potential evidence like the first stage
    half = ReIdentifier(cfg, matcher=matcher, min_score_ratio=0.5)
    assert half.exit_threshold == 2.5
    # an injected matcher without layers has no exit stage; one with another exit layer is an error
    assert ReIdentifier(cfg, matcher=VectorMatcher({})).exit_threshold is None
    with pytest.raises(ValueError, match="layer"):
        ReIdentifier(replace(cfg, gate_exit_layer=3), matcher=matcher)
    with pytest.raises(ValueError, match="keypoints"):  # a threshold for another number of keypoints
        ReIdentifier(replace(cfg, gate_exit_keypoints=exit_keypoints + 128), matcher=matcher)


def test_exit_stage_on_the_top_keypoints_sees_only_them():
    """With ``gate_exit_keypoints`` the exit stage scores the first K keypoints of each side (XFeat's
    best): exactly the all-keypoints stage on the two sides cut to K, and not the same as on all of
    them. ``exit_stage`` stops after the exit layer whatever the score."""
    from agent.reid.identifier import make_matcher
    from agent.reid.xfeat import top_keypoints

    goal, same, _ = _views()
    top = make_matcher(ReIDConfig(gate=True, num_threads=1, gate_exit_keypoints=256))
    every = make_matcher(ReIDConfig(gate=True, num_threads=1, gate_exit_keypoints=0))
    assert (top.exit_keypoints, every.exit_keypoints) == (256, 0)
    g, o = top.extract(goal, 1024), top.extract(same, 1024)
    assert len(g) > 256 and len(o) > 256
    on_top = top.exit_stage(g, o)
    assert top.layers_run == 2 and not top.exited
    cut = every.exit_stage(top_keypoints(g, 256), top_keypoints(o, 256))
    on_all = every.exit_stage(g, o)
    assert on_top == pytest.approx(cut) and on_top["count"] <= 256
    assert on_all["count"] > on_top["count"] and on_all["conf"] > on_top["conf"] > 0
    assert top_keypoints(o, 256).keypoints_xy.tolist() == o.keypoints_xy[:256].tolist()
    assert top_keypoints(o, 5000) is o  # fewer than K: the features themselves


def test_exit_threshold_from_config_or_calibration_file(tmp_path):
    from agent.reid.identifier import matcher_key, resolve_exit_threshold

    assert resolve_exit_threshold(ReIDConfig(gate=False, gate_exit_threshold=3.0)) is None
    assert resolve_exit_threshold(ReIDConfig(gate=True, gate_exit_layer=0)) is None
    assert resolve_exit_threshold(ReIDConfig(gate=True, gate_exit_threshold=3.0)) == 3.0
    assert resolve_exit_threshold(ReIDConfig(matcher="sift", gate=True, gate_exit_threshold=3.0)) is None  # no layers
    f = tmp_path / "cal.json"
    base = {
        "matcher": "xfeat_lighterglue",
        "score": "conf",
        "tau": 70.0,
        "gate_threshold": 21.0,
        "gate_min_cosine": 0.82,
    }
    f.write_text(json.dumps(base))  # calibrated before the exit stage: off
    assert resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f))) is None
    f.write_text(json.dumps({**base, "gate_exit_layer": 2, "gate_exit_threshold": 6.5}))
    assert (
        resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f), gate_exit_layer=3, gate_exit_keypoints=0))
        is None
    )
    # a file without ``gate_exit_keypoints`` was calibrated on all keypoints: off for the top 384
    assert resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f), gate_exit_keypoints=0)) == 6.5
    assert resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f), gate_exit_keypoints=384)) is None
    f.write_text(json.dumps({**base, "gate_exit_layer": 2, "gate_exit_keypoints": 384, "gate_exit_threshold": 4.0}))
    assert resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f))) == 4.0
    assert resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f), gate_exit_keypoints=256)) is None
    f.write_text(json.dumps({**base, "gate_exit_layer": 2, "gate_exit_threshold": 6.5}))
    assert (
        resolve_exit_threshold(ReIDConfig(gate=True, calibration_file=str(f), tau=60.0, gate_exit_keypoints=0)) is None
    )
    # matchers are shared per key: the exit layer (a hook) makes matchers of its own
    assert matcher_key(ReIDConfig(gate=True)) != matcher_key(ReIDConfig(gate=False))
    assert matcher_key(ReIDConfig(gate=True)) != matcher_key(ReIDConfig(gate=True, gate_exit_layer=3))
    assert matcher_key(ReIDConfig(gate=True)) != matcher_key(ReIDConfig(gate=True, gate_exit_keypoints=0))
