"""Planar collision geometry of a home, without PyBullet.

The robot is a vertical cylinder (radius 0.17 m, height 1.41 m, docs/architecture.md section 1)
that only translates in the floor plane, so a collision test against vertical
prisms reduces exactly to a 2D test: the disc of the robot's radius against the
footprints of every solid part whose height range overlaps the robot's.
Footprints are rotated rectangles (boxes) and circles (cylinders; round parts
such as foliage use a conservative circle or box).

``FootprintIndex`` answers ``collides(x, y)`` in pure Python through a bucket
grid (fast for single queries, as in stepping and planning) and rasterises the
navigable grid with numpy (fast for whole maps). Both use the same formulas,
so a position is navigable on the grid exactly when ``collides`` says False at
the cell centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.types import ROBOT_HEIGHT_M, ROBOT_RADIUS_M, grid_ij_to_xy, grid_xy_to_ij

# Parts whose top is below this height are floor coverings (rugs): drivable.
FLOOR_COVERING_TOP_M = 0.03
_BUCKET_M = 0.5


@dataclass(frozen=True, slots=True)
class RectFootprint:
    """A rectangle of half sizes (hx_m, hy_m) centred at (cx_m, cy_m), rotated by yaw_rad (world frame)."""

    cx_m: float
    cy_m: float
    hx_m: float
    hy_m: float
    yaw_rad: float
    z0_m: float
    z1_m: float

    def distance(self, x_m: float, y_m: float) -> float:
        """Euclidean distance from the point to the rectangle (0 inside)."""
        dx, dy = x_m - self.cx_m, y_m - self.cy_m
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        lx, ly = abs(c * dx + s * dy) - self.hx_m, abs(-s * dx + c * dy) - self.hy_m
        if lx <= 0.0 and ly <= 0.0:
            return 0.0
        return math.hypot(max(lx, 0.0), max(ly, 0.0))

    def distance_grid(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        dx, dy = x_m - self.cx_m, y_m - self.cy_m
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        lx = np.abs(c * dx + s * dy) - self.hx_m
        ly = np.abs(-s * dx + c * dy) - self.hy_m
        return np.hypot(np.maximum(lx, 0.0), np.maximum(ly, 0.0))

    def bounds(self) -> tuple[float, float, float, float]:
        c, s = abs(math.cos(self.yaw_rad)), abs(math.sin(self.yaw_rad))
        ex, ey = c * self.hx_m + s * self.hy_m, s * self.hx_m + c * self.hy_m
        return (self.cx_m - ex, self.cy_m - ey, self.cx_m + ex, self.cy_m + ey)

    def corners_xy(self) -> np.ndarray:
        """(4, 2) float64 corners, counter-clockwise, world frame metres."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * [self.hx_m, self.hy_m]
        return local @ np.array([[c, s], [-s, c]]) + [self.cx_m, self.cy_m]


