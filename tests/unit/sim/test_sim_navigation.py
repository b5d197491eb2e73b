"""Geodesic distances, viewpoints and lattice planning on small hand-made homes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.types import Action, Pose2D
from sim.geometry import FootprintIndex, NavGrid, RectFootprint
from sim.lattice import ViewpointGoal, plan_to_goal
from sim.navigation import geodesic_at, geodesic_field, instance_viewpoints, reachable_component
from sim.simple_homes import box_object, room_home
from sim.world import SimWorld


def _open_grid(n: int = 200, res: float = 0.05) -> NavGrid:
    return NavGrid(np.ones((n, n), dtype=bool), res, (0.0, 0.0))


def test_geodesic_in_open_space_is_euclidean_within_a_few_percent() -> None:
    grid = _open_grid()
    target = np.array([[5.025, 5.025]])
    field = geodesic_field(grid, target)
    for x, y in [(1.0, 1.0), (9.0, 5.0), (5.0, 8.7), (2.3, 8.1)]:
        d = geodesic_at(field, grid, x, y)
        e = math.hypot(x - 5.025, y - 5.025)
        assert abs(d - e) / e < 0.03, (x, y, d, e)


def test_geodesic_goes_around_a_wall() -> None:
    index = FootprintIndex(
        [RectFootprint(3.0, 2.0, 0.05, 2.0, 0.0, 0.0, 2.5)], (0.0, 0.0, 6.0, 6.0), robot_radius_m=0.17
    )
    grid = index.navigable_grid(0.05)
    field = geodesic_field(grid, np.array([[5.0, 1.0]]))
    d = geodesic_at(field, grid, 1.0, 1.0)
    # straight is 4 m; around the wall's end (x=3, y=4 plus clearance) about 2 * hypot(2, 3.2)
    assert d > 7.0 and d < 8.2
    assert math.isinf(geodesic_at(field, grid, 3.0, 1.0))  # inside the wall


@pytest.fixture(scope="module")
def world():
    chair = box_object(0, "chair", (3.0, 2.0), (0.5, 0.5, 0.9))
    w = SimWorld(room_home(5.0, 4.0, [chair]))
    yield w
    w.close()


def test_viewpoints_are_navigable_near_and_see_the_instance(world: SimWorld) -> None:
    vp = instance_viewpoints(world, 0)
    assert len(vp) > 100
    obj = world.home.instance(0)
    for x, y in vp:
        assert not world.collides(x, y)
        assert min(fp.distance(x, y) for fp in obj.footprints()) <= 1.0 + 1e-9
    # on a 0.1 m lattice
    assert np.allclose(np.diff(np.unique(np.round(vp[:, 0], 4))), 0.1)


def test_viewpoints_exclude_positions_behind_an_occluder() -> None:
    chair = box_object(0, "chair", (3.0, 2.0), (0.4, 0.4, 0.5))
    screen = box_object(1, "panel", (2.25, 2.0), (0.1, 3.0, 2.4))  # a tall wall-like panel west of the chair
    w = SimWorld(room_home(5.0, 4.0, [chair, screen]))
    try:
        vp = instance_viewpoints(w, 0)
        assert len(vp) > 0 and np.all(vp[:, 0] > 2.25)  # nothing west of the panel sees the chair
    finally:
        w.close()


def test_lattice_plan_replays_exactly_and_reaches_a_viewpoint(world: SimWorld) -> None:
    vp = instance_viewpoints(world, 0)
    grid = world.navigable_grid(0.05)
    field = geodesic_field(grid, vp)
    start = Pose2D(0.5, 0.5, 2.0)
    plan = plan_to_goal(
        world.move, start, ViewpointGoal(vp), lambda x, y: max(geodesic_at(field, grid, x, y) - 0.1, 0.0)
    )
    assert plan is not None and plan.actions[-1] == Action.STOP
    p = start
    for a, expected in zip(plan.actions[:-1], plan.poses_world):
        p, moved = world.move(p, a)
        assert moved and p == expected
    assert np.min(np.hypot(vp[:, 0] - p.x_m, vp[:, 1] - p.y_m)) <= 0.1
    shortest = geodesic_at(field, grid, start.x_m, start.y_m)
    assert plan.path_length_m >= shortest - 0.1 - 1e-6
    assert plan.path_length_m <= shortest * 1.15 + 0.25


def test_reachable_component_picks_the_start_side() -> None:
    index = FootprintIndex([RectFootprint(3.0, 3.0, 0.05, 3.1, 0.0, 0.0, 2.5)], (0.0, 0.0, 6.0, 6.0))
    grid = index.navigable_grid(0.05)
    left = reachable_component(grid, (1.0, 1.0))
    right = reachable_component(grid, (5.0, 1.0))
    assert left.any() and right.any() and not (left & right).any()
