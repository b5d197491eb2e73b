"""Ground-truth navigation quantities: goal viewpoints and geodesic distances.

* Viewpoints (docs/architecture.md section 1): navigable positions within 1.0 m of the goal
  instance from which it is visible. Candidates lie on a 0.1 m lattice (every
  other cell of the 0.05 m navigable grid), so the union of the 0.1 m success
  discs around them covers the whole viewpoint region without gaps. Visibility:
  rays from the camera's optical centre (1.31 m) to interior points of the
  instance's parts; the instance is visible when enough rays reach it first.
* Geodesic distances: fast marching (scikit-fmm) on the navigable grid from the
  viewpoint cells, so every position gets its shortest-path distance to the
  nearest viewpoint (used for the episode's shortest path, NE and planning).
"""

from __future__ import annotations

import math

import numpy as np
import skfmm
from scipy import ndimage

from agent.types import CAMERA_HEIGHT_M, SUCCESS_DISTANCE_M
from sim.geometry import NavGrid
from sim.home import SceneObject

GRID_RESOLUTION_M = 0.05
VIEWPOINT_STRIDE = 2  # cells: 0.1 m lattice
MIN_VISIBLE_FRACTION = 0.1
MIN_VISIBLE_RAYS = 2
MAX_SAMPLE_POINTS = 48


def reachable_component(grid: NavGrid, xy_m: tuple[float, float] | None = None) -> np.ndarray:
    """(H, W) bool: the 8-connected free component containing ``xy_m`` (the largest one if None)."""
    labels, n = ndimage.label(grid.navigable, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return np.zeros_like(grid.navigable)
    if xy_m is None:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        return labels == int(np.argmax(sizes))
    i, j = grid.xy_to_ij(np.array([xy_m]))[0]
    if not grid.inside(np.array([[i, j]]))[0] or labels[i, j] == 0:
        return np.zeros_like(grid.navigable)
    return labels == labels[i, j]


def geodesic_field(grid: NavGrid, target_xy_m: np.ndarray, free: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float64 shortest-path metres from each free cell to the nearest target; inf elsewhere.

    ``free`` restricts the traversable cells (default: the grid's navigable cells).
    Targets are snapped to their cells; cells that are not free are ignored."""
    free = grid.navigable if free is None else free
    ij = grid.xy_to_ij(np.asarray(target_xy_m, dtype=np.float64).reshape(-1, 2))
    ij = ij[grid.inside(ij)]
    ij = ij[free[ij[:, 0], ij[:, 1]]] if len(ij) else ij
    out = np.full(grid.shape, np.inf)
    if len(ij) == 0:
        return out
    phi = np.ones(grid.shape)
    phi[ij[:, 0], ij[:, 1]] = 0.0
    dist = skfmm.distance(np.ma.MaskedArray(phi, ~free), dx=grid.resolution_m)
    if isinstance(dist, np.ma.MaskedArray):
        out[~dist.mask] = dist.data[~dist.mask]
    else:
        out[:] = dist
    out[~free] = np.inf
    return out


def geodesic_at(field: np.ndarray, grid: NavGrid, x_m: float, y_m: float) -> float:
    """Field value at a continuous position: bilinear over finite cell centres, else the best
    neighbouring cell plus the straight distance to it (inf if none is reachable)."""
    res = grid.resolution_m
    fx = (x_m - grid.origin_xy_m[0]) / res - 0.5
    fy = (y_m - grid.origin_xy_m[1]) / res - 0.5
    j0, i0 = math.floor(fx), math.floor(fy)
    tx, ty = fx - j0, fy - i0
    h, w = field.shape
    if 0 <= i0 < h - 1 and 0 <= j0 < w - 1:
        a, b = field.item(i0, j0), field.item(i0, j0 + 1)
        c, d = field.item(i0 + 1, j0), field.item(i0 + 1, j0 + 1)
        v = (1 - ty) * ((1 - tx) * a + tx * b) + ty * ((1 - tx) * c + tx * d)
        if math.isfinite(v):
            return v
    best = math.inf
    ic, jc = math.floor(fy + 0.5), math.floor(fx + 0.5)
    for i in range(max(ic - 2, 0), min(ic + 3, h)):
        for j in range(max(jc - 2, 0), min(jc + 3, w)):
            f = field.item(i, j)
            if math.isfinite(f):
                cx = grid.origin_xy_m[0] + (j + 0.5) * res
                cy = grid.origin_xy_m[1] + (i + 0.5) * res
                best = min(best, f + math.hypot(cx - x_m, cy - y_m))
    return best


def instance_sample_points(obj: SceneObject, max_points: int = MAX_SAMPLE_POINTS) -> np.ndarray:
    """(N, 3) world points inside the instance's parts (centres and inner corners), for ray tests."""
    pts = []
    for p in obj.parts:
        if not p.solid:
            continue
        c = np.array(p.center_xyz_m)
        half = np.array(p.size_xyz_m) / 2.0 * 0.6
        cy, sy = math.cos(p.yaw_rad), math.sin(p.yaw_rad)
        rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        pts.append(c)
        for sx in (-1, 1):
            for sy_ in (-1, 1):
                for sz in (-1, 1):
                    pts.append(c + rot @ (half * [sx, sy_, sz]))
    arr = np.array(pts)
    if len(arr) > max_points:  # deterministic thinning that keeps every part represented
        arr = arr[np.linspace(0, len(arr) - 1, max_points).round().astype(int)]
    return arr


def instance_distance_grid(obj: SceneObject, grid: NavGrid) -> np.ndarray:
    """(H, W) float64: 2D distance from each cell centre to the instance's footprint."""
    xs, ys = grid.cell_centres()
    d = np.full(grid.shape, np.inf)
    for fp in obj.footprints():
        d = np.minimum(d, fp.distance_grid(xs, ys))
    return d


def instance_viewpoints(
    world, instance_id: int, free: np.ndarray | None = None, camera_height_m: float = CAMERA_HEIGHT_M
) -> np.ndarray:
    """(N, 2) float64 world xy of the instance's goal viewpoints (may be empty).

    world: a ``sim.world.SimWorld`` (navigable grid and ray tests).
    free: optional (H, W) bool restriction (e.g. the component reachable from a start)."""
    grid = world.navigable_grid(GRID_RESOLUTION_M)
    obj = world.home.instance(instance_id)
    mask = grid.navigable if free is None else (grid.navigable & free)
    stride = np.zeros(grid.shape, dtype=bool)
    stride[::VIEWPOINT_STRIDE, ::VIEWPOINT_STRIDE] = True
    near = instance_distance_grid(obj, grid) <= SUCCESS_DISTANCE_M
    ij = np.argwhere(mask & stride & near)
    if len(ij) == 0:
        return np.zeros((0, 2))
    xy = grid.ij_to_xy(ij)
    targets = instance_sample_points(obj)
    eyes = np.column_stack([xy, np.full(len(xy), camera_height_m)])
    origins = np.repeat(eyes, len(targets), axis=0)
    ends = np.tile(targets, (len(eyes), 1))
    # extend each ray a little past its target point: it must enter the part
    direction = ends - origins
    ends = ends + direction / np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9) * 0.02
    hits = world.ray_objects(origins, ends).reshape(len(eyes), len(targets)) == instance_id
    n_hit = hits.sum(axis=1)
    visible = (n_hit >= MIN_VISIBLE_RAYS) & (n_hit >= MIN_VISIBLE_FRACTION * len(targets))
    return xy[visible]
