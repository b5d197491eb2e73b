"""Local navigation by fast marching (docs/architecture.md section 2.4).

One geodesic distance field per step is computed *from the agent* with scikit-fmm over the
traversible map (obstacles and collision marks dilated by the robot radius; unexplored
space is optimistically traversible, as in frontier exploration). The same field ranks
frontiers by geodesic distance, finds the nearest reachable cell of a goal region, and
gives the path: steepest descent from the chosen target back to the agent. The action
heads for a look-ahead point on that path with the discrete action set.

Failures (no reachable target) raise ``PlanError`` with a reason code; the policy records
it (``AgentRecord.planner_error``) and reacts. They are never turned into a silent STOP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import skfmm

from agent.mapping import GridMap
from agent.types import ROBOT_RADIUS_M, TURN_ANGLE_DEG, Action, Pose2D, wrap_angle


class PlanError(RuntimeError):
    """No plan: ``reason`` is ``unreachable`` (no target cell reachable) or ``no_target``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    robot_radius_m: float = ROBOT_RADIUS_M
    # Cells whose centre is closer than radius + margin to an obstacle cell's centre are
    # blocked. An obstacle can sit up to half a cell nearer than its cell centre, but a
    # larger margin closes the 0.4-0.5 m gaps beside furniture that the robot does fit
    # through; the rare graze becomes a collision mark.
    inflation_margin_m: float = 0.0
    lookahead_m: float = 0.5  # heading target along the path
    # Half a turn (+1 deg): some multiple of 30 deg is always within it, so turning never oscillates.
    turn_tolerance_deg: float = TURN_ANGLE_DEG / 2.0 + 1.0
    crop_margin_m: float = 1.5  # FMM window = bbox(explored, agent, targets) + margin
    fmm_order: int = 1


@dataclass(frozen=True, slots=True, eq=False)
class DistanceField:
    """Geodesic distance from the agent over a window of the map.

    distance_m:  (h, w) float32, inf where unreachable; window cell (a, b) is map cell
                 (a + offset_ij[0], b + offset_ij[1]).
    traversible: (h, w) bool of the same window.
    """

    distance_m: np.ndarray
    traversible: np.ndarray
    offset_ij: tuple[int, int]
    agent_ij: tuple[int, int]  # map cell

    def window(self, layer: np.ndarray) -> np.ndarray:
        h, w = self.distance_m.shape
        return layer[self.offset_ij[0] : self.offset_ij[0] + h, self.offset_ij[1] : self.offset_ij[1] + w]

    def at(self, ij_map: np.ndarray) -> np.ndarray:
        """Distances (N,) of map cells (N, 2); inf outside the window."""
        ij = np.asarray(ij_map, np.int64).reshape(-1, 2) - np.asarray(self.offset_ij)
        h, w = self.distance_m.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < h) & (ij[:, 1] >= 0) & (ij[:, 1] < w)
        out = np.full(len(ij), np.inf, np.float32)
        out[ok] = self.distance_m[ij[ok, 0], ij[ok, 1]]
        return out


@dataclass(frozen=True, slots=True, eq=False)
class Plan:
    """The chosen target and the first action towards it.

    path_xy_m: (K, 2) float32 run-frame path from the agent to the target.
    """

    action: Action
    target_ij: tuple[int, int]
    target_xy_m: tuple[float, float]
    distance_m: float
    path_xy_m: np.ndarray


def disk_kernel(radius_cells: float) -> np.ndarray:
    """(2n+1, 2n+1) uint8: offsets strictly closer than ``radius_cells`` (a real number)."""
    n = int(math.ceil(radius_cells))
    ii, jj = np.mgrid[-n : n + 1, -n : n + 1]
    return (ii * ii + jj * jj < radius_cells * radius_cells).astype(np.uint8)


