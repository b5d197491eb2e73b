import math
from dataclasses import replace

import numpy as np

from agent.mapping import GridMap
from agent.modes import MotionState
from agent.motion import blocked_here, move_key, safe_action
from agent.planner import FMMPlanner, Plan
from agent.types import Action, Pose2D
from tests.helpers.agent_scenes import observation, room_walls


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
    for a in (
        Action.TURN_LEFT,
        Action.TURN_RIGHT,
        Action.TURN_LEFT,
        Action.TURN_LEFT,
        Action.TURN_RIGHT,
        Action.MOVE_FORWARD,
        Action.TURN_RIGHT,
    ):
        m = after_action(m, a)
        runs.append(m.alternating_turns)
    # a turn the same way starts a new run; a forward move ends it
    assert runs == [1, 2, 3, 1, 2, 0, 1]


def _open_room_at(pose: Pose2D):
    grid = GridMap()
    grid.update(observation(room_walls(-3.0, -2.0, 3.0, 2.0), pose))
    planner = FMMPlanner()
    return grid, planner, planner.distance_field(grid, pose)


def test_a_to_and_fro_run_ends_in_a_side_step_on_the_other_side():
    from agent.motion import N_HEADINGS, detour_heading, heading_bin

    pose = Pose2D(-2.0, -1.0, 0.0)
    grid, planner, field = _open_room_at(pose)
    i, j, h = move_key(grid, pose)
    # the move ahead failed here, and so did the one 30 deg to the left (where the path bends)
    motion = MotionState(
        blocked=frozenset({(i, j, h), (i, j, (h + 1) % N_HEADINGS)}), alternating_turns=4, last_action=Action.TURN_LEFT
    )
    path = np.array([[-2.0 + 0.05 * k, -1.0] for k in range(40)], np.float32)  # straight ahead, 2 m
    plan = Plan(Action.MOVE_FORWARD, (0, 0), tuple(path[-1]), 2.0, path)
    # off, or before the N-th turn: the refusal turns towards the path as before
    assert safe_action(plan, pose, field, grid, planner, motion)[0] == Action.TURN_LEFT
    assert safe_action(plan, pose, field, grid, planner, motion, detour_after_turns=5)[0] == Action.TURN_LEFT
    # on: the free heading whose step ends nearest the path 1 m ahead is 30 deg to the right
    assert detour_heading(plan, pose, field, grid, planner, motion) == (h - 1) % N_HEADINGS
    action, m = safe_action(plan, pose, field, grid, planner, motion, detour_after_turns=4)
    assert action == Action.TURN_RIGHT and m.detour == (i, j, (h - 1) % N_HEADINGS)
    # turned there, the plan asks to turn back; the detour steps forward instead, once
    turned = Pose2D(pose.x_m, pose.y_m, -math.radians(30))
    assert heading_bin(turned.yaw_rad) == m.detour[2]
    back = Plan(Action.TURN_LEFT, (0, 0), tuple(path[-1]), 2.0, path)
    action, m2 = safe_action(back, turned, field, grid, planner, m, detour_after_turns=4)
    assert action == Action.MOVE_FORWARD and m2.detour is None
    # from the next cell the plan rules again
    moved = Pose2D(turned.x_m + 0.2165, turned.y_m - 0.125, turned.yaw_rad)
    action, m3 = safe_action(back, moved, field, grid, planner, replace(m2, alternating_turns=0), detour_after_turns=4)
    assert action == Action.TURN_LEFT and m3.detour is None


def test_no_side_step_where_no_step_is_free_or_none_gets_nearer():
    from agent.motion import N_HEADINGS, detour_heading

    pose = Pose2D(-2.0, -1.0, 0.0)
    grid, planner, field = _open_room_at(pose)
    i, j, _ = move_key(grid, pose)
    path = np.array([[-2.0 + 0.05 * k, -1.0] for k in range(40)], np.float32)
    plan = Plan(Action.MOVE_FORWARD, (0, 0), tuple(path[-1]), 2.0, path)
    # every step but the one straight back failed: stepping back gets no nearer the path ahead
    back_bin = N_HEADINGS // 2
    motion = MotionState(blocked=frozenset((i, j, b) for b in range(N_HEADINGS) if b != back_bin), alternating_turns=6)
    assert detour_heading(plan, pose, field, grid, planner, motion) is None
    action, m = safe_action(plan, pose, field, grid, planner, motion, detour_after_turns=4)
    assert action in (Action.TURN_LEFT, Action.TURN_RIGHT) and m.detour is None


def test_refused_moves_are_counted_until_the_robot_moves_forward():
    # To and fro between a refused heading and its neighbour: the refusal turns away, the plan
    # turns back. The plan's own turns do not reset the count of refusals (the policy gives up
    # the target after 4); a forward move does.
    from agent.motion import after_action

    pose = Pose2D(-2.0, -1.0, 0.0)
    grid, planner, field = _open_room_at(pose)
    motion = MotionState(blocked=frozenset({move_key(grid, pose)}))
    path = np.array([[-2.0, -1.0], [-1.5, -0.8], [-1.0, -0.6]], np.float32)
    ahead = Plan(Action.MOVE_FORWARD, (0, 0), (-1.0, -0.6), 1.0, path)
    back = Plan(Action.TURN_RIGHT, (0, 0), (-1.0, -0.6), 1.0, path)
    turned = Pose2D(pose.x_m, pose.y_m, math.radians(30))
    for k in range(1, 5):
        action, motion = safe_action(ahead, pose, field, grid, planner, motion)
        assert action == Action.TURN_LEFT and motion.blocked_repeats == k
        motion = after_action(motion, action)
        action, motion = safe_action(back, turned, field, grid, planner, replace(motion, blocked=frozenset()))
        assert action == Action.TURN_RIGHT and motion.blocked_repeats == k
        motion = after_action(replace(motion, blocked=frozenset({move_key(grid, pose)})), action)
    assert after_action(motion, Action.MOVE_FORWARD).blocked_repeats == 0
