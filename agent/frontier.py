"""Frontier-based exploration (Yamauchi 1997; docs/architecture.md section 2.1).

A frontier cell is an explored, free cell with an unexplored 4-neighbour. Frontier cells
are grouped into 8-connected clusters; clusters smaller than ``min_cluster_cells`` are
noise. The target is the reachable frontier cell nearest to the agent by geodesic distance
(read from the planner's distance field). It is kept until reached, until it stops being a
frontier, or until it proves unreachable or yields no progress; reached and failed targets
are blacklisted (a disk on the map's ``frontier_blacklist`` layer) so the agent does not
return to them. That layer is separate from the goal-candidate blacklist: when nothing is
left to explore, the policy forgives it (a doorway "reached" from the side may still lead
somewhere) while rejected goal candidates stay rejected.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from agent.mapping import GridMap
from agent.planner import DistanceField

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class FrontierConfig:
    min_cluster_cells: int = 5  # 25 cm of boundary at 5 cm cells
    reached_radius_m: float = 0.5  # geodesic distance at which a frontier counts as reached
    blacklist_radius_m: float = 0.5
    switch_margin_m: float = 1.0  # keep the current target unless another is this much nearer
    no_progress_steps: int = 25  # no decrease of the geodesic distance in this many steps -> give up


def frontier_mask(grid: GridMap, min_cluster_cells: int = 5) -> np.ndarray:
    """(H, W) bool frontier cells (explored free with an unexplored 4-neighbour), not blacklisted
    (neither as a frontier nor as a rejected goal candidate)."""
    L = grid.layers
    free = L.explored & ~L.obstacle & ~L.collision
    unexplored = ~L.explored
    nb = np.zeros_like(unexplored)
    nb[1:, :] |= unexplored[:-1, :]
    nb[:-1, :] |= unexplored[1:, :]
    nb[:, 1:] |= unexplored[:, :-1]
    nb[:, :-1] |= unexplored[:, 1:]
    front = free & nb & ~L.blacklist & ~L.frontier_blacklist
    if min_cluster_cells > 1 and front.any():
        n, labels, stats, _ = cv2.connectedComponentsWithStats(front.astype(np.uint8), connectivity=8)
        small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < min_cluster_cells)
        small = small[small > 0]
        if len(small):
            front &= ~np.isin(labels, small)
    return front


@dataclass(frozen=True, slots=True)
class FrontierChoice:
    target_xy_m: tuple[float, float]
    target_ij: tuple[int, int]
    distance_m: float
    reason: str  # "new", "kept"


class FrontierExplorer:
    """Chooses and tracks the exploration target. Targets are kept in run-frame metres,
    so they survive map growth."""

    def __init__(self, config: FrontierConfig = FrontierConfig()) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.target_xy_m: tuple[float, float] | None = None
        self._best_distance_m = np.inf
        self._steps_without_progress = 0

    def blacklist_target(self, grid: GridMap, why: str) -> None:
        if self.target_xy_m is not None:
            log.debug("blacklisting frontier %s (%s)", self.target_xy_m, why)
            grid.blacklist_disk(self.target_xy_m, self.config.blacklist_radius_m, layer="frontier_blacklist")
        self.reset()

    def choose(self, grid: GridMap, field: DistanceField, frontier: np.ndarray) -> FrontierChoice | None:
        """The frontier target for this step, or None when no frontier is reachable.

        ``frontier`` (H, W) bool from ``frontier_mask``. Blacklists the current target when
        reached or stuck, then picks the nearest reachable frontier cell.
        """
        cfg = self.config
        if self.target_xy_m is not None:
            kept = self._keep_current(grid, field, frontier)
            if kept is not None:
                return kept
        cells = np.argwhere(frontier)
        if len(cells) == 0:
            return None
        d = field.at(cells)
        ok = np.isfinite(d) & (d > cfg.reached_radius_m)
        if not ok.any():
            # every frontier is either unreachable or already at hand: blacklist the near ones
            for ij in cells[np.isfinite(d)]:
                grid.layers.frontier_blacklist[ij[0], ij[1]] = True
            return None
        k = int(np.argmin(np.where(ok, d, np.inf)))
        ij = (int(cells[k, 0]), int(cells[k, 1]))
        xy = grid.ij_to_xy(np.array([ij]))[0]
        self.target_xy_m = (float(xy[0]), float(xy[1]))
        self._best_distance_m = float(d[k])
        self._steps_without_progress = 0
        return FrontierChoice(self.target_xy_m, ij, float(d[k]), "new")

    def _keep_current(self, grid: GridMap, field: DistanceField, frontier: np.ndarray) -> FrontierChoice | None:
        cfg = self.config
        assert self.target_xy_m is not None
        ij = grid.xy_to_ij(np.array([self.target_xy_m]))[0]
        ij_t = (int(ij[0]), int(ij[1]))
        d = float(field.at(ij[None])[0])
        still_frontier = bool(grid.in_bounds(ij[None])[0]) and _near(frontier, ij_t, 2)
        if not still_frontier:
            self.reset()
            return None
        if not np.isfinite(d):
            self.blacklist_target(grid, "unreachable")
            return None
        if d <= cfg.reached_radius_m:
            self.blacklist_target(grid, "reached")
            return None
        if d < self._best_distance_m - 1e-3:
            self._best_distance_m = d
            self._steps_without_progress = 0
        else:
            self._steps_without_progress += 1
            if self._steps_without_progress > cfg.no_progress_steps:
                self.blacklist_target(grid, "no progress")
                return None
        # hysteresis: switch only if some other frontier is clearly nearer
        cells = np.argwhere(frontier)
        dd = field.at(cells)
        dd = np.where(dd > cfg.reached_radius_m, dd, np.inf)
        if len(dd) and float(dd.min()) < d - cfg.switch_margin_m:
            self.reset()
            return None
        return FrontierChoice(self.target_xy_m, ij_t, d, "kept")


def _near(mask: np.ndarray, ij: tuple[int, int], r: int) -> bool:
    h, w = mask.shape
    i0, i1 = max(ij[0] - r, 0), min(ij[0] + r + 1, h)
    j0, j1 = max(ij[1] - r, 0), min(ij[1] + r + 1, w)
    return bool(mask[i0:i1, j0:j1].any())