class FMMPlanner:
    def __init__(self, config: PlannerConfig = PlannerConfig()) -> None:
        self.config = config

    def inflation_radius_cells(self, resolution_m: float) -> float:
        return (self.config.robot_radius_m + self.config.inflation_margin_m) / resolution_m

    def distance_field(self, grid: GridMap, pose: Pose2D, extra_targets: np.ndarray | None = None) -> DistanceField:
        """FMM from the agent's cell. ``extra_targets`` (H, W) bool only widens the window."""
        cfg = self.config
        L = grid.layers
        h, w = grid.shape
        ai, aj = grid.cell_of(pose)
        if not (0 <= ai < h and 0 <= aj < w):
            grid.ensure_contains((pose.x_m, pose.y_m), (pose.x_m, pose.y_m))
            L = grid.layers
            h, w = grid.shape
            ai, aj = grid.cell_of(pose)
        # window: bounding box of everything relevant plus a margin
        content = L.explored | L.collision
        if extra_targets is not None:
            content = content | extra_targets
        rows = np.flatnonzero(content.any(axis=1))
        cols = np.flatnonzero(content.any(axis=0))
        m = int(math.ceil(cfg.crop_margin_m / grid.resolution_m))
        i0 = max(min(ai, rows[0] if len(rows) else ai) - m, 0)
        i1 = min(max(ai, rows[-1] if len(rows) else ai) + m + 1, h)
        j0 = max(min(aj, cols[0] if len(cols) else aj) - m, 0)
        j1 = min(max(aj, cols[-1] if len(cols) else aj) + m + 1, w)
        blocked_raw = (L.obstacle | L.collision)[i0:i1, j0:j1]
        r = self.inflation_radius_cells(grid.resolution_m)
        kernel = disk_kernel(r)
        inflated = cv2.dilate(blocked_raw.astype(np.uint8), kernel).astype(bool)
        # A collision mark is a failed move, not a seen surface: its whole inflation stays
        # blocked, so no path squeezes past it at a slightly different heading.
        collision_zone = cv2.dilate(L.collision[i0:i1, j0:j1].astype(np.uint8), kernel).astype(bool)
        trav = ~inflated | (L.visited[i0:i1, j0:j1] & ~blocked_raw & ~collision_zone)
        # The agent is physically where it is: clear the inflation of seen obstacles (never
        # the obstacles, nor a collision mark's zone) in a disk around it, so a robot that
        # got close to a wall can still plan.
        a = (ai - i0, aj - j0)
        ii, jj = np.ogrid[0 : i1 - i0, 0 : j1 - j0]
        near = (ii - a[0]) ** 2 + (jj - a[1]) ** 2 <= r * r
        trav |= near & ~blocked_raw & ~collision_zone
        trav[a] = True
        phi = np.ones(trav.shape, np.float64)
        phi[a] = 0.0
        d = skfmm.distance(np.ma.MaskedArray(phi, ~trav), dx=grid.resolution_m, order=cfg.fmm_order)
        dist = np.ma.filled(d.astype(np.float32), np.inf)
        dist[~trav] = np.inf
        return DistanceField(dist, trav, (i0, j0), (ai, aj))

    def plan(self, grid: GridMap, field: DistanceField, pose: Pose2D, target_mask: np.ndarray) -> Plan:
        """Path and first action towards the nearest reachable cell of ``target_mask`` (H, W) bool.

        Raises ``PlanError('no_target')`` for an empty mask, ``PlanError('unreachable')``
        when no target cell is reachable.
        """
        if not target_mask.any():
            raise PlanError("no_target", "target mask is empty")
        tw = field.window(target_mask)
        d = np.where(tw, field.distance_m, np.inf)
        k = int(np.argmin(d))
        if not np.isfinite(d.flat[k]):
            raise PlanError("unreachable", f"none of {int(target_mask.sum())} target cells is reachable")
        t_win = np.unravel_index(k, d.shape)
        target_ij = (int(t_win[0] + field.offset_ij[0]), int(t_win[1] + field.offset_ij[1]))
        path_win = descend(field.distance_m, (int(t_win[0]), int(t_win[1])))[::-1]
        path_ij = path_win + np.asarray(field.offset_ij)
        path_xy = grid.ij_to_xy(path_ij).astype(np.float32)
        path_xy[0] = (pose.x_m, pose.y_m)
        action = self.action_along(path_xy, pose, grid, field)
        txy = grid.ij_to_xy(np.array([target_ij]))[0]
        return Plan(action, target_ij, (float(txy[0]), float(txy[1])), float(d.flat[k]), path_xy)

    def action_along(
        self, path_xy: np.ndarray, pose: Pose2D, grid: GridMap | None = None, field: DistanceField | None = None
    ) -> Action:
        """Turn towards the look-ahead point on the path, or move forward when facing it.

        The look-ahead point is the farthest path point within ``lookahead_m`` that the robot
        sees in a straight traversible line (so it does not cut corners of the path)."""
        here = np.array([pose.x_m, pose.y_m])
        dist = np.hypot(*(path_xy - here).T)
        within = np.flatnonzero(dist <= self.config.lookahead_m)
        k = int(within[-1]) if len(within) else len(path_xy) - 1
        if grid is not None and field is not None:
            while k > 1 and not self.line_free(grid, field, here, path_xy[k]):
                k -= 1
        p = path_xy[max(k, min(1, len(path_xy) - 1))]
        if np.hypot(*(p - here)) < 1e-6:
            return Action.TURN_LEFT  # degenerate (target at the agent); callers check 'reached' first
        return self.turn_towards(math.atan2(p[1] - pose.y_m, p[0] - pose.x_m), pose) or Action.MOVE_FORWARD

    @staticmethod
    def line_free(grid: GridMap, field: DistanceField, a_xy: np.ndarray, b_xy: np.ndarray) -> bool:
        n = max(2, int(math.ceil(float(np.hypot(*(b_xy - a_xy))) / (0.5 * grid.resolution_m))) + 1)
        ij = grid.xy_to_ij(np.linspace(a_xy, b_xy, n)) - np.asarray(field.offset_ij)
        h, w = field.traversible.shape
        if np.any((ij[:, 0] < 0) | (ij[:, 0] >= h) | (ij[:, 1] < 0) | (ij[:, 1] >= w)):
            return False
        return bool(field.traversible[ij[:, 0], ij[:, 1]].all())

    def turn_towards(self, bearing_rad: float, pose: Pose2D) -> Action | None:
        """The turn that reduces the heading error, or None when within tolerance."""
        err = wrap_angle(bearing_rad - pose.yaw_rad)
        if abs(err) <= math.radians(self.config.turn_tolerance_deg):
            return None
        return Action.TURN_LEFT if err > 0 else Action.TURN_RIGHT


def descend(distance: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Steepest descent on a distance field (8-neighbourhood) from ``start`` to its zero.

    Returns (K, 2) int64 cells from ``start`` to the source. Stops early at a cell with
    no lower neighbour (cannot happen on an exact FMM field; guards numerical plateaus).
    """
    h, w = distance.shape
    padded = np.full((h + 2, w + 2), np.inf, np.float32)
    padded[1:-1, 1:-1] = distance
    offsets = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])
    cur = np.array(start, np.int64)
    path = [cur.copy()]
    for _ in range(h * w):
        here = padded[cur[0] + 1, cur[1] + 1]
        if here <= 0.0:
            break
        nb = padded[cur[0] + 1 + offsets[:, 0], cur[1] + 1 + offsets[:, 1]]
        k = int(np.argmin(nb))
        if not nb[k] < here:
            break
        cur = cur + offsets[k]
        path.append(cur.copy())
    return np.asarray(path, np.int64)


def region_within(cells: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Cells (H, W) bool within ``radius_m`` (Euclidean, cell centres) of any True cell."""
    if not cells.any():
        return np.zeros_like(cells)
    dt = cv2.distanceTransform((~cells).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return dt * resolution_m <= radius_m
