"""Top-down occupancy map built from depth by inverse perspective projection (docs/architecture.md section 2.1).

The map is a 2D grid of square cells (5 cm by default) in the run frame (start-relative,
``agent.types``). Grid index (i, j): row i grows with y, column j with x (``ij_grid``).

Two defects of the reference implementation are avoided by construction:

* No drift when the map re-centres: cell (i, j) of the grid is *global* cell
  (i + origin_i, j + origin_j) with ``global = floor(coordinate / resolution)``; growing
  the map shifts the integer origin and copies every layer with the same integer offset,
  so no layer (goal, collision, ...) can move relative to another.
* No silent drop of far points: every valid depth reading up to ``max_depth_m`` (30 m in
  simulation, i.e. all of it) is used, and the map grows to hold it. Readings beyond
  ``max_depth_m`` or outside ``max_extent_m`` are counted in ``MapUpdate`` and logged.

Free space also comes from the visibility fan: for every image column the space between
the camera and the nearest obstacle point (or, with none, the farthest floor point) is
observed free. This covers the blind zone in front of a level camera (1.31 m high with a
34 deg lower half-FOV, the floor is first visible about 1.9 m ahead), which otherwise stays
"unexplored" and spawns frontiers at the robot's feet.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from agent.alignment import Alignment, AlignmentConfig, align_frame, frame_scan
from agent.projection import PointCloud, camera_rays_base, lift_depth_image
from agent.types import ROBOT_HEIGHT_M, ROBOT_RADIUS_M, MapSnapshot, Observation, Pose2D

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class MappingConfig:
    resolution_m: float = 0.05
    initial_size_m: float = 12.0  # square grid centred on the start, grows on demand
    grow_step_m: float = 4.0  # extra margin added whenever the grid grows
    max_extent_m: float = 64.0  # hard cap on a side: homes up to 20x20 m from any start fit
    depth_stride_px: int = 2  # every 2nd pixel: 4.3 cm footprint at 10 m with the sim camera
    min_depth_m: float = 0.1
    max_depth_m: float = 30.0  # the sim's depth is exact; a real sensor wants ~5 m
    obstacle_min_height_m: float = 0.10  # above floor noise, below the lowest furniture
    obstacle_max_height_m: float = ROBOT_HEIGHT_M  # anything higher cannot hit the robot
    # per cell and frame: filters depth speckle (issue 30: docs/experiments/realism-val.md)
    obstacle_min_points: int = 3
    # a reading that differs from the median of its 3x3 neighbourhood by more than this share is
    # dropped (a stereo camera's flying pixels between two surfaces); 0: off
    depth_consistency: float = 0.05
    # obstacle evidence over frames: a frame that hits a cell adds one (up to the cap), a frame
    # that sees through it (the cell lies at least ``clear_margin_m`` short of its column's first
    # obstacle, within ``clear_max_range_m`` of the camera, and far enough that the column's
    # lowest ray passes below ``obstacle_min_height_m`` there) takes one away; the cell stays an
    # obstacle until its evidence is spent. One hit blocks at once, as before; a cell hit in many
    # frames (a wall) needs as many clear views (up to the cap). 0: off (an obstacle is for ever).
    # Under the `stretch` profile it removed about 70% of the phantom cells the filters leave
    # (docs/experiments/realism-evidence.md)
    obstacle_evidence_cap: int = 3
    clear_margin_m: float = 0.15
    clear_max_range_m: float = 3.0
    free_fan: bool = True
    robot_radius_m: float = ROBOT_RADIUS_M
    collision_length_m: float = 0.10  # depth of the collision mark in front of the robot


LAYER_DTYPES: dict[str, type] = {"obstacle_evidence": np.int8}  # every other layer is bool


@dataclass(slots=True, eq=False)
class MapLayers:
    """The named layers, all (H, W) bool in ``ij_grid`` order. Mutable; owned by ``GridMap``."""

    obstacle: np.ndarray
    explored: np.ndarray
    visited: np.ndarray
    collision: np.ndarray
    goal: np.ndarray
    blacklist: np.ndarray  # rejected goal candidates: their points are dropped
    # rejected *potential* candidates (never scored tau): only evidence below tau is dropped
    # there; a later detection still counts (the rejection only said "not confirmed yet")
    potential_blacklist: np.ndarray
    frontier_blacklist: np.ndarray  # frontiers given up (reached, unreachable, stalled); may be forgiven
    # int8: frames of obstacle evidence left (``MappingConfig.obstacle_evidence_cap``); the one
    # layer that is not bool
    obstacle_evidence: np.ndarray

    @staticmethod
    def empty(shape: tuple[int, int]) -> MapLayers:
        return MapLayers(*(np.zeros(shape, LAYER_DTYPES.get(f.name, bool)) for f in dataclasses.fields(MapLayers)))

    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(self))


@dataclass(frozen=True, slots=True, eq=False)
class DepthFrame:
    """A depth frame lifted once (``GridMap.lift``): its points at ``pose``, readings beyond range."""

    cloud: PointCloud
    pose: Pose2D
    n_beyond: int


@dataclass(frozen=True, slots=True)
class MapUpdate:
    """What one depth frame contributed."""

    n_points: int
    n_obstacle_points: int
    n_beyond_max_depth: int
    n_outside_extent: int
    grew: bool


class GridMap:
    """A growing top-down grid with named layers (see module docstring)."""

    def __init__(self, config: MappingConfig = MappingConfig()) -> None:
        self.config = config
        self.resolution_m = config.resolution_m
        n = int(math.ceil(config.initial_size_m / config.resolution_m))
        self._max_cells = int(math.ceil(config.max_extent_m / config.resolution_m))
        self.origin_ij = (-(n // 2), -(n // 2))  # global cell index of grid cell (0, 0)
        self.layers = MapLayers.empty((n, n))

    # --- geometry -----------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        return self.layers.obstacle.shape  # type: ignore[return-value]

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        """Run-frame (x, y) of the corner of cell (0, 0)."""
        return (self.origin_ij[1] * self.resolution_m, self.origin_ij[0] * self.resolution_m)

    def global_cells(self, xy_m: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy_m, np.float64).reshape(-1, 2)
        return np.floor(xy[:, ::-1] / self.resolution_m).astype(np.int64)  # (gi, gj)

    def xy_to_ij(self, xy_m: np.ndarray) -> np.ndarray:
        """(N, 2) run-frame metres -> (N, 2) int64 grid (i, j); may be out of bounds."""
        return self.global_cells(xy_m) - np.asarray(self.origin_ij, np.int64)

    def ij_to_xy(self, ij: np.ndarray) -> np.ndarray:
        """(N, 2) grid (i, j) -> (N, 2) float64 run-frame centre of the cell."""
        ij = np.asarray(ij, np.float64).reshape(-1, 2)
        return (ij[:, ::-1] + np.asarray(self.origin_ij[::-1], np.float64) + 0.5) * self.resolution_m

    def in_bounds(self, ij: np.ndarray) -> np.ndarray:
        ij = np.asarray(ij).reshape(-1, 2)
        h, w = self.shape
        return (ij[:, 0] >= 0) & (ij[:, 0] < h) & (ij[:, 1] >= 0) & (ij[:, 1] < w)

    def cell_of(self, pose: Pose2D) -> tuple[int, int]:
        i, j = self.xy_to_ij(np.array([[pose.x_m, pose.y_m]]))[0]
        return int(i), int(j)

    # --- growth ---------------------------------------------------------------------

    def ensure_contains(self, xy_min: tuple[float, float], xy_max: tuple[float, float]) -> bool:
        """Grow the grid (all layers alike) to cover the run-frame box; True if it grew.

        The box is clipped to ``max_extent_m`` around the start; callers drop what lies beyond.
        """
        g_lo = self.global_cells(np.array([xy_min]))[0]
        g_hi = self.global_cells(np.array([xy_max]))[0]
        half = self._max_cells // 2
        g_lo = np.maximum(g_lo, -half)
        g_hi = np.minimum(g_hi, half - 1)
        o = np.asarray(self.origin_ij)
        end = o + np.asarray(self.shape)
        if np.all(g_lo >= o) and np.all(g_hi < end):
            return False
        step = int(math.ceil(self.config.grow_step_m / self.resolution_m))
        new_o = np.where(g_lo < o, np.maximum(g_lo - step, -half), o)
        new_end = np.where(g_hi >= end, np.minimum(g_hi + 1 + step, half), end)
        shape = tuple(int(v) for v in new_end - new_o)
        off = o - new_o
        grown = MapLayers.empty(shape)  # type: ignore[arg-type]
        for name in self.layers.names():
            old = getattr(self.layers, name)
            getattr(grown, name)[off[0] : off[0] + old.shape[0], off[1] : off[1] + old.shape[1]] = old
        self.layers = grown
        self.origin_ij = (int(new_o[0]), int(new_o[1]))
        log.debug("map grew to %s cells, origin %s", shape, self.origin_ij)
        return True

    # --- updates --------------------------------------------------------------------

    def lift(self, obs: Observation) -> DepthFrame:
        """The frame's depth, filtered (``depth_consistency``) and lifted at ``obs.pose``."""
        cfg = self.config
        depth = obs.depth_m
        if cfg.depth_consistency > 0:
            med = cv2.medianBlur(np.ascontiguousarray(depth, np.float32), 3)
            depth = np.where(np.abs(depth - med) <= cfg.depth_consistency * med, depth, 0.0).astype(np.float32)
        n_beyond = int(np.count_nonzero(depth[:: cfg.depth_stride_px, :: cfg.depth_stride_px] > cfg.max_depth_m))
        cloud = lift_depth_image(
            depth,
            obs.intrinsics,
            obs.pose,
            obs.camera_height_m,
            obs.camera_tilt_rad,
            stride_px=cfg.depth_stride_px,
            min_depth_m=cfg.min_depth_m,
            max_depth_m=cfg.max_depth_m,
        )
        return DepthFrame(cloud, obs.pose, n_beyond)

    def align(self, frame: DepthFrame, config: AlignmentConfig) -> Alignment:
        """The pose near the frame's at which its obstacle points fit this map best (``agent.alignment``)."""
        cfg = self.config
        height = frame.cloud.xyz_run[:, 2]
        is_obstacle = (height >= cfg.obstacle_min_height_m) & (height <= cfg.obstacle_max_height_m)
        scan = frame_scan(frame.cloud.xy_base, frame.cloud.uv_px, is_obstacle, config.max_range_m)
        return align_frame(
            self.layers.obstacle, self.layers.explored, self.origin_xy_m, self.resolution_m, scan, frame.pose, config
        )

    def update(self, obs: Observation, frame: DepthFrame | None = None) -> MapUpdate:
        """Fuse one depth frame (vectorised): obstacle, explored and the free-space fan. ``frame``:
        the frame already lifted (``lift``), possibly at another pose than ``obs.pose`` (aligned)."""
        cfg = self.config
        if frame is None:
            frame = self.lift(obs)
        cloud = frame.cloud if frame.pose == obs.pose else frame.cloud.at_pose(obs.pose)
        n_beyond = frame.n_beyond
        xy = cloud.xyz_run[:, :2]
        pose_xy = np.array([obs.pose.x_m, obs.pose.y_m])
        lo = np.minimum(xy.min(axis=0), pose_xy) if len(xy) else pose_xy
        hi = np.maximum(xy.max(axis=0), pose_xy) if len(xy) else pose_xy
        grew = self.ensure_contains((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))
        ij = self.xy_to_ij(xy)
        inside = self.in_bounds(ij)
        n_outside = int(np.count_nonzero(~inside))
        if n_beyond or n_outside:
            log.debug(
                "depth frame: %d readings beyond %.1f m, %d points outside the map extent",
                n_beyond,
                cfg.max_depth_m,
                n_outside,
            )
        height = cloud.xyz_run[:, 2]
        is_obstacle = (height >= cfg.obstacle_min_height_m) & (height <= cfg.obstacle_max_height_m)
        h, w = self.shape
        seen = inside.copy()
        see_through = None  # (rows, cols, mask): the cells this frame saw through
        if cfg.free_fan and len(xy):
            # Floor seen *beyond* the first obstacle of its column (over a bed, between chair
            # legs) comes in sparse rows at range; marked explored it would riddle the map with
            # one-cell frontiers. Like a 2D laser scan, each column counts up to its first hit.
            r_end, see_through = self._fill_fan(obs, cloud.uv_px, cloud.xy_base, is_obstacle)
            col = cloud.uv_px[:, 0] // cfg.depth_stride_px
            rng = np.hypot(cloud.xy_base[:, 0], cloud.xy_base[:, 1])
            seen &= is_obstacle | (rng <= r_end[col] + self.resolution_m)
        flat = ij[seen, 0] * w + ij[seen, 1]
        self.layers.explored.reshape(-1)[flat] = True
        obst_flat = ij[inside & is_obstacle, 0] * w + ij[inside & is_obstacle, 1]
        hit = np.zeros(0, np.int64)
        if len(obst_flat):
            cells, counts = np.unique(obst_flat, return_counts=True)
            hit = cells[counts >= cfg.obstacle_min_points]
            self.layers.obstacle.reshape(-1)[hit] = True
        if cfg.obstacle_evidence_cap > 0:
            self._weigh_evidence(hit, see_through)
        return MapUpdate(len(xy), int(np.count_nonzero(is_obstacle)), n_beyond, n_outside, grew)

    def _weigh_evidence(self, hit: np.ndarray, see_through: tuple[slice, slice, np.ndarray] | None) -> None:
        """Obstacle evidence over frames (``MappingConfig.obstacle_evidence_cap``): ``hit`` (flat
        indices) gain one frame, the cells seen through (and not hit) lose one; an obstacle whose
        evidence is spent is cleared."""
        ev = self.layers.obstacle_evidence
        flat = ev.reshape(-1)
        flat[hit] = np.minimum(flat[hit].astype(np.int16) + 1, self.config.obstacle_evidence_cap)
        if see_through is None:
            return
        rows, cols, through = see_through
        win = ev[rows, cols]
        was_hit = np.zeros(ev.shape, bool)
        was_hit.reshape(-1)[hit] = True
        spend = through & ~was_hit[rows, cols] & (win > 0)
        win[spend] -= 1
        self.layers.obstacle[rows, cols][spend & (win == 0)] = False

    def _fill_fan(
        self, obs: Observation, uv_px: np.ndarray, xy_base: np.ndarray, is_obstacle: np.ndarray
    ) -> tuple[np.ndarray, tuple[slice, slice, np.ndarray] | None]:
        """Mark explored the polygon swept by each column's line of sight (see module docstring).

        Returns r_end: (n_cols,) float32 horizontal range of each column's first obstacle, or of
        its farthest point when it has none (inf for a column without points); and, with obstacle
        evidence on, the cells seen through (rows, cols and a mask of that window): the fan from
        where each column's lowest valid ray passes below the obstacle height to ``clear_margin_m``
        short of its end (at most ``clear_max_range_m``)."""
        stride = self.config.depth_stride_px
        col = (uv_px[:, 0] // stride).astype(np.int64)
        n_cols = int(col.max()) + 1
        rng = np.hypot(xy_base[:, 0], xy_base[:, 1])
        r_obs = np.full(n_cols, np.inf, np.float32)
        np.minimum.at(r_obs, col[is_obstacle], rng[is_obstacle])
        r_free = np.full(n_cols, -np.inf, np.float32)
        np.maximum.at(r_free, col[~is_obstacle], rng[~is_obstacle])
        r_end = np.where(np.isfinite(r_obs), r_obs, r_free)
        keep = np.isfinite(r_end) & (r_end > 0)
        r_end = np.where(keep, r_end, np.inf).astype(np.float32)
        if np.count_nonzero(keep) < 2:
            return r_end, None
        cols = np.nonzero(keep)[0]
        u = cols * stride
        intr = obs.intrinsics
        xn = (u - intr.cx) / intr.fx
        bearing = np.arctan2(-xn, math.cos(obs.camera_tilt_rad)) + obs.pose.yaw_rad
        r = r_end[keep].astype(np.float64)
        pts = np.stack([obs.pose.x_m + r * np.cos(bearing), obs.pose.y_m + r * np.sin(bearing)], axis=1)
        pts = np.vstack([[obs.pose.x_m, obs.pose.y_m], pts])
        self._fill_polygon(pts, self.layers.explored)
        cfg = self.config
        if cfg.obstacle_evidence_cap <= 0:
            return r_end, None
        # Seen through: between where the column's lowest valid ray passes below the obstacle
        # height (nearer, an obstacle can stand unseen under it: the field of view's lower edge,
        # or depth dropped out) and a margin short of its first obstacle (or clear_max_range_m).
        v_low = np.full(n_cols, -1, np.int64)
        np.maximum.at(v_low, col, uv_px[:, 1].astype(np.int64))
        fwd, left, up = camera_rays_base(u, v_low[cols], intr, obs.camera_tilt_rad)
        drop = obs.camera_height_m - cfg.obstacle_min_height_m
        with np.errstate(divide="ignore"):
            r_lo = np.where(up < 0, drop * np.hypot(fwd, left) / np.maximum(-up, 1e-9), np.inf)
        r_hi = np.minimum(r - cfg.clear_margin_m, cfg.clear_max_range_m)
        sees = r_hi > r_lo
        if np.count_nonzero(sees) < 2:
            return r_end, None
        r_lo, r_hi, b = r_lo[sees], r_hi[sees], bearing[sees]
        ring = np.concatenate([r_lo, r_hi[::-1]])
        bb = np.concatenate([b, b[::-1]])
        pts = np.stack([obs.pose.x_m + ring * np.cos(bb), obs.pose.y_m + ring * np.sin(bb)], axis=1)
        return r_end, self._polygon_mask(pts)

    def _polygon_mask(self, xy_m: np.ndarray) -> tuple[slice, slice, np.ndarray] | None:
        """A run-frame polygon (N, 2) rasterised: the grid window (rows, cols) around it and the
        cells inside in that window (clipped to the grid; None when it misses the grid)."""
        shift = 3  # sub-cell vertex precision for cv2.fillPoly
        origin = np.asarray(self.origin_xy_m)
        pix = (xy_m - origin) / self.resolution_m - 0.5  # cell centres at integer coordinates
        lo = np.maximum(np.floor(pix.min(axis=0)).astype(int) - 1, 0)
        hi = np.minimum(np.ceil(pix.max(axis=0)).astype(int) + 2, np.asarray(self.shape[::-1]))
        if np.any(hi <= lo):
            return None
        buf = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
        poly = np.round((pix - lo) * (1 << shift)).astype(np.int32)
        cv2.fillPoly(buf, [poly.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=shift)
        return slice(lo[1], hi[1]), slice(lo[0], hi[0]), buf.astype(bool)

    def _fill_polygon(self, xy_m: np.ndarray, layer: np.ndarray) -> None:
        """Rasterise a run-frame polygon (N, 2) into ``layer`` (clipped to the grid)."""
        mask = self._polygon_mask(xy_m)
        if mask is not None:
            rows, cols, inside = mask
            layer[rows, cols] |= inside

    def mark_visited(self, xy_from: tuple[float, float], xy_to: tuple[float, float]) -> None:
        """Cells on the segment the robot centre travelled. The robot's own footprint at
        ``xy_to`` is free space: collision marks there were misplaced (a move blocked by
        something at the side marks the front) and obstacle cells there are quantisation
        artefacts; both are cleared within the radius less one cell."""
        r = self.config.robot_radius_m
        self.ensure_contains(
            (min(xy_from[0], xy_to[0]) - r, min(xy_from[1], xy_to[1]) - r),
            (max(xy_from[0], xy_to[0]) + r, max(xy_from[1], xy_to[1]) + r),
        )
        n = max(2, int(math.ceil(math.dist(xy_from, xy_to) / (0.5 * self.resolution_m))) + 1)
        seg = np.linspace(xy_from, xy_to, n)
        ij = self.xy_to_ij(seg)
        ij = ij[self.in_bounds(ij)]
        self.layers.visited[ij[:, 0], ij[:, 1]] = True
        self.layers.explored[ij[:, 0], ij[:, 1]] = True
        ci, cj = self.xy_to_ij(np.array([xy_to]))[0]
        rc = (r - self.resolution_m) / self.resolution_m
        n = int(math.ceil(rc))
        ii, jj = np.mgrid[-n : n + 1, -n : n + 1]
        inside = ii * ii + jj * jj <= rc * rc
        cells = np.stack([ii[inside] + ci, jj[inside] + cj], axis=1)
        cells = cells[self.in_bounds(cells)]
        for layer in (self.layers.collision, self.layers.obstacle):
            layer[cells[:, 0], cells[:, 1]] = False
        self.layers.obstacle_evidence[cells[:, 0], cells[:, 1]] = 0
        self.layers.explored[cells[:, 0], cells[:, 1]] = True

    def mark_collision(self, pose: Pose2D) -> None:
        """A forward move failed: something the camera cannot see (below its field of view,
        thin or transparent) blocks the robot. Mark a band across the robot's front."""
        cfg = self.config
        r = cfg.robot_radius_m
        near, far = r, r + cfg.collision_length_m
        corners_local = np.array([[near, -r], [far, -r], [far, r], [near, r]])
        corners = pose.transform_xy(corners_local)
        self.ensure_contains(tuple(corners.min(axis=0)), tuple(corners.max(axis=0)))  # type: ignore[arg-type]
        self._fill_polygon(corners, self.layers.collision)

    def set_goal_cells(self, ij: np.ndarray) -> None:
        """Replace the goal layer with these grid cells (in-bounds ones)."""
        self.layers.goal[:] = False
        ij = np.asarray(ij, np.int64).reshape(-1, 2)
        ij = ij[self.in_bounds(ij)]
        self.layers.goal[ij[:, 0], ij[:, 1]] = True

    def clear_goal(self) -> None:
        self.layers.goal[:] = False

    def blacklist_cells(self, ij: np.ndarray, margin_m: float, layer: str = "blacklist") -> None:
        """Reject a goal candidate: its cells (in-bounds ones) and everything within ``margin_m``
        of them join the ``blacklist`` layer (goal points there are ignored from now on), or the
        ``potential_blacklist`` layer (only points below tau are ignored there)."""
        if layer not in ("blacklist", "potential_blacklist"):
            raise ValueError(f"not a candidate blacklist layer: {layer!r}")
        ij = np.asarray(ij, np.int64).reshape(-1, 2)
        ij = ij[self.in_bounds(ij)]
        if len(ij) == 0:
            return
        cells = np.zeros(self.shape, bool)
        cells[ij[:, 0], ij[:, 1]] = True
        dt = cv2.distanceTransform((~cells).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        target = getattr(self.layers, layer)
        target |= dt * self.resolution_m <= margin_m

    def forgive_collisions(self) -> None:
        """Drop every collision mark: they are guesses (which side blocked a move is unknown)."""
        self.layers.collision[:] = False

    def start_again(self) -> int:
        """Forget what the map says about the home's geometry (obstacles and their evidence,
        the explored area, collision marks, given-up frontiers) and keep what the robot knows
        otherwise: where it has been (``visited``), the goal cells and the rejected candidates.
        Returns the number of obstacle cells dropped. The policy's fresh map
        (``PolicyConfig.fresh_map_min_steps_left``)."""
        L = self.layers
        dropped = int(np.count_nonzero(L.obstacle))
        for layer in (L.obstacle, L.obstacle_evidence, L.explored, L.collision, L.frontier_blacklist):
            layer[:] = 0
        return dropped

    def forgive_frontiers(self) -> None:
        """Drop every given-up frontier (rejected goal candidates stay rejected)."""
        self.layers.frontier_blacklist[:] = False

    def blacklist_disk(self, xy_m: tuple[float, float], radius_m: float, layer: str = "blacklist") -> None:
        self.ensure_contains((xy_m[0] - radius_m, xy_m[1] - radius_m), (xy_m[0] + radius_m, xy_m[1] + radius_m))
        ci, cj = self.xy_to_ij(np.array([xy_m]))[0]
        rc = int(math.ceil(radius_m / self.resolution_m))
        h, w = self.shape
        i0, i1 = max(ci - rc, 0), min(ci + rc + 1, h)
        j0, j1 = max(cj - rc, 0), min(cj + rc + 1, w)
        ii, jj = np.mgrid[i0:i1, j0:j1]
        disk = (ii - ci) ** 2 + (jj - cj) ** 2 <= rc * rc
        getattr(self.layers, layer)[i0:i1, j0:j1] |= disk

    # --- read-out ---------------------------------------------------------------------

    def snapshot(self, frontier: np.ndarray | None = None) -> MapSnapshot:
        """An immutable copy for the record (``agent.types.MapSnapshot``)."""
        L = self.layers
        return MapSnapshot(
            resolution_m=self.resolution_m,
            origin_xy_m=self.origin_xy_m,
            obstacle=L.obstacle.copy(),
            explored=L.explored.copy(),
            visited=L.visited.copy(),
            collision=L.collision.copy(),
            goal=L.goal.copy(),
            frontier=np.zeros(self.shape, bool) if frontier is None else frontier.copy(),
            blacklist=L.blacklist | L.frontier_blacklist | L.potential_blacklist,
        )
