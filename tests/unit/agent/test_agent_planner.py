import math

import numpy as np
import pytest

from agent.mapping import GridMap, MappingConfig
from agent.planner import FMMPlanner, PlanError, region_within
from agent.types import Action, Pose2D


def corridor_grid() -> GridMap:
    """An L-shaped corridor 0.8 m wide, fully explored: east along y=0 to x=4, then north to y=4."""
    grid = GridMap(MappingConfig(initial_size_m=12.0))
    L = grid.layers
    L.explored[:] = True
    L.obstacle[:] = True
    free = np.zeros(grid.shape, bool)
    for x0, y0, x1, y1 in [(-0.4, -0.4, 4.4, 0.4), (3.6, -0.4, 4.4, 4.4)]:
        ij0 = grid.xy_to_ij(np.array([[x0, y0]]))[0]
        ij1 = grid.xy_to_ij(np.array([[x1, y1]]))[0]
        free[ij0[0] : ij1[0], ij0[1] : ij1[1]] = True
    L.obstacle &= ~free
    return grid


def target_at(grid, x, y):
    m = np.zeros(grid.shape, bool)
    i, j = grid.xy_to_ij(np.array([[x, y]]))[0]
    m[i, j] = True
    return m


def step(pose: Pose2D, action: Action) -> Pose2D:
    if action == Action.MOVE_FORWARD:
        return Pose2D(pose.x_m + 0.25 * math.cos(pose.yaw_rad), pose.y_m + 0.25 * math.sin(pose.yaw_rad), pose.yaw_rad)
    if action == Action.TURN_LEFT:
        return pose.compose(Pose2D(0, 0, math.radians(30)))
    if action == Action.TURN_RIGHT:
        return pose.compose(Pose2D(0, 0, -math.radians(30)))
    return pose


def clearance_m(grid, pose):
    obst = grid.ij_to_xy(np.argwhere(grid.layers.obstacle))
    return float(np.min(np.hypot(obst[:, 0] - pose.x_m, obst[:, 1] - pose.y_m)))


def test_path_goes_round_the_corner():
    grid = corridor_grid()
    planner = FMMPlanner()
    pose = Pose2D(0.0, 0.0, 0.0)
    field = planner.distance_field(grid, pose)
    plan = planner.plan(grid, field, pose, target_at(grid, 4.0, 4.0))
    assert plan.action == Action.MOVE_FORWARD
    assert 7.5 < plan.distance_m < 8.6  # 4 m east + 4 m north, not the 5.7 m diagonal
    assert plan.path_xy_m[-1, 0] == pytest.approx(4.0, abs=0.05)
    # every path point keeps the robot radius from the walls
    for x, y in plan.path_xy_m[1:]:
        assert clearance_m(grid, Pose2D(float(x), float(y))) >= 0.17


def test_turns_towards_a_target_behind():
    grid = corridor_grid()
    planner = FMMPlanner()
    pose = Pose2D(2.0, 0.0, 0.0)
    field = planner.distance_field(grid, pose)
    assert planner.plan(grid, field, pose, target_at(grid, 0.0, 0.0)).action in (Action.TURN_LEFT, Action.TURN_RIGHT)
    pose = Pose2D(2.0, 0.0, math.radians(80))  # target behind-left of the heading: turning left is shorter
    field = planner.distance_field(grid, pose)
    assert planner.plan(grid, field, pose, target_at(grid, 0.0, 0.0)).action == Action.TURN_LEFT


def test_walking_the_plan_reaches_the_target_without_touching_walls():
    grid = corridor_grid()
    planner = FMMPlanner()
    pose = Pose2D(0.0, 0.0, math.radians(-90))
    goal = target_at(grid, 4.0, 4.0)
    for _ in range(100):
        field = planner.distance_field(grid, pose)
        plan = planner.plan(grid, field, pose, goal)
        if plan.distance_m < 0.2:
            break
        pose = step(pose, plan.action)
        assert clearance_m(grid, pose) >= 0.17 - 0.05
    assert math.hypot(pose.x_m - 4.0, pose.y_m - 4.0) < 0.3


def test_unreachable_target_is_an_error_not_a_stop():
    grid = corridor_grid()
    walled = grid.xy_to_ij(np.array([[3.6, 2.0], [4.4, 2.3]]))
    grid.layers.obstacle[walled[0, 0] : walled[1, 0], walled[0, 1] : walled[1, 1]] = True
    planner = FMMPlanner()
    pose = Pose2D()
    field = planner.distance_field(grid, pose)
    with pytest.raises(PlanError) as err:
        planner.plan(grid, field, pose, target_at(grid, 4.0, 4.0))
    assert err.value.reason == "unreachable"
    with pytest.raises(PlanError) as err:
        planner.plan(grid, field, pose, np.zeros(grid.shape, bool))
    assert err.value.reason == "no_target"


def test_agent_touching_a_wall_can_still_plan():
    grid = corridor_grid()
    planner = FMMPlanner()
    pose = Pose2D(1.0, 0.3, 0.0)  # 10 cm from the wall: inside the inflated zone
    field = planner.distance_field(grid, pose)
    plan = planner.plan(grid, field, pose, target_at(grid, 3.0, 0.0))
    assert np.isfinite(plan.distance_m)


def test_unexplored_space_is_optimistically_traversible():
    grid = GridMap()
    planner = FMMPlanner()
    pose = Pose2D()
    field = planner.distance_field(grid, pose, extra_targets=target_at(grid, 2.0, 1.0))
    plan = planner.plan(grid, field, pose, target_at(grid, 2.0, 1.0))
    assert plan.distance_m == pytest.approx(math.hypot(2.0, 1.0), abs=0.15)


def test_region_within():
    cells = np.zeros((21, 21), bool)
    cells[10, 10] = True
    r = region_within(cells, 0.25, 0.05)
    assert r[10, 15] and not r[10, 16] and r[13, 13] and not r[14, 14]
