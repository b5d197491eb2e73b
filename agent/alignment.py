"""Frame-to-map alignment: the pose a depth frame fits the map best at, near the estimate.

A real robot's pose estimate is off by a few centimetres and a degree or two (wheel odometry
between a lidar localiser's corrections). Fused at the estimate, a wall seen again from farther
away lands beside its first copy: at 4-5 m a 1.5 deg heading error puts it 10-13 cm into the
room, and a corridor seen lengthwise gets a phantom wall that closes it
(docs/experiments/unconfirmed-obstacles.md). Before a frame is fused, its obstacle points are
tried at small rotations (about the robot) and shifts of the estimated pose against the map's
obstacle cells; the pose where they lie nearest the mapped obstacles (mean distance to the
nearest one, capped) is taken when it beats the estimate by a margin and enough of the frame
lands on mapped structure. The search is centred on the estimate, never on an earlier
correction, so the map cannot drift further from the localiser than the search window.

With an exact pose the estimate already puts every re-seen point in its mapped cell (distance
0), so no other pose beats it by the margin and the map is the one fused without alignment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from agent.types import Pose2D, wrap_angle

_UPSAMPLE = 4  # the distance field is looked up at a quarter cell


@dataclass(frozen=True, slots=True)
class AlignmentConfig:
    enabled: bool = True
    max_yaw_deg: float = 4.0  # search window: the localiser's heading error is ~1.5 deg SD
    yaw_step_deg: float = 0.25  # 2 cm across at 5 m, under half a 5 cm cell
    max_shift_m: float = 0.05  # ... and its position error ~3 cm SD
    shift_step_m: float = 0.025
    max_range_m: float = 5.0  # obstacle points used: within this of the robot
    max_points: int = 400  # at most this many, evenly spread over the frame's obstacle points
    min_points: int = 60  # fewer obstacle points: too little structure to align on
    cap_m: float = 0.15  # a point's distance to the nearest mapped obstacle is counted up to this
    # the best pose must cut the mean (capped) distance by this much against the estimate: above
    # what the 5 cm cells' quantisation alone gives a shift (up to ~0.013 m at an exact pose in
    # tests/unit/agent/test_agent_alignment.py; a 1.5-2.5 deg heading error gives 0.03-0.05) ...
    min_gain_m: float = 0.02
    # ... and put this share of the points within one cell of a mapped obstacle (the frame sees
    # structure already mapped: a frame of a new room has nothing to align to)
    min_inlier_share: float = 0.3


@dataclass(frozen=True, slots=True)
class Alignment:
    """The outcome for one frame: the pose to fuse at (the estimate when not corrected)."""

    pose: Pose2D
    corrected: bool
    yaw_deg: float = 0.0  # correction applied, about the robot
    shift_m: tuple[float, float] = (0.0, 0.0)
    score_m: float = math.nan  # mean capped distance at the chosen pose (nan: not searched)
    estimate_score_m: float = math.nan  # ... at the estimate
    inlier_share: float = math.nan


def align_frame(
    obstacle: np.ndarray,
    origin_xy_m: tuple[float, float],
    resolution_m: float,
    points_base: np.ndarray,
    pose: Pose2D,
    cfg: AlignmentConfig,
) -> Alignment:
    """Search poses near ``pose`` for the frame's obstacle points ``points_base`` ((N, 2) metres,
    base frame: forward, left) against the map's ``obstacle`` layer (``ij_grid`` order, cell
    (0, 0)'s corner at ``origin_xy_m``). Rotations are about the robot's position."""
    pts = np.asarray(points_base, np.float64).reshape(-1, 2)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= cfg.max_range_m]
    if len(pts) < cfg.min_points or not obstacle.any():
        return Alignment(pose, False)
    if len(pts) > cfg.max_points:
        pts = pts[np.linspace(0, len(pts) - 1, cfg.max_points).round().astype(np.int64)]
    res = resolution_m
    cap = cfg.cap_m / res  # in cells
    # the map window the search can reach, with the distance (in cells, capped) to its obstacles
    reach = cfg.max_range_m + cfg.max_shift_m + cfg.cap_m + res
    ox, oy = origin_xy_m
    h, w = obstacle.shape
    j0 = max(int(math.floor((pose.x_m - reach - ox) / res)), 0)
    j1 = min(int(math.ceil((pose.x_m + reach - ox) / res)) + 1, w)
    i0 = max(int(math.floor((pose.y_m - reach - oy) / res)), 0)
    i1 = min(int(math.ceil((pose.y_m + reach - oy) / res)) + 1, h)
    if i1 <= i0 or j1 <= j0:
        return Alignment(pose, False)
    win = obstacle[i0:i1, j0:j1]
    if not win.any():
        return Alignment(pose, False)
    # distance (in cells, capped) from each cell centre to the nearest obstacle cell's centre,
    # interpolated to a quarter cell so that sub-cell moves change the score smoothly
    dist = cv2.distanceTransform((~win).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    dist = np.pad(np.minimum(dist, cap), 1, constant_values=cap)  # beyond the window: the cap
    f = _UPSAMPLE
    dist = cv2.resize(dist, (dist.shape[1] * f, dist.shape[0] * f), interpolation=cv2.INTER_LINEAR)
    wx, wy = ox + (j0 - 1) * res, oy + (i0 - 1) * res  # corner of the padded window
    hh, ww = dist.shape
    step = res / f

    n_yaw = int(round(cfg.max_yaw_deg / cfg.yaw_step_deg))
    yaws = np.radians(np.arange(-n_yaw, n_yaw + 1) * cfg.yaw_step_deg)
    n_sh = int(round(cfg.max_shift_m / cfg.shift_step_m))
    s = np.arange(-n_sh, n_sh + 1) * cfg.shift_step_m
    sx, sy = (a.reshape(-1) for a in np.meshgrid(s, s))  # (S,)
    scores = np.empty((len(yaws), len(sx)))
    inliers = np.empty((len(yaws), len(sx)))
    for k, dyaw in enumerate(yaws):
        c, si = math.cos(pose.yaw_rad + dyaw), math.sin(pose.yaw_rad + dyaw)
        x = pose.x_m + c * pts[:, 0] - si * pts[:, 1]
        y = pose.y_m + si * pts[:, 0] + c * pts[:, 1]
        jj = np.floor((x[None, :] + sx[:, None] - wx) / step).astype(np.int64)
        ii = np.floor((y[None, :] + sy[:, None] - wy) / step).astype(np.int64)
        np.clip(jj, 0, ww - 1, out=jj)
        np.clip(ii, 0, hh - 1, out=ii)
        d = dist[ii, jj]  # (S, N)
        scores[k] = d.mean(axis=1)
        inliers[k] = (d <= 1.0).mean(axis=1)
    k0, s0 = n_yaw, len(sx) // 2  # the estimate: no rotation, no shift
    est, best = float(scores[k0, s0]) * res, float(scores.min()) * res
    if est - best < cfg.min_gain_m:
        return Alignment(pose, False, score_m=est, estimate_score_m=est, inlier_share=float(inliers[k0, s0]))
    # the best; of equal ones (a wall two cells thick leaves a band of them), the smallest correction
    near = scores <= scores.min() + 1e-9
    size = np.abs(np.arange(len(yaws)) - k0)[:, None] / max(n_yaw, 1) + np.hypot(sx, sy)[None, :] / max(
        cfg.max_shift_m, 1e-9
    )
    kb, sb = np.unravel_index(int(np.argmin(np.where(near, size, np.inf))), scores.shape)
    share = float(inliers[kb, sb])
    if share < cfg.min_inlier_share:
        return Alignment(pose, False, score_m=est, estimate_score_m=est, inlier_share=float(inliers[k0, s0]))
    best = float(scores[kb, sb]) * res
    dyaw = float(yaws[kb])
    corrected = Pose2D(pose.x_m + float(sx[sb]), pose.y_m + float(sy[sb]), wrap_angle(pose.yaw_rad + dyaw))
    return Alignment(
        corrected,
        True,
        yaw_deg=math.degrees(dyaw),
        shift_m=(float(sx[sb]), float(sy[sb])),
        score_m=best,
        estimate_score_m=est,
        inlier_share=share,
    )
