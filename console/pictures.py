"""Pictures drawn from agent records: the top-down map, a colour depth image, the
keypoint-match picture and the video frame (egocentric view beside the map).

All inputs are in the run's start-relative frame (metres) and ``agent.types``
conventions; all outputs are (H, W, 3) uint8 RGB arrays. Pure functions, so the
viewer, the artifacts and the tests share them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from agent.types import MapSnapshot, Pose2D

# Layer colours (RGB); later layers are painted over earlier ones.
UNKNOWN_RGB = (48, 52, 60)
EXPLORED_RGB = (196, 208, 228)  # light blue-grey: visible on white pages and viewers
VISITED_RGB = (178, 222, 186)
OBSTACLE_RGB = (70, 78, 110)
FRONTIER_RGB = (0, 190, 220)
# each colour means one thing (the pages' legends, static/common.js): the purple of a rejected
# candidate (console/viewer/scene.py) is not a map layer's
BLACKLIST_RGB = (128, 128, 128)  # given up: rejected candidates' and abandoned frontiers' cells
COLLISION_RGB = (140, 60, 20)  # not the orange of a potential candidate
GOAL_RGB = (230, 30, 40)
TRAJECTORY_RGB = (20, 130, 60)
PLAN_RGB = (250, 180, 0)
TARGET_RGB = (255, 0, 200)
ROBOT_RGB = (20, 90, 230)
CANDIDATE_MARK_RGB = (255, 140, 0)  # a goal candidate not rejected (a cross)


@dataclass(frozen=True, slots=True)
class MapView:
    """How world metres map to the pixels of a drawn map (y up in the picture).

    Pixel column u = (x - x_min_m) * px_per_m; row v = (y_max_m - y) * px_per_m."""

    x_min_m: float
    y_max_m: float
    px_per_m: float
    width_px: int
    height_px: int

    def to_px(self, xy_m: np.ndarray) -> np.ndarray:
        xy_m = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        u = (xy_m[:, 0] - self.x_min_m) * self.px_per_m
        v = (self.y_max_m - xy_m[:, 1]) * self.px_per_m
        return np.stack([u, v], axis=1)


def _bounds(
    snapshot: MapSnapshot | None, points_xy: list[np.ndarray], margin_m: float
) -> tuple[float, float, float, float]:
    xs: list[float] = []
    ys: list[float] = []
    if snapshot is not None:
        known = snapshot.explored | snapshot.obstacle
        if known.any():
            ii, jj = np.nonzero(known)
            corners = snapshot.ij_to_xy(np.array([[ii.min(), jj.min()], [ii.max(), jj.max()]]))
            xs += [corners[0, 0], corners[1, 0]]
            ys += [corners[0, 1], corners[1, 1]]
    for pts in points_xy:
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if len(pts):
            xs += [float(pts[:, 0].min()), float(pts[:, 0].max())]
            ys += [float(pts[:, 1].min()), float(pts[:, 1].max())]
    if not xs:
        xs, ys = [-1.0, 1.0], [-1.0, 1.0]
    x0, x1 = min(xs) - margin_m, max(xs) + margin_m
    y0, y1 = min(ys) - margin_m, max(ys) + margin_m
    # at least 4 m across so the first frames are not absurdly zoomed in
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half = max(2.0, (x1 - x0) / 2, (y1 - y0) / 2)
    return cx - half, cx + half, cy - half, cy + half


def layers_rgb(snapshot: MapSnapshot) -> np.ndarray:
    """The map's layers painted into one (H, W, 3) uint8 image in grid order (row i = +y)."""
    h, w = snapshot.explored.shape
    img = np.empty((h, w, 3), np.uint8)
    img[:] = UNKNOWN_RGB
    img[snapshot.explored] = EXPLORED_RGB
    img[snapshot.visited] = VISITED_RGB
    img[snapshot.obstacle] = OBSTACLE_RGB
    img[snapshot.frontier] = FRONTIER_RGB
    if snapshot.blacklist is not None:
        img[snapshot.blacklist] = BLACKLIST_RGB
    img[snapshot.collision] = COLLISION_RGB
    img[snapshot.goal] = GOAL_RGB
    return img


