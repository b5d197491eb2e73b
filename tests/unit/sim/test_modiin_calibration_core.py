import numpy as np
import pytest

from sim.evaluation.calibration_core import make_pairs, plot_curves, pr_curves


def test_pairs_and_negative_weights():
    inst = [0] * 4 + [1] * 4 + [2] * 4
    ps = make_pairs(inst, max_negatives=10, seed=1)
    assert ps.label.sum() == 3 * 6
    assert (~ps.label).sum() == 10 and ps.n_negatives_total == 66 - 18
    np.testing.assert_allclose(ps.weight[~ps.label], 48 / 10)
    a, b = ps.pairs.T
    assert np.all(a < b)
    same = np.asarray(inst)[a] == np.asarray(inst)[b]
    assert np.array_equal(same, ps.label)


def test_pr_curve_and_max_f_on_a_known_case():
    scores = np.array([9, 8, 7, 6, 5, 4, 3, 2], float)
    label = np.array([1, 1, 0, 1, 0, 0, 1, 0], bool)
    c = pr_curves(scores, label)
    # tau = 6: TP 3, FP 1 -> P 0.75, R 0.75, F 0.75 (the best)
    assert c.tau == 6 and c.max_f == pytest.approx(0.75)
    assert c.precision[0] == 1.0 and c.recall[-1] == 1.0


def test_weights_act_like_repeated_negatives():
    scores = np.array([5, 4, 3, 2], float)
    label = np.array([1, 0, 1, 0], bool)
    w = pr_curves(scores, label, np.array([1, 3, 1, 3], float))
    rep = pr_curves(np.array([5, 4, 4, 4, 3, 2, 2, 2], float), np.array([1, 0, 0, 0, 1, 0, 0, 0], bool))
    np.testing.assert_allclose(w.precision, rep.precision)
    np.testing.assert_allclose(w.f, rep.f)


def test_ties_share_one_operating_point(tmp_path):
    c = pr_curves(np.array([1, 1, 1, 0], float), np.array([1, 0, 1, 0], bool))
    assert list(c.threshold) == [1, 0]
    plot_curves(str(tmp_path / "pr.png"), {"conf": c}, "test")
    assert (tmp_path / "pr.png").stat().st_size > 1000
