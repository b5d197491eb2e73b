"""The policy's memory of failed forward moves (``modes.MotionState``) and the guard that
keeps a plan from repeating one.

A forward move that did not move the robot leaves a collision mark on the map, but the mark is
only a guess of what blocked it (which side, how far). The move itself is remembered exactly:
(global cell i, cell j, 30 deg heading bin) of where it was tried.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from agent.mapping import GridMap
from agent.modes import MotionState
from agent.planner import DistanceField, FMMPlanner, Plan
from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG, Action, Pose2D, wrap_angle

N_HEADINGS = int(round(360 / TURN_ANGLE_DEG))


def heading_bin(yaw_rad: float) -> int:
    return int(round(yaw_rad / math.radians(TURN_ANGLE_DEG))) % N_HEADINGS


def move_key(grid: GridMap, pose: Pose2D) -> tuple[int, int, int]:
    """(global cell i, cell j, heading bin) of a forward move from ``pose``."""
    i, j = grid.xy_to_ij(np.array([[pose.x_m, pose.y_m]]))[0]
    return int(i) + grid.origin_ij[0], int(j) + grid.origin_ij[1], heading_bin(pose.yaw_rad)


def blocked_here(grid: GridMap, motion: MotionState, pose: Pose2D) -> bool:
    """A forward move from this cell failed, at any heading."""
    i, j, _ = move_key(grid, pose)
    return any((i, j, h) in motion.blocked for h in range(N_HEADINGS))


def safe_action(plan: Plan, pose: Pose2D, field: DistanceField, grid: GridMap, planner: FMMPlanner,
                motion: MotionState) -> tuple[Action, MotionState]:
    """The plan's action, unless it is a forward move that already failed from this very
    cell and heading: then turn towards the side the path bends to. And when the plan turns
    back to such a heading (it points between two 30 deg headings and the nearer one is
    blocked), step forward on the current heading instead, to get round what blocked the move,
    rather than turn to and fro on the spot; only where the map shows that step traversible.
    Returns the action and the updated memory (``blocked_repeats`` counts refused moves in a row)."""
    key = move_key(grid, pose)
    if plan.action in (Action.TURN_LEFT, Action.TURN_RIGHT):
        sign = 1.0 if plan.action == Action.TURN_LEFT else -1.0
        turned = Pose2D(pose.x_m, pose.y_m, pose.yaw_rad + sign * math.radians(TURN_ANGLE_DEG))
        if move_key(grid, turned) in motion.blocked and key not in motion.blocked:
            here = np.array([pose.x_m, pose.y_m])
            ahead = here + FORWARD_STEP_M * np.array([math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)])
            if planner.line_free(grid, field, here, ahead):
                return Action.MOVE_FORWARD, motion
    if plan.action != Action.MOVE_FORWARD or key not in motion.blocked:
        return plan.action, replace(motion, blocked_repeats=0)
    path = plan.path_xy_m
    far = path[min(len(path) - 1, 8)]
    err = wrap_angle(math.atan2(far[1] - pose.y_m, far[0] - pose.x_m) - pose.yaw_rad)
    return (Action.TURN_LEFT if err >= 0 else Action.TURN_RIGHT), replace(motion, blocked_repeats=motion.blocked_repeats + 1)


def after_action(motion: MotionState, action: Action) -> MotionState:
    """The memory after the robot took ``action``: the run of alternating turns (left, right,
    left, ... on the spot: a turn never moves the robot) that ends with it."""
    turns = (Action.TURN_LEFT, Action.TURN_RIGHT)
    if action not in turns:
        n = 0
    elif motion.last_action in turns and motion.last_action != action:
        n = max(motion.alternating_turns, 1) + 1
    else:
        n = 1
    return replace(motion, alternating_turns=n, last_action=action)
