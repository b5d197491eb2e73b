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


def safe_action(
    plan: Plan,
    pose: Pose2D,
    field: DistanceField,
    grid: GridMap,
    planner: FMMPlanner,
    motion: MotionState,
    detour_after_turns: int = 0,
) -> tuple[Action, MotionState]:
    """The plan's action, unless it is a forward move that already failed from this very
    cell and heading: then turn towards the side the path bends to. And when the plan turns
    back to such a heading (it points between two 30 deg headings and the nearer one is
    blocked), step forward on the current heading instead, to get round what blocked the move,
    rather than turn to and fro on the spot; only where the map shows that step traversible.

    ``detour_after_turns`` N > 0: after N turns to and fro on the spot, side-step (``detour``).
    Returns the action and the updated memory (``blocked_repeats`` counts the moves refused since
    the robot last moved forward: the plan's own turns in between do not reset it, or a to-and-fro
    between a refused heading and its neighbour would never count past one)."""
    key = move_key(grid, pose)
    if motion.detour is not None:
        di, dj, dh = motion.detour
        if (di, dj) != key[:2]:
            motion = replace(motion, detour=None)  # stepped off the cell: the detour is done
        elif key[2] == dh:
            return Action.MOVE_FORWARD, replace(motion, detour=None, blocked_repeats=0)
        else:
            return _turn_to_bin(key[2], dh), motion
    if 0 < detour_after_turns <= motion.alternating_turns:
        h = detour_heading(plan, pose, field, grid, planner, motion)
        if h is not None:
            motion = replace(motion, detour=(key[0], key[1], h))
            if h == key[2]:
                return Action.MOVE_FORWARD, replace(motion, detour=None, blocked_repeats=0)
            return _turn_to_bin(key[2], h), motion
    if plan.action in (Action.TURN_LEFT, Action.TURN_RIGHT):
        sign = 1.0 if plan.action == Action.TURN_LEFT else -1.0
        turned = Pose2D(pose.x_m, pose.y_m, pose.yaw_rad + sign * math.radians(TURN_ANGLE_DEG))
        if move_key(grid, turned) in motion.blocked and key not in motion.blocked:
            here = np.array([pose.x_m, pose.y_m])
            ahead = here + FORWARD_STEP_M * np.array([math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)])
            if planner.line_free(grid, field, here, ahead):
                return Action.MOVE_FORWARD, motion
    if plan.action != Action.MOVE_FORWARD or key not in motion.blocked:
        return plan.action, motion
    path = plan.path_xy_m
    far = path[min(len(path) - 1, 8)]
    err = wrap_angle(math.atan2(far[1] - pose.y_m, far[0] - pose.x_m) - pose.yaw_rad)
    return (Action.TURN_LEFT if err >= 0 else Action.TURN_RIGHT), replace(
        motion, blocked_repeats=motion.blocked_repeats + 1
    )


def detour_heading(
    plan: Plan,
    pose: Pose2D,
    field: DistanceField,
    grid: GridMap,
    planner: FMMPlanner,
    motion: MotionState,
    aim_m: float = 1.0,
) -> int | None:
    """The heading bin of a side-step out of a to-and-fro run, or None.

    The run means the plan's next move is one that failed from here and every turn away from it
    turns back (the path hugs a corner the map does not show where the robot meets it). Of the
    12 forward steps from this cell, the candidates are those not remembered as failed that the
    map shows traversible; the chosen one ends nearest to the point ``aim_m`` along the path,
    and must end nearer to it than the robot is now. Ties go to the smaller turn."""
    path = plan.path_xy_m
    if len(path) < 2:
        return None
    seg = np.hypot(*np.diff(path, axis=0).T)
    along = np.concatenate([[0.0], np.cumsum(seg)])
    aim = path[min(int(np.searchsorted(along, aim_m)), len(path) - 1)]
    here = np.array([pose.x_m, pose.y_m])
    i, j, cur = move_key(grid, pose)
    best: tuple[float, int, int] | None = None
    for b in range(N_HEADINGS):
        if (i, j, b) in motion.blocked:
            continue
        yaw = b * math.radians(TURN_ANGLE_DEG)
        ahead = here + FORWARD_STEP_M * np.array([math.cos(yaw), math.sin(yaw)])
        if not planner.line_free(grid, field, here, ahead):
            continue
        turn = min((b - cur) % N_HEADINGS, (cur - b) % N_HEADINGS)
        cand = (float(np.hypot(*(ahead - aim))), turn, b)
        if best is None or cand[:2] < best[:2]:
            best = cand
    if best is None or best[0] >= float(np.hypot(*(here - aim))):
        return None
    return best[2]


def _turn_to_bin(cur: int, target: int) -> Action:
    return Action.TURN_LEFT if (target - cur) % N_HEADINGS <= N_HEADINGS // 2 else Action.TURN_RIGHT


def after_action(motion: MotionState, action: Action) -> MotionState:
    """The memory after the robot took ``action``: the run of alternating turns (left, right,
    left, ... on the spot: a turn never moves the robot) that ends with it."""
    turns = (Action.TURN_LEFT, Action.TURN_RIGHT)
    if action == Action.MOVE_FORWARD:
        motion = replace(motion, blocked_repeats=0)
    if action not in turns:
        n = 0
    elif motion.last_action in turns and motion.last_action != action:
        n = max(motion.alternating_turns, 1) + 1
    else:
        n = 1
    return replace(motion, alternating_turns=n, last_action=action)
