"""The task's metrics on hand-made cases (docs/architecture.md section 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.metrics import aggregate, episode_metrics, is_success, spl

VP = np.array([[1.0, 1.0], [2.0, 1.0]])


def test_spl_formula() -> None:
    assert spl(True, 4.0, 5.0) == pytest.approx(0.8)
    assert spl(True, 4.0, 4.0) == 1.0
    assert spl(True, 4.0, 3.5) == 1.0  # a path shorter than the geodesic counts as the geodesic
    assert spl(False, 4.0, 4.0) == 0.0


def test_success_boundary_is_inclusive() -> None:
    assert is_success(True, (1.1, 1.0), VP)  # exactly 0.1 m from a viewpoint
    assert not is_success(True, (1.0, 1.1 + 1e-6), VP)  # just outside
    assert not is_success(False, (1.0, 1.0), VP)  # must issue STOP
    assert is_success(True, (2.0 + 0.06, 1.0 + 0.08), VP)  # 0.1 m diagonally


def test_episode_metrics_combines_them() -> None:
    episode = dict(viewpoints_xy_m=VP, max_steps=1000, shortest_path_m=4.5)
    m = episode_metrics(
        called_stop=True, stop_xy_m=(2.05, 1.0), steps=40, path_length_m=6.0, stop_geodesic_m=0.05, **episode
    )
    assert m.success and m.spl == pytest.approx(0.75) and m.ne_m == 0.05 and not m.max_steps_reached
    assert m.stop_to_viewpoint_m == pytest.approx(0.05)
    fail = episode_metrics(
        called_stop=False, stop_xy_m=(5.0, 5.0), steps=1000, path_length_m=30.0, stop_geodesic_m=3.2, **episode
    )
    assert not fail.success and fail.spl == 0.0 and fail.ne_m == 3.2 and fail.max_steps_reached


def test_aggregate_overall_and_per_category() -> None:
    rows = [
        {"category": "chair", "success": True, "spl": 0.8, "ne": 0.05, "max_steps_reached": False},
        {"category": "chair", "success": False, "spl": 0.0, "ne": 2.95, "max_steps_reached": True},
        {"category": "tv", "success": True, "spl": 0.6, "ne": 0.0, "max_steps_reached": False},
        {"category": "tv", "success": False, "spl": 0.0, "ne": math.inf, "max_steps_reached": False},
    ]
    s = aggregate(rows)
    assert s["episodes"] == 4 and s["sr"] == 0.5 and s["spl"] == pytest.approx(0.35) and s["max_st"] == 0.25
    assert s["ne"] == pytest.approx(1.0) and s["ne_unreachable"] == 1
    assert s["per_category"]["chair"] == {
        "episodes": 2,
        "sr": 0.5,
        "spl": 0.4,
        "ne": 1.5,
        "ne_unreachable": 0,
        "max_st": 0.5,
    }
    assert s["per_category"]["tv"]["sr"] == 0.5
    assert aggregate([])["episodes"] == 0


def test_bootstrap_over_homes() -> None:
    from sim.metrics import bootstrap_ci

    # two homes: one always succeeds, one never; the interval spans most of [0, 1]
    vals = [1.0] * 5 + [0.0] * 5
    homes = ["a"] * 5 + ["b"] * 5
    lo, hi = bootstrap_ci(vals, homes)
    assert lo == 0.0 and hi == 1.0
    # the same 10 episodes as 10 independent homes give a narrower interval
    lo10, hi10 = bootstrap_ci(vals, list(range(10)))
    assert 0.0 < lo10 < 0.5 < hi10 < 1.0
    # every home alike: a point interval; deterministic
    assert bootstrap_ci([0.5] * 6, [1, 1, 2, 2, 3, 3]) == (0.5, 0.5)
    assert bootstrap_ci(vals, list(range(10))) == (lo10, hi10)


def test_aggregate_has_home_intervals_with_scene_seeds() -> None:
    rows = [
        {
            "category": "chair",
            "success": i % 2 == 0,
            "spl": 0.5 * (i % 2 == 0),
            "ne": 0.1,
            "max_steps_reached": False,
            "scene_seed": i // 2,
        }
        for i in range(8)
    ]
    s = aggregate(rows)
    assert s["homes"] == 4 and s["sr"] == 0.5
    assert s["sr_ci95"] == [0.5, 0.5] and s["spl_ci95"] == [0.25, 0.25]  # every home has SR 0.5
    assert s["per_category"]["chair"]["homes"] == 4
