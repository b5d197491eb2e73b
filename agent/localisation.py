"""Goal localisation: matched keypoints on the goal instance -> 3D goal points -> goal layer
(docs/architecture.md section 2.3; Krantz et al. 2023, section 3.3).

Each detection adds points: the matched goal-image keypoints that fall inside the goal
mask select their egocentric partners, which are lifted to 3D with the depth image and the
pose (or, for the oracle ablation, pixels of the ground-truth egocentric instance mask).
Points accumulate over the run. Outliers are removed by clustering: points closer than
``cluster_radius_m`` (in the floor plane) join one cluster, and the largest cluster is the
goal. Clusters are also the *candidates* the policy verifies and may reject: rejected
candidates are blacklisted, and their points and any later points inside the blacklisted
area are ignored. Everything is done per point/cell (the reference code zeroed whole rows).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from agent.mapping import GridMap
from agent.projection import lift_pixels
from agent.types import Observation

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class LocalisationConfig:
    cluster_radius_m: float = 0.3
    depth_window_px: int = 1  # median depth over a (2k+1)^2 window around a (sub-pixel) keypoint
    min_depth_m: float = 0.1
    max_depth_m: float = 12.0  # goal points farther than this are too uncertain to navigate to
    min_points_per_frame: int = 2
    max_oracle_pixels: int = 400  # subsample the oracle egocentric mask
    min_height_m: float = 0.02  # points on the floor are not on the object


@dataclass(frozen=True, slots=True, eq=False)
class Candidate:
    """A cluster of goal points.

    cells_ij: (K, 2) int64 map cells holding its points; points_xyz: (N, 3) float32 run frame.
    """

    label: int
    points_xyz: np.ndarray
    cells_ij: np.ndarray
    centroid_xy_m: tuple[float, float]
    n_points: int
    max_score: float
    n_frames: int
    id: int = -1  # stable: the index of its oldest point (clusters that merge keep the older id)
    frames: tuple[int, ...] = ()  # steps that added points to it, ascending
    # where the robot stood (run frame, metres) for each of ``frames``: the side it was seen from
    seen_from_xy_m: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True, slots=True)
class View:
    """One frame's contribution: its step, re-ID score, the distance from the robot to the
    points it added (their 10th percentile, metres), how many points it added and where the
    robot stood (run frame)."""

    step: int
    score: float
    distance_m: float
    n_points: int
    robot_xy_m: tuple[float, float] = (0.0, 0.0)


class GoalLocaliser:
    def __init__(self, config: LocalisationConfig = LocalisationConfig()) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self._xyz = np.zeros((0, 3), np.float32)
        self._score = np.zeros(0, np.float32)
        self._frame = np.zeros(0, np.int64)
        self._views: dict[int, View] = {}

    def view(self, frame: int) -> View | None:
        """The view (step) that added points, or None."""
        return self._views.get(frame)

    @property
    def points_xyz(self) -> np.ndarray:
        return self._xyz

    def _depth_at(self, depth_m: np.ndarray, uv: np.ndarray, k: int) -> np.ndarray:
        h, w = depth_m.shape
        u = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
        v = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
        if k <= 0:
            return depth_m[v, u]
        offs = np.arange(-k, k + 1)
        vv = np.clip(v[:, None, None] + offs[None, :, None], 0, h - 1)
        uu = np.clip(u[:, None, None] + offs[None, None, :], 0, w - 1)
        win = depth_m[vv, uu].reshape(len(u), -1).astype(np.float32)
        win[~np.isfinite(win) | (win <= 0)] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN window -> NaN, dropped by the caller
            return np.nanmedian(win, axis=1)

    def points_from_pixels(self, obs: Observation, uv: np.ndarray, window_px: int | None = None) -> np.ndarray:
        """Lift egocentric pixels (N, 2) (x, y) to run-frame points (M, 3), dropping invalid depth."""
        cfg = self.config
        if len(uv) == 0:
            return np.zeros((0, 3), np.float32)
        z = self._depth_at(obs.depth_m, uv, cfg.depth_window_px if window_px is None else window_px)
        ok = np.isfinite(z) & (z >= cfg.min_depth_m) & (z <= cfg.max_depth_m)
        cloud = lift_pixels(
            uv[ok, 0], uv[ok, 1], z[ok], obs.intrinsics, obs.pose, obs.camera_height_m, obs.camera_tilt_rad
        )
        return cloud.xyz_run[cloud.xyz_run[:, 2] >= cfg.min_height_m]

    def keypoint_points(self, obs: Observation, uv: np.ndarray) -> np.ndarray:
        """Each egocentric pixel (N, 2) (x, y) lifted as ``points_from_pixels`` lifts it, one row per
        pixel: (N, 3) float32 run-frame points, NaN rows where that drops it (no valid depth, out of
        range, on the floor). The agent's memory of a home keeps these for every keypoint of a
        keyframe (``agent.memory``), so a later goal's matches on it become the same goal points a
        live frame would give."""
        cfg = self.config
        out = np.full((len(uv), 3), np.nan, np.float32)
        if len(uv) == 0:
            return out
        z = self._depth_at(obs.depth_m, uv, cfg.depth_window_px)
        ok = np.isfinite(z) & (z >= cfg.min_depth_m) & (z <= cfg.max_depth_m)
        cloud = lift_pixels(
            uv[ok, 0], uv[ok, 1], z[ok], obs.intrinsics, obs.pose, obs.camera_height_m, obs.camera_tilt_rad
        )
        high = cloud.xyz_run[:, 2] >= cfg.min_height_m
        out[np.flatnonzero(ok)[high]] = cloud.xyz_run[high]
        return out

    def add_matches(
        self, obs: Observation, goal_xy: np.ndarray, obs_xy: np.ndarray, goal_mask: np.ndarray, score: float
    ) -> np.ndarray:
        """Add the points of matches whose goal keypoint lies in ``goal_mask`` (h, w) bool. Returns them."""
        if len(goal_xy) == 0:
            return np.zeros((0, 3), np.float32)
        h, w = goal_mask.shape
        gx = np.clip(np.round(goal_xy[:, 0]).astype(int), 0, w - 1)
        gy = np.clip(np.round(goal_xy[:, 1]).astype(int), 0, h - 1)
        on_object = goal_mask[gy, gx]
        return self._add(self.points_from_pixels(obs, obs_xy[on_object]), score, obs)

    def add_mask_pixels(self, obs: Observation, ego_mask: np.ndarray, score: float) -> np.ndarray:
        """Oracle localisation: lift (a subsample of) the egocentric instance mask (H, W) bool."""
        vu = np.argwhere(ego_mask)
        if len(vu) > self.config.max_oracle_pixels:
            vu = vu[np.linspace(0, len(vu) - 1, self.config.max_oracle_pixels).astype(int)]
        uv = vu[:, ::-1].astype(np.float32)
        # mask pixels are exact: no depth window (it would mix in the background at the edges)
        return self._add(self.points_from_pixels(obs, uv, window_px=0), score, obs)

    def _add(self, xyz: np.ndarray, score: float, obs: Observation) -> np.ndarray:
        return self.add_points(xyz, score, obs.step, (obs.pose.x_m, obs.pose.y_m))

    def add_points(self, xyz: np.ndarray, score: float, frame: int, robot_xy_m: tuple[float, float]) -> np.ndarray:
        """Add one view's goal points (N, 3) run frame, seen from ``robot_xy_m`` with ``score``, as
        view ``frame`` (a step; the agent's memory of a home gives remembered keyframes negative
        ids). Fewer than ``min_points_per_frame`` add nothing. Returns the points added."""
        if len(xyz) < self.config.min_points_per_frame:
            return np.zeros((0, 3), np.float32)
        # the distance to the seen surface (a robust nearest point), not to the points' centroid:
        # the centroid of a bed or couch lies a metre inside it, so a view from its edge would
        # count as a view from afar
        dist = np.hypot(xyz[:, 0] - robot_xy_m[0], xyz[:, 1] - robot_xy_m[1])
        robot = (float(robot_xy_m[0]), float(robot_xy_m[1]))
        self._views[frame] = View(frame, float(score), float(np.quantile(dist, 0.1)), len(xyz), robot)
        self._xyz = np.vstack([self._xyz, xyz.astype(np.float32)])
        self._score = np.concatenate([self._score, np.full(len(xyz), score, np.float32)])
        self._frame = np.concatenate([self._frame, np.full(len(xyz), frame, np.int64)])
        return xyz

    def candidates(self, grid: GridMap, detection_score: float | None = None) -> list[Candidate]:
        """Clusters of the accumulated points outside blacklisted cells, largest first. In the
        ``potential_blacklist`` layer only points scoring at least ``detection_score`` (tau)
        count (None: none there count)."""
        if len(self._xyz) == 0:
            return []
        grid.ensure_contains(tuple(self._xyz[:, :2].min(axis=0)), tuple(self._xyz[:, :2].max(axis=0)))
        ij = grid.xy_to_ij(self._xyz[:, :2])
        inside = grid.in_bounds(ij)
        keep = inside.copy()
        ii, jj = ij[inside, 0], ij[inside, 1]
        soft = grid.layers.potential_blacklist[ii, jj]
        if detection_score is not None:
            soft &= self._score[inside] < detection_score
        keep[inside] = ~grid.layers.blacklist[ii, jj] & ~soft
        if not keep.any():
            return []
        ij_k = ij[keep]
        lo = ij_k.min(axis=0)
        hi = ij_k.max(axis=0)
        r = max(1, int(round(0.5 * self.config.cluster_radius_m / grid.resolution_m)))
        occ = np.zeros((int(hi[0] - lo[0]) + 1 + 2 * r, int(hi[1] - lo[1]) + 1 + 2 * r), np.uint8)
        local = ij_k - lo + r
        occ[local[:, 0], local[:, 1]] = 1
        # cells within cluster_radius of each other end up connected after a dilation by half of it
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        _, labels = cv2.connectedComponents(cv2.dilate(occ, kernel), connectivity=8)
        point_label = labels[local[:, 0], local[:, 1]]
        xyz_k, score_k, frame_k = self._xyz[keep], self._score[keep], self._frame[keep]
        index_k = np.flatnonzero(keep)
        out = []
        for lab in np.unique(point_label):
            sel = point_label == lab
            pts = xyz_k[sel]
            cells = np.unique(ij_k[sel], axis=0)
            c = pts[:, :2].mean(axis=0)
            frames = np.unique(frame_k[sel])
            out.append(
                Candidate(
                    int(lab),
                    pts,
                    cells,
                    (float(c[0]), float(c[1])),
                    int(sel.sum()),
                    float(score_k[sel].max()),
                    int(len(frames)),
                    int(index_k[sel].min()),
                    tuple(int(f) for f in frames),
                    tuple(self._views[int(f)].robot_xy_m for f in frames if int(f) in self._views),
                )
            )
        out.sort(key=lambda c: c.n_points, reverse=True)
        return out