@dataclass(frozen=True, slots=True)
class CircleFootprint:
    cx_m: float
    cy_m: float
    r_m: float
    z0_m: float
    z1_m: float

    def distance(self, x_m: float, y_m: float) -> float:
        return max(math.hypot(x_m - self.cx_m, y_m - self.cy_m) - self.r_m, 0.0)

    def distance_grid(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return np.maximum(np.hypot(x_m - self.cx_m, y_m - self.cy_m) - self.r_m, 0.0)

    def bounds(self) -> tuple[float, float, float, float]:
        return (self.cx_m - self.r_m, self.cy_m - self.r_m, self.cx_m + self.r_m, self.cy_m + self.r_m)


Footprint = RectFootprint | CircleFootprint


def blocks_robot(fp: Footprint, robot_height_m: float = ROBOT_HEIGHT_M) -> bool:
    """Whether a part at this height range can touch the robot cylinder."""
    return fp.z1_m > FLOOR_COVERING_TOP_M and fp.z0_m < robot_height_m


@dataclass(frozen=True, slots=True, eq=False)
class NavGrid:
    """A boolean top-down grid in the world frame.

    navigable: (H, W) bool; cell (i, j) covers x in [origin_x + j*res, +res),
    y in [origin_y + i*res, +res) (``ij_grid``: row i grows with world y). A cell
    is navigable when the robot centred at the cell centre collides with nothing.
    """

    navigable: np.ndarray
    resolution_m: float
    origin_xy_m: tuple[float, float]

    @property
    def shape(self) -> tuple[int, int]:
        return self.navigable.shape  # type: ignore[return-value]

    def xy_to_ij(self, xy_m: np.ndarray) -> np.ndarray:
        """(N, 2) world metres -> (N, 2) int64 (i, j); may fall outside the grid."""
        return grid_xy_to_ij(xy_m, self.origin_xy_m, self.resolution_m)

    def ij_to_xy(self, ij: np.ndarray) -> np.ndarray:
        """(N, 2) (i, j) -> (N, 2) float64 world metres of the cell centres."""
        return grid_ij_to_xy(ij, self.origin_xy_m, self.resolution_m)

    def inside(self, ij: np.ndarray) -> np.ndarray:
        ij = np.asarray(ij).reshape(-1, 2)
        h, w = self.navigable.shape
        return (ij[:, 0] >= 0) & (ij[:, 0] < h) & (ij[:, 1] >= 0) & (ij[:, 1] < w)

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World x and y of every cell centre, each (H, W) float64."""
        h, w = self.navigable.shape
        xs = self.origin_xy_m[0] + (np.arange(w) + 0.5) * self.resolution_m
        ys = self.origin_xy_m[1] + (np.arange(h) + 0.5) * self.resolution_m
        return np.meshgrid(xs, ys)


class FootprintIndex:
    """Collision queries of the robot disc against a fixed set of footprints."""

    def __init__(
        self,
        footprints: list[Footprint] | tuple[Footprint, ...],
        bounds_xy_m: tuple[float, float, float, float],
        robot_radius_m: float = ROBOT_RADIUS_M,
        robot_height_m: float = ROBOT_HEIGHT_M,
    ) -> None:
        self.robot_radius_m = robot_radius_m
        self.bounds_xy_m = bounds_xy_m  # (xmin, ymin, xmax, ymax): anything outside collides
        self.footprints = tuple(fp for fp in footprints if blocks_robot(fp, robot_height_m))
        self._buckets: dict[tuple[int, int], list[Footprint]] = {}
        self._lower: list[list[float]] | None = None
        self._fast_res = 0.05
        pad = robot_radius_m
        for fp in self.footprints:
            x0, y0, x1, y1 = fp.bounds()
            for bi in range(math.floor((y0 - pad) / _BUCKET_M), math.floor((y1 + pad) / _BUCKET_M) + 1):
                for bj in range(math.floor((x0 - pad) / _BUCKET_M), math.floor((x1 + pad) / _BUCKET_M) + 1):
                    self._buckets.setdefault((bi, bj), []).append(fp)

    def _build_fast_path(self, resolution_m: float = 0.05) -> None:
        """A coarse lower bound on clearance: exact distances at cell centres minus half a cell
        diagonal. A query whose bound already exceeds the robot radius skips the exact test."""
        xmin, ymin, xmax, ymax = self.bounds_xy_m
        w = int(math.ceil((xmax - xmin) / resolution_m)) + 1
        h = int(math.ceil((ymax - ymin) / resolution_m)) + 1
        xs = xmin + (np.arange(w) + 0.5) * resolution_m
        ys = ymin + (np.arange(h) + 0.5) * resolution_m
        gx, gy = np.meshgrid(xs, ys)
        cap = self.robot_radius_m + 1.0
        d = np.full((h, w), cap)
        for fp in self.footprints:
            x0, y0, x1, y1 = fp.bounds()
            j0 = max(int(math.floor((x0 - cap - xmin) / resolution_m)), 0)
            j1 = min(int(math.ceil((x1 + cap - xmin) / resolution_m)) + 1, w)
            i0 = max(int(math.floor((y0 - cap - ymin) / resolution_m)), 0)
            i1 = min(int(math.ceil((y1 + cap - ymin) / resolution_m)) + 1, h)
            if i0 < i1 and j0 < j1:
                d[i0:i1, j0:j1] = np.minimum(d[i0:i1, j0:j1], fp.distance_grid(gx[i0:i1, j0:j1], gy[i0:i1, j0:j1]))
        # a point in a cell is at most half a diagonal from the cell centre; 1 mm more for rounding
        self._lower = (d - resolution_m * math.sqrt(0.5) - 1e-3).tolist()
        self._fast_res = resolution_m

    def clearance_lower_bound_m(self, x_m: float, y_m: float) -> float:
        """A lower bound on the distance to the nearest footprint (0 outside the bounds)."""
        if self._lower is None:
            self._build_fast_path()
        lower = self._lower
        assert lower is not None  # built just above
        i = int((y_m - self.bounds_xy_m[1]) / self._fast_res)
        j = int((x_m - self.bounds_xy_m[0]) / self._fast_res)
        if 0 <= i < len(lower) and 0 <= j < len(lower[0]) and y_m >= self.bounds_xy_m[1] and x_m >= self.bounds_xy_m[0]:
            return lower[i][j]
        return 0.0

    def clearance_m(self, x_m: float, y_m: float) -> float:
        """Distance from the point to the nearest footprint, capped at the robot radius."""
        best = self.robot_radius_m
        for fp in self._buckets.get((math.floor(y_m / _BUCKET_M), math.floor(x_m / _BUCKET_M)), ()):
            d = fp.distance(x_m, y_m)
            if d < best:
                best = d
        return best

    def collides(self, x_m: float, y_m: float) -> bool:
        """True when the robot centred at (x_m, y_m) overlaps a solid part or leaves the home's bounds."""
        xmin, ymin, xmax, ymax = self.bounds_xy_m
        if not (xmin <= x_m <= xmax and ymin <= y_m <= ymax):
            return True
        if self.clearance_lower_bound_m(x_m, y_m) >= self.robot_radius_m:
            return False
        return self.clearance_m(x_m, y_m) < self.robot_radius_m

    def navigable_grid(self, resolution_m: float, margin_m: float = 0.0) -> NavGrid:
        """Rasterise ``not collides`` at every cell centre over the home's bounds."""
        xmin, ymin, xmax, ymax = self.bounds_xy_m
        ox, oy = xmin - margin_m, ymin - margin_m
        w = int(math.ceil((xmax + margin_m - ox) / resolution_m))
        h = int(math.ceil((ymax + margin_m - oy) / resolution_m))
        grid = NavGrid(np.zeros((h, w), dtype=bool), resolution_m, (ox, oy))
        xs, ys = grid.cell_centres()
        free = (xs >= xmin) & (xs <= xmax) & (ys >= ymin) & (ys <= ymax)
        r = self.robot_radius_m
        for fp in self.footprints:
            x0, y0, x1, y1 = fp.bounds()
            j0 = max(int(math.floor((x0 - r - ox) / resolution_m)), 0)
            j1 = min(int(math.ceil((x1 + r - ox) / resolution_m)) + 1, w)
            i0 = max(int(math.floor((y0 - r - oy) / resolution_m)), 0)
            i1 = min(int(math.ceil((y1 + r - oy) / resolution_m)) + 1, h)
            if i0 >= i1 or j0 >= j1:
                continue
            window = free[i0:i1, j0:j1]
            window &= fp.distance_grid(xs[i0:i1, j0:j1], ys[i0:i1, j0:j1]) >= r
        grid.navigable[:] = free
        return grid
