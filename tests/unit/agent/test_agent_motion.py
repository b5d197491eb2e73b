import math

import numpy as np

from agent.mapping import GridMap
from agent.modes import MotionState
from agent.motion import blocked_here, move_key, safe_action
from agent.planner import FMMPlanner, Plan
from agent.types import Action, Pose2D
from agent_scenes import observation, room_walls


def test_a_failed_forward_move_is_not_repeated_and_no_to_and_fro():
    walls = room_walls(-3.0, -2.0, 3.0, 2.0)
    grid = GridMap()
    pose = Pose2D(-2.0, -1.0, 0.0)
    grid.update(observation(walls, pose))
    planner = FMMPlanner()
    field = planner.distance_field(grid, pose)
    motion = MotionState(blocked=frozenset({move_key(grid, pose)}))
    assert blocked_here(grid, motion, pose)
    path = np.array([[-2.0, -1.0], [-1.5, -0.8], [-1.0, -0.6]], np.float32)
    plan = Plan(Action.MOVE_FORWARD, (0, 0), (-1.0, -0.6), 1.0, path)
    action, m = safe_action(plan, pose, field, grid, planner, motion)
    assert action == Action.TURN_LEFT and m.blocked_repeats == 1  # the path bends left
    # turned left, the plan turns back to the blocked heading: step ahead on this one instead
    turned = Pose2D(pose.x_m, pose.y_m, math.radians(30))
    back = Plan(Action.TURN_RIGHT, (0, 0), (-1.0, -0.6), 1.0, path)
    assert safe_action(back, turned, field, grid, planner, m)[0] == Action.MOVE_FORWARD
    action, m = safe_action(back, turned, field, grid, planner, MotionState())
    assert action == Action.TURN_RIGHT and m.blocked_repeats == 0


def test_the_run_of_alternating_turns_counts_to_and_fro_only():
    from agent.motion import after_action

    m = MotionState()
    runs = []
    for a in (Action.TURN_LEFT, Action.TURN_RIGHT, Action.TURN_LEFT, Action.TURN_LEFT, Action.TURN_RIGHT,
              Action.MOVE_FORWARD, Action.TURN_RIGHT):
        m = after_action(m, a)
        runs.append(m.alternating_turns)
    # a turn the same way starts a new run; a forward move ends it
    assert runs == [1, 2, 3, 1, 2, 0, 1]