def render_map(
    snapshot: MapSnapshot | None,
    *,
    trajectory_xy_m: np.ndarray | None = None,
    pose: Pose2D | None = None,
    plan_xy_m: np.ndarray | None = None,
    target_xy_m: tuple[float, float] | None = None,
    goal_points_xyz: np.ndarray | None = None,
    extra_points_xy_m: np.ndarray | None = None,
    extra_labels: Sequence[str] | None = None,
    size_px: int = 480,
    margin_m: float = 0.75,
) -> tuple[np.ndarray, MapView]:
    """A top-down picture (+x right, +y up) of the known part of the map with overlays.
    ``extra_labels``: a short text beside each extra point (the memory's request numbers)."""
    traj = np.zeros((0, 2)) if trajectory_xy_m is None else np.asarray(trajectory_xy_m, np.float64).reshape(-1, 2)
    plan = np.zeros((0, 2)) if plan_xy_m is None else np.asarray(plan_xy_m, np.float64).reshape(-1, 2)
    goal_xy = (
        np.zeros((0, 2)) if goal_points_xyz is None else np.asarray(goal_points_xyz, np.float64).reshape(-1, 3)[:, :2]
    )
    extra = np.zeros((0, 2)) if extra_points_xy_m is None else np.asarray(extra_points_xy_m, np.float64).reshape(-1, 2)
    pose_xy = np.zeros((0, 2)) if pose is None else np.array([[pose.x_m, pose.y_m]])
    target = np.zeros((0, 2)) if target_xy_m is None else np.array([target_xy_m], np.float64)
    x0, x1, _y0, y1 = _bounds(snapshot, [traj, goal_xy, pose_xy, target, extra], margin_m)
    px_per_m = size_px / (x1 - x0)
    view = MapView(x0, y1, px_per_m, size_px, size_px)

    canvas = np.empty((size_px, size_px, 3), np.uint8)
    canvas[:] = UNKNOWN_RGB
    if snapshot is not None:
        grid = layers_rgb(snapshot)
        # Sample the grid at each output pixel centre (nearest cell): exact and cheap.
        u = np.arange(size_px) + 0.5
        xs = x0 + u / px_per_m
        ys = y1 - u / px_per_m
        jj = np.floor((xs - snapshot.origin_xy_m[0]) / snapshot.resolution_m).astype(np.int64)
        ii = np.floor((ys - snapshot.origin_xy_m[1]) / snapshot.resolution_m).astype(np.int64)
        h, w = grid.shape[:2]
        valid_j = (jj >= 0) & (jj < w)
        valid_i = (ii >= 0) & (ii < h)
        rows = np.clip(ii, 0, h - 1)
        cols = np.clip(jj, 0, w - 1)
        sampled = grid[rows[:, None], cols[None, :]]
        mask = valid_i[:, None] & valid_j[None, :]
        canvas[mask] = sampled[mask]

    thick = max(1, size_px // 240)

    def poly(points: np.ndarray, colour: tuple[int, int, int], width: int) -> None:
        if len(points) >= 2:
            pts = np.round(view.to_px(points)).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(canvas, [pts], False, colour, width, cv2.LINE_AA)

    poly(traj, TRAJECTORY_RGB, thick)
    poly(plan, PLAN_RGB, thick)
    for u_px, v_px in np.round(view.to_px(goal_xy)).astype(np.int32):
        cv2.circle(canvas, (int(u_px), int(v_px)), max(2, thick + 1), GOAL_RGB, -1, cv2.LINE_AA)
    for k, (u_px, v_px) in enumerate(np.round(view.to_px(extra)).astype(np.int32)):
        cv2.drawMarker(canvas, (int(u_px), int(v_px)), CANDIDATE_MARK_RGB, cv2.MARKER_TILTED_CROSS, 6 * thick, thick)
        if extra_labels is not None and k < len(extra_labels):
            _label(canvas, extra_labels[k], (int(u_px) + 4 * thick, int(v_px) - 3 * thick), thick)
    if len(target):
        u_px, v_px = np.round(view.to_px(target)[0]).astype(int)
        cv2.drawMarker(canvas, (int(u_px), int(v_px)), TARGET_RGB, cv2.MARKER_STAR, 8 * thick, thick, cv2.LINE_AA)
    if pose is not None:
        r_px = max(3, int(round(0.17 * px_per_m)))
        c = np.round(view.to_px(pose_xy)[0]).astype(int)
        cv2.circle(canvas, (int(c[0]), int(c[1])), r_px, ROBOT_RGB, -1, cv2.LINE_AA)
        tip = view.to_px(
            np.array([[pose.x_m + 0.4 * math.cos(pose.yaw_rad), pose.y_m + 0.4 * math.sin(pose.yaw_rad)]])
        )[0]
        cv2.arrowedLine(
            canvas,
            (int(c[0]), int(c[1])),
            (int(round(tip[0])), int(round(tip[1]))),
            (255, 255, 255),
            thick,
            cv2.LINE_AA,
            tipLength=0.35,
        )
    return canvas, view


def _label(canvas: np.ndarray, text: str, at_px: tuple[int, int], thick: int) -> None:
    """``text`` with its lower left corner at ``at_px``, in the mark's orange on a dark outline
    (legible on every layer colour), moved inside the picture when it would leave it."""
    scale = 0.45 * thick
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    u = min(max(at_px[0], 1), canvas.shape[1] - w - 1)
    v = min(max(at_px[1], h + 1), canvas.shape[0] - 1)
    cv2.putText(canvas, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(canvas, text, (u, v), cv2.FONT_HERSHEY_SIMPLEX, scale, CANDIDATE_MARK_RGB, thick, cv2.LINE_AA)


def depth_rgb(depth_m: np.ndarray, max_m: float = 5.0) -> np.ndarray:
    """Depth (H, W) float32 metres -> turbo-coloured (H, W, 3) uint8; invalid (0) pixels black."""
    depth = np.asarray(depth_m, np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    scaled = np.zeros(depth.shape, np.uint8)
    scaled[valid] = np.clip(255.0 * (1.0 - np.minimum(depth[valid], max_m) / max_m), 0, 255).astype(np.uint8)
    bgr = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    rgb[~valid] = 0
    return rgb


def fit_height(rgb: np.ndarray, height_px: int) -> np.ndarray:
    h, w = rgb.shape[:2]
    width_px = max(1, int(round(w * height_px / h)))
    interp = cv2.INTER_AREA if height_px < h else cv2.INTER_LINEAR
    return cv2.resize(rgb, (width_px, height_px), interpolation=interp)


def match_picture(
    goal_rgb: np.ndarray,
    obs_rgb: np.ndarray,
    matches_goal_xy: np.ndarray,
    matches_obs_xy: np.ndarray,
    height_px: int = 320,
    max_lines: int = 200,
) -> np.ndarray:
    """Goal image and egocentric image side by side (same height) with match lines."""
    g = fit_height(goal_rgb, height_px)
    o = fit_height(obs_rgb, height_px)
    sg = height_px / goal_rgb.shape[0]
    so = height_px / obs_rgb.shape[0]
    canvas = np.concatenate([g, o], axis=1).copy()
    mg = np.asarray(matches_goal_xy, np.float64).reshape(-1, 2)
    mo = np.asarray(matches_obs_xy, np.float64).reshape(-1, 2)
    n = min(len(mg), len(mo))
    if n > max_lines:  # thin out evenly rather than drawing a solid block
        keep = np.linspace(0, n - 1, max_lines).astype(int)
        mg, mo, n = mg[keep], mo[keep], max_lines
    rng = np.random.default_rng(0)
    colours = rng.integers(60, 255, size=(max(n, 1), 3))
    for k in range(n):
        p = (int(round(mg[k, 0] * sg)), int(round(mg[k, 1] * sg)))
        q = (int(round(mo[k, 0] * so + g.shape[1])), int(round(mo[k, 1] * so)))
        colour = tuple(int(c) for c in colours[k])
        cv2.line(canvas, p, q, colour, 1, cv2.LINE_AA)
        cv2.circle(canvas, p, 2, colour, -1)
        cv2.circle(canvas, q, 2, colour, -1)
    cv2.putText(
        canvas, f"{n} matches", (6, height_px - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA
    )
    return canvas


def video_frame(obs_rgb: np.ndarray, map_rgb: np.ndarray, caption: str, height_px: int = 240) -> np.ndarray:
    """Egocentric view beside the map, with a caption strip underneath."""
    left = fit_height(obs_rgb, height_px)
    right = fit_height(map_rgb, height_px)
    row = np.concatenate([left, right], axis=1)
    strip = np.full((22, row.shape[1], 3), 20, np.uint8)
    cv2.putText(strip, caption[:80], (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (240, 240, 240), 1, cv2.LINE_AA)
    return np.concatenate([row, strip], axis=0)
