"""Pose integration and collision of the simulated robot (docs/architecture.md section 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.types import ROBOT_RADIUS_M, Action, Pose2D, wrap_angle
from sim.geometry import CircleFootprint, FootprintIndex, RectFootprint
from sim.simple_homes import box_object, room_home
from sim.world import SimWorld


@pytest.fixture(scope="module")
def world():
    # 4 x 4 m room; a 1 x 1 m box (a "couch") centred at (3, 3); a rug at (1, 3).
    rug = box_object(1, "rug", (1.0, 3.0), (1.0, 1.0, 0.01))
    w = SimWorld(room_home(4.0, 4.0, [box_object(0, "couch", (3.0, 3.0), (1.0, 1.0, 0.8)), rug]))
    yield w
    w.close()


def test_forward_moves_a_quarter_metre_along_the_heading(world: SimWorld) -> None:
    p, moved = world.move(Pose2D(1.0, 1.0, math.radians(30)), Action.MOVE_FORWARD)
    assert moved
    assert math.isclose(p.x_m, 1.0 + 0.25 * math.cos(math.radians(30)))
    assert math.isclose(p.y_m, 1.0 + 0.25 * math.sin(math.radians(30)))
    assert math.isclose(p.yaw_rad, math.radians(30))


def test_turns_are_thirty_degrees_in_place(world: SimWorld) -> None:
    p = Pose2D(1.0, 1.0, 0.0)
    left, moved = world.move(p, Action.TURN_LEFT)
    assert moved and (left.x_m, left.y_m) == (1.0, 1.0) and math.isclose(left.yaw_rad, math.radians(30))
    right, _ = world.move(p, Action.TURN_RIGHT)
    assert math.isclose(right.yaw_rad, -math.radians(30))
    q = p
    for _ in range(12):
        q, _ = world.move(q, Action.TURN_LEFT)
    assert abs(wrap_angle(q.yaw_rad - p.yaw_rad)) < 1e-9


def test_stop_does_not_move(world: SimWorld) -> None:
    p = Pose2D(1.0, 1.0, 0.3)
    assert world.move(p, Action.STOP) == (p, False)


def test_blocked_forward_leaves_the_pose_unchanged(world: SimWorld) -> None:
    # Wall inner face at x = 3.95; the robot may stand with its centre up to x = 3.78.
    p = Pose2D(3.6, 1.0, 0.0)
    q, moved = world.move(p, Action.MOVE_FORWARD)
    assert not moved and q == p  # no sliding
    # at an angle towards the wall: still no sliding along it
    p2 = Pose2D(3.6, 1.0, math.radians(30))
    q2, moved2 = world.move(p2, Action.MOVE_FORWARD)
    assert not moved2 and q2 == p2


def test_collision_boundary_is_the_robot_radius(world: SimWorld) -> None:
    face = 3.95
    assert not world.collides(face - ROBOT_RADIUS_M - 1e-6, 1.0)
    assert world.collides(face - ROBOT_RADIUS_M + 1e-3, 1.0)
    # the box (2.5..3.5 in x and y): corner distance in 2D
    d = ROBOT_RADIUS_M / math.sqrt(2)
    assert world.collides(2.5 - d + 1e-3, 2.5 - d + 1e-3)
    assert not world.collides(2.5 - d - 1e-3, 2.5 - d - 1e-3)


def test_rugs_are_drivable(world: SimWorld) -> None:
    assert not world.collides(1.0, 3.0)


def test_forward_does_not_tunnel_past_a_corner() -> None:
    # A thin pole: both ends of a step are clear but the middle touches it.
    index = FootprintIndex([CircleFootprint(1.0, 1.0, 0.02, 0.0, 1.0)], (0.0, 0.0, 3.0, 3.0))
    w = SimWorld.__new__(SimWorld)
    w.footprints = index
    start = Pose2D(1.0 - 0.125, 1.0 - 0.18, 0.0)
    assert not index.collides(start.x_m, start.y_m) and not index.collides(start.x_m + 0.25, start.y_m)
    assert SimWorld.move(w, start, Action.MOVE_FORWARD) == (start, False)


def test_grid_agrees_with_collides(world: SimWorld) -> None:
    grid = world.navigable_grid(0.05)
    xs, ys = grid.cell_centres()
    rng = np.random.default_rng(0)
    for i, j in zip(rng.integers(0, grid.shape[0], 400), rng.integers(0, grid.shape[1], 400)):
        assert grid.navigable[i, j] == (not world.collides(float(xs[i, j]), float(ys[i, j])))


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-3, 3),
    y=st.floats(-3, 3),
    yaw=st.floats(-math.pi, math.pi),
    ang=st.floats(-math.pi, math.pi),
    hx=st.floats(0.05, 1.0),
    hy=st.floats(0.05, 1.0),
)
def test_rect_distance_is_rotation_invariant(x: float, y: float, yaw: float, ang: float, hx: float, hy: float) -> None:
    a = RectFootprint(0.0, 0.0, hx, hy, 0.0, 0.0, 1.0)
    b = RectFootprint(0.0, 0.0, hx, hy, ang, 0.0, 1.0)
    c, s = math.cos(ang), math.sin(ang)
    assert math.isclose(a.distance(x, y), b.distance(c * x - s * y, s * x + c * y), abs_tol=1e-9)


@settings(max_examples=60, deadline=None)
@given(actions=st.lists(st.sampled_from([Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT]), max_size=30))
def test_integration_matches_pose_composition_and_stays_free(world: SimWorld, actions: list[Action]) -> None:
    start = Pose2D(1.5, 1.2, 0.4)
    p = start
    for a in actions:
        q, moved = world.move(p, a)
        if a == Action.MOVE_FORWARD and moved:
            assert math.isclose(q.relative_to(p).x_m, 0.25, abs_tol=1e-9) and abs(q.relative_to(p).y_m) < 1e-9
        if a == Action.MOVE_FORWARD and not moved:
            assert q == p
        assert not world.collides(q.x_m, q.y_m)
        p = q
