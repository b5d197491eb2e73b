"""Shortest action sequences on the robot's discrete motion lattice (A*).

The robot moves in 0.25 m steps along 12 headings (30 deg turns, docs/architecture.md section 1),
so the positions it can reach form a lattice anchored at its start pose. A
continuous shortest path (the fast-marching geodesic) is a lower bound that the
lattice can only approximate; this search finds the action sequence with the
shortest *lattice* path to a goal region, using the real collision-checked step
(``SimWorld.move``) so the plan replays exactly, and the geodesic field as the
A* heuristic.

States are merged when they agree to ``MERGE_M`` in position and in heading;
each stored state keeps its exact pose, so replaying the returned actions from
the start reproduces the poses bit for bit.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agent.types import FORWARD_STEP_M, VIEWPOINT_SUCCESS_RADIUS_M, Action, Pose2D

log = logging.getLogger(__name__)

MERGE_M = 0.02
TURN_COST = 1e-3  # path length is what SPL counts; turns only break ties
MAX_EXPANSIONS = 150_000


@dataclass(frozen=True, slots=True)
class LatticePlan:
    actions: tuple[Action, ...]  # ends with STOP
    poses_world: tuple[Pose2D, ...]  # pose after each action (the last one is the stop pose)
    path_length_m: float
    expansions: int


class ViewpointGoal:
    """Goal test: within the success radius of any viewpoint, less a small safety margin so
    the stop position is a success whatever the rounding. Viewpoints are bucketed in cells
    of the radius, so a query looks at the 3 x 3 cells around it."""

    def __init__(
        self, viewpoints_xy_m: np.ndarray, radius_m: float = VIEWPOINT_SUCCESS_RADIUS_M, margin_m: float = 1e-4
    ) -> None:
        self.radius_m = radius_m - margin_m
        self._cell = radius_m
        self._buckets: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for x, y in np.asarray(viewpoints_xy_m, dtype=np.float64).reshape(-1, 2).tolist():
            self._buckets.setdefault((math.floor(x / self._cell), math.floor(y / self._cell)), []).append((x, y))

    def __call__(self, x_m: float, y_m: float) -> bool:
        bi, bj = math.floor(x_m / self._cell), math.floor(y_m / self._cell)
        r2 = self.radius_m * self.radius_m
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for x, y in self._buckets.get((bi + di, bj + dj), ()):
                    if (x - x_m) ** 2 + (y - y_m) ** 2 <= r2:
                        return True
        return False


def plan_to_goal(
    move: Callable[[Pose2D, Action], tuple[Pose2D, bool]],
    start: Pose2D,
    is_goal: Callable[[float, float], bool],
    heuristic: Callable[[float, float], float],
    weight: float = 1.0,
    max_expansions: int = MAX_EXPANSIONS,
) -> LatticePlan | None:
    """A* from ``start`` to the first pose where ``is_goal`` holds; None if none is reachable.

    heuristic: lower bound on the remaining path length in metres (inf = unreachable)."""
    turn = math.radians(30.0)

    def key(p: Pose2D) -> tuple[int, int, int]:
        k = int(round((p.yaw_rad - start.yaw_rad) / turn)) % 12
        return (int(round(p.x_m / MERGE_M)), int(round(p.y_m / MERGE_M)), k)

    if is_goal(start.x_m, start.y_m):
        return LatticePlan((Action.STOP,), (start,), 0.0, 0)
    h0 = heuristic(start.x_m, start.y_m)
    if not math.isfinite(h0):
        return None
    poses: list[Pose2D] = [start]
    parent: list[int] = [-1]
    via: list[Action] = [Action.STOP]
    g_cost: list[float] = [0.0]
    best: dict[tuple[int, int, int], float] = {key(start): 0.0}
    heap: list[tuple[float, float, int]] = [(weight * h0, 0.0, 0)]
    expansions = 0
    goal_node = -1
    while heap:
        _, g, node = heapq.heappop(heap)
        pose = poses[node]
        if g > best.get(key(pose), math.inf) + 1e-12:
            continue
        if is_goal(pose.x_m, pose.y_m):
            goal_node = node
            break
        expansions += 1
        if expansions > max_expansions:
            log.debug("lattice search gave up after %d expansions", expansions)
            return None
        for action, cost in (
            (Action.MOVE_FORWARD, FORWARD_STEP_M),
            (Action.TURN_LEFT, TURN_COST),
            (Action.TURN_RIGHT, TURN_COST),
        ):
            nxt, moved = move(pose, action)
            if not moved:
                continue
            ng = g + cost
            k = key(nxt)
            if ng >= best.get(k, math.inf) - 1e-12:
                continue
            h = heuristic(nxt.x_m, nxt.y_m)
            if not math.isfinite(h):
                continue
            best[k] = ng
            poses.append(nxt)
            parent.append(node)
            via.append(action)
            g_cost.append(ng)
            heapq.heappush(heap, (ng + weight * h, ng, len(poses) - 1))
    if goal_node < 0:
        return None
    actions: list[Action] = []
    seq: list[Pose2D] = []
    n = goal_node
    while parent[n] >= 0:
        actions.append(via[n])
        seq.append(poses[n])
        n = parent[n]
    actions.reverse()
    seq.reverse()
    length = sum(FORWARD_STEP_M for a in actions if a == Action.MOVE_FORWARD)
    final = seq[-1] if seq else start
    return LatticePlan(tuple(actions) + (Action.STOP,), tuple(seq) + (final,), length, expansions)
