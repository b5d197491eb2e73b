"""Where the agent stops at a goal candidate (DESIGN section 2, local navigation; issue 13's
"stop where success is"): success is decided within 1.0 m of the object and seeing it.

* the core: the cells the stop region is measured from, the candidate's cells nearest the median
  of its points (``stop_core_by="points"``: the cells of the share of its *points* nearest the
  median, so that each cell weighs by the evidence in it);
* the line of sight on the map from a stop cell to the core;
* the view at the stop: which of the core's points the depth frame shows, and what hides the
  others (``stop_needs_view``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from agent.config import PolicyConfig
from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.planner import region_within
from agent.projection import lift_pixels, view_of_points
from agent.types import Observation


def core_points(cand: Candidate, quantile: float) -> np.ndarray:
    """(M, 3) the share ``quantile`` of the candidate's points nearest (in xy) to their median."""
    pts = cand.points_xyz
    med = np.median(pts[:, :2], axis=0)
    d = np.hypot(pts[:, 0] - med[0], pts[:, 1] - med[1])
    return pts[d <= np.quantile(d, quantile)]


def core_cells(grid: GridMap, cand: Candidate, quantile: float, by: str = "points") -> np.ndarray:
    """(K, 2) in-bounds cells of the candidate's core: those nearest to the median of its points.
    ``by="points"``: the cells of the share ``quantile`` of its points nearest to the median,
    so that each cell weighs by the evidence in it; ``by="cells"``: that share of its cells."""
    if by == "points":
        keep = np.unique(grid.xy_to_ij(core_points(cand, quantile)[:, :2]), axis=0)
    elif by == "cells":
        med = np.median(cand.points_xyz[:, :2], axis=0)
        xy = grid.ij_to_xy(cand.cells_ij)
        d = np.hypot(xy[:, 0] - med[0], xy[:, 1] - med[1])
        keep = cand.cells_ij[d <= np.quantile(d, quantile)]
    else:
        raise ValueError(f"core_cells: unknown by={by!r}")
    return keep[grid.in_bounds(keep)]


def stop_cells(grid: GridMap, cand: Candidate, pc: PolicyConfig) -> np.ndarray:
    """(H, W) bool: the cells the stop region is measured from. ``stop_rule="radius"``: all the
    candidate's cells (the goal layer). ``"core"``: its core (``core_cells``), so that stray
    points (depth at a keypoint on the object's edge read off what stands behind or before it)
    do not pull the stop point off the object."""
    if pc.stop_rule == "radius" or len(cand.cells_ij) < 4:
        return grid.layers.goal
    keep = core_cells(grid, cand, pc.stop_core_quantile, pc.stop_core_by)
    mask = np.zeros(grid.shape, bool)
    mask[keep[:, 0], keep[:, 1]] = True
    return mask


def cells_near(grid: GridMap, xy_m: Sequence[tuple[float, float]], radius_m: float) -> np.ndarray:
    """(H, W) bool: the cells within ``radius_m`` of the run-frame points ``xy_m`` (in the map)."""
    mask = np.zeros(grid.shape, bool)
    if not len(xy_m):
        return mask
    ij = grid.xy_to_ij(np.asarray(xy_m, np.float64))
    ij = ij[grid.in_bounds(ij)]
    mask[ij[:, 0], ij[:, 1]] = True
    return region_within(mask, radius_m, grid.resolution_m)


def in_sight(grid: GridMap, region: np.ndarray, target: np.ndarray, occluder: np.ndarray | None = None) -> np.ndarray:
    """The cells of ``region`` with a line of sight on the map to the centre of ``target``
    cells (success needs the object in view from the stop point): no obstacle cell on the
    segment, except those within 0.3 m of the target (the object itself), and no ``occluder``
    cell (what was seen to hide the candidate counts however near the object it is). When no
    cell is in sight: those clear of the occluder alone, else the plain region."""
    cells = np.argwhere(region)
    tij = np.argwhere(target)
    if len(cells) == 0 or len(tij) == 0:
        return region
    centre = np.median(tij, axis=0)
    own = region_within(target, 0.3, grid.resolution_m)
    blocking = grid.layers.obstacle & ~own
    if occluder is not None:
        blocking |= occluder
    n = 48  # samples per segment: about 5 cm apart over 2.4 m
    t = np.linspace(0.0, 1.0, n)[None, :, None]
    pts = np.rint(cells[:, None, :] * (1 - t) + centre[None, None, :] * t).astype(np.int64)
    pts[..., 0] = np.clip(pts[..., 0], 0, grid.shape[0] - 1)
    pts[..., 1] = np.clip(pts[..., 1], 0, grid.shape[1] - 1)
    out = np.zeros_like(region)
    clear = ~blocking[pts[..., 0], pts[..., 1]].any(axis=1)
    out[cells[clear, 0], cells[clear, 1]] = True
    if out.any() or occluder is None:
        return out if out.any() else region  # nothing in sight yet: the plain region
    # nothing in sight on the map: still keep out what was seen to hide the candidate
    clear = ~occluder[pts[..., 0], pts[..., 1]].any(axis=1)
    out[cells[clear, 0], cells[clear, 1]] = True
    return out if out.any() else region


def core_view(grid: GridMap, cand: Candidate, obs: Observation, pc: PolicyConfig) -> tuple[int, int, np.ndarray | None]:
    """How the depth frame sees the candidate's core: (points in the frame with a depth
    reading, those seen, and None unless it is hidden: then the (M, 2) run-frame xy of what
    hides it, the frame's points before the unseen ones). Hidden: at least
    ``stop_view_min_points`` in the frame and fewer than ``stop_view_min_share`` of them
    seen. Points out of the frame, or where the depth has no reading, are no evidence."""
    ok, seen, uv = view_of_points(core_points(cand, pc.stop_core_quantile), obs, pc.stop_view_margin_m,
                                  pc.stop_view_margin_frac)
    hid = ok & ~seen
    occluder = np.zeros((0, 2))
    if hid.any():
        # what the frame shows there instead: the object's own near side (seen from another
        # side than its points were) counts as seen, anything else hides it
        u, v = uv[hid, 0], uv[hid, 1]
        xy = lift_pixels(u, v, obs.depth_m[v, u], obs.intrinsics, obs.pose, obs.camera_height_m,
                         obs.camera_tilt_rad).xyz_run[:, :2].astype(np.float64)
        own = np.zeros(grid.shape, bool)
        cells = cand.cells_ij[grid.in_bounds(cand.cells_ij)]
        own[cells[:, 0], cells[:, 1]] = True
        own = region_within(own, pc.stop_view_own_m, grid.resolution_m)
        ij = grid.xy_to_ij(xy)
        inb = grid.in_bounds(ij)
        on_obj = np.zeros(len(xy), bool)
        on_obj[inb] = own[ij[inb, 0], ij[inb, 1]]
        seen[np.flatnonzero(hid)[on_obj]] = True
        occluder = xy[~on_obj]
    n_in, n_seen = int(ok.sum()), int(seen.sum())
    if n_in < pc.stop_view_min_points or n_seen >= pc.stop_view_min_share * n_in:
        return n_in, n_seen, None
    return n_in, n_seen, occluder
