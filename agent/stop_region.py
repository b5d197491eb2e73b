"""Where the agent stops at a goal candidate (docs/architecture.md section 2, local navigation):
success is decided within 1.0 m of the object and seeing it.

* the core: the cells the stop region is measured from, the cells of the share of the
  candidate's *points* nearest their median, so that each cell weighs by the evidence in it (a
  few stray points spread over many cells: on val a third of a TV's cells held 3% of its points,
  0.4-0.9 m in front of it);
* the line of sight on the map from a stop cell to the core;
* one object on the map: the core's cells on an obstacle of the map other than the one that
  holds most of its points are dropped. The goal mask leaks onto what stands before the
  object (furniture in front of a couch): those points are on another obstacle, separated
  from the object by free floor, and a stop measured from them ends short of the object
  (two val homes under the ``stretch`` profile stopped 1.02 and 1.12 m from the object:
  docs/experiments/stop-one-object.md);
* the side the candidate was seen from: the cells around it within 90 degrees of a direction
  it was seen from. A bed or TV against a wall is, on the map, one obstacle with the wall, so
  the line of sight alone lets a stop cell behind that wall through (two later goals on
  ``trainseq10s2``, recalled from memory, stopped there facing the wall:
  docs/experiments/seen-side.md).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from agent.config import PolicyConfig
from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.planner import region_within


def core_points(cand: Candidate, quantile: float) -> np.ndarray:
    """(M, 3) the share ``quantile`` of the candidate's points nearest (in xy) to their median."""
    pts = cand.points_xyz
    med = np.median(pts[:, :2], axis=0)
    d = np.hypot(pts[:, 0] - med[0], pts[:, 1] - med[1])
    return pts[d <= np.quantile(d, quantile)]


def core_cells(grid: GridMap, cand: Candidate, quantile: float, one_object: bool = False) -> np.ndarray:
    """(K, 2) in-bounds cells of the candidate's core: the cells of the share ``quantile`` of its
    points nearest to their median, so that each cell weighs by the evidence in it; with
    ``one_object``, only those of them on one object of the map (``on_one_object``)."""
    keep, counts = np.unique(grid.xy_to_ij(core_points(cand, quantile)[:, :2]), axis=0, return_counts=True)
    inside = grid.in_bounds(keep)
    keep, counts = keep[inside], counts[inside]
    return on_one_object(grid, keep, counts) if one_object else keep


NEAR_OBSTACLE_CELLS = 2  # a goal cell this near (0.1 m at 0.05 m cells) an obstacle cell is on it
OBJECT_WINDOW_CELLS = 10  # obstacles are joined within the cells' box and this margin around it


def on_one_object(grid: GridMap, cells: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The ``cells`` (K, 2) on the one obstacle of the map that holds most of their points
    (``counts`` per cell), and those on no obstacle (not mapped yet). Obstacles are the map's
    8-connected obstacle cells within the cells' box (and ``OBJECT_WINDOW_CELLS`` around it); a
    cell is on the obstacle it touches within ``NEAR_OBSTACLE_CELLS``. With no cell on an
    obstacle: all of them."""
    if len(cells) == 0:
        return cells
    lo = np.maximum(cells.min(axis=0) - OBJECT_WINDOW_CELLS, 0)
    hi = np.minimum(cells.max(axis=0) + OBJECT_WINDOW_CELLS + 1, np.asarray(grid.shape))
    labels, n = ndimage.label(grid.layers.obstacle[lo[0] : hi[0], lo[1] : hi[1]], structure=np.ones((3, 3)))
    if n == 0:
        return cells
    size = 2 * NEAR_OBSTACLE_CELLS + 1
    near = np.where(labels > 0, labels, ndimage.grey_dilation(labels, size=(size, size)))
    on = near[cells[:, 0] - lo[0], cells[:, 1] - lo[1]]
    weight = np.bincount(on, weights=counts, minlength=n + 1)
    weight[0] = 0.0
    if weight.max() <= 0.0:
        return cells
    return cells[(on == 0) | (on == int(np.argmax(weight)))]


def stop_cells(grid: GridMap, cand: Candidate, pc: PolicyConfig) -> np.ndarray:
    """(H, W) bool: the cells the stop region is measured from. ``stop_rule="radius"``: all the
    candidate's cells (the goal layer). ``"core"``: its core (``core_cells``), so that stray
    points (depth at a keypoint on the object's edge read off what stands behind or before it)
    do not pull the stop point off the object."""
    if pc.stop_rule == "radius" or len(cand.cells_ij) < 4:
        return grid.layers.goal
    keep = core_cells(grid, cand, pc.stop_core_quantile, pc.stop_one_object)
    mask = np.zeros(grid.shape, bool)
    mask[keep[:, 0], keep[:, 1]] = True
    return mask


def in_sight(grid: GridMap, region: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The cells of ``region`` with a line of sight on the map to the centre of ``target``
    cells (success needs the object in view from the stop point): no obstacle cell on the
    segment, except those within 0.3 m of the target (the object itself). When no cell is in
    sight yet: the plain region."""
    cells = np.argwhere(region)
    tij = np.argwhere(target)
    if len(cells) == 0 or len(tij) == 0:
        return region
    centre = np.median(tij, axis=0)
    own = region_within(target, 0.3, grid.resolution_m)
    blocking = grid.layers.obstacle & ~own
    n = 48  # samples per segment: about 5 cm apart over 2.4 m
    t = np.linspace(0.0, 1.0, n)[None, :, None]
    pts = np.rint(cells[:, None, :] * (1 - t) + centre[None, None, :] * t).astype(np.int64)
    pts[..., 0] = np.clip(pts[..., 0], 0, grid.shape[0] - 1)
    pts[..., 1] = np.clip(pts[..., 1], 0, grid.shape[1] - 1)
    out = np.zeros_like(region)
    clear = ~blocking[pts[..., 0], pts[..., 1]].any(axis=1)
    out[cells[clear, 0], cells[clear, 1]] = True
    return out if out.any() else region


def seen_side(grid: GridMap, region: np.ndarray, target: np.ndarray, seen_from_xy_m: np.ndarray) -> np.ndarray:
    """The cells of ``region`` on a side the candidate was seen from: the direction from the
    centre of ``target`` cells to the cell lies within 90 degrees of the direction to one of the
    places it was seen from (``Candidate.seen_from_xy_m``, run frame). What was seen is a
    surface facing those places, so a cell there can see it; a cell on the far side may face
    the wall it stands against. When no place is known, or no cell of the region is on a seen
    side: the plain region."""
    seen = np.asarray(seen_from_xy_m, np.float64).reshape(-1, 2)
    cells = np.argwhere(region)
    tij = np.argwhere(target)
    if len(seen) == 0 or len(cells) == 0 or len(tij) == 0:
        return region
    centre = grid.ij_to_xy(np.median(tij, axis=0)[None])[0]
    to_cell = grid.ij_to_xy(cells) - centre
    to_seen = seen - centre
    keep = ((to_cell @ to_seen.T) >= 0.0).any(axis=1)
    if not keep.any():
        return region
    out = np.zeros_like(region)
    out[cells[keep, 0], cells[keep, 1]] = True
    return out
