"""Frame-to-map alignment: the pose a depth frame fits the map best at, near the estimate.

A real robot's pose estimate is off by a few centimetres and a degree or two (wheel odometry
between a lidar localiser's corrections). Fused at the estimate, a wall seen again from farther
away lands beside its first copy: at 4-5 m a 1.5 deg heading error puts it 10-13 cm into the
room, and a corridor seen lengthwise gets a phantom wall that closes it
(docs/experiments/unconfirmed-obstacles.md). Before a frame is fused it is aligned as a 2D laser
scan is: its scan (each image column's nearest obstacle point) is tried at small rotations (about
the robot) and shifts of the estimated pose against the map's surface cells (obstacle cells
beside explored free space: what a scan can hit; the inside of a bed's footprint is not), scored
by the mean distance to the nearest surface cell, capped. The best pose is taken when it beats
the estimate by a margin, lies inside the search window (an optimum on its edge says the
frame does not fix the heading) and puts nearly the whole scan on mapped surfaces (a frame
that sees new structure is fused at the estimate: there is nothing to draw twice). The search
is centred on the estimate, never on an earlier correction, so the map cannot drift further
from the localiser than the window.
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
    max_yaw_deg: float = 6.0  # search window: the localiser's heading error is ~1.5 deg SD
    yaw_step_deg: float = 0.25  # 2 cm across at 5 m, under half a 5 cm cell
    max_shift_m: float = 0.05  # ... and its position error ~3 cm SD
    shift_step_m: float = 0.025
    max_range_m: float = 5.0  # scan points used: within this of the robot
    min_points: int = 40  # fewer scan points: too little structure to align on
    cap_m: float = 0.15  # a point's distance to the nearest mapped surface is counted up to this
    # the best pose must cut the mean (capped) distance by this much against the estimate ...
    min_gain_m: float = 0.02
    # ... and put this share of the scan within one cell of a mapped surface
    min_inlier_share: float = 0.9
    # ... and the previous frame must have asked for the same correction (within 1 deg, a cell at
    # 3 m, and a cell in position): a pose error lasts between a localiser's corrections, while a
    # frame that fits better elsewhere by chance (a wall seen alone from up close) is one frame
    # (clean: 3 such frames in 298 steps of two train episodes, none twice in a row; under
    # `stretch` 11 corrections taken in the same steps, benchmarks/alignment_check.py)
    agree_yaw_deg: float = 1.0
    agree_shift_m: float = 0.05


@dataclass(frozen=True, slots=True)
class Alignment:
    """The outcome for one frame: the pose to fuse at (the estimate when not corrected)."""

    pose: Pose2D
    corrected: bool
    yaw_deg: float = 0.0  # correction applied, about the robot
    shift_m: tuple[float, float] = (0.0, 0.0)
    score_m: float = math.nan  # mean capped distance at the chosen pose (nan: not searched)
    estimate_score_m: float = math.nan  # ... at the estimate
    inlier_share: float = math.nan  # of the scan within a cell of a mapped surface, at the chosen pose
    estimate_inlier_share: float = math.nan  # ... at the estimate


def frame_scan(xy_base: np.ndarray, uv_px: np.ndarray, is_obstacle: np.ndarray, max_range_m: float) -> np.ndarray:
    """A depth frame as a 2D laser scan: each image column's nearest obstacle point (base frame,
    (K, 2) metres), within ``max_range_m``."""
    rng = np.hypot(xy_base[:, 0], xy_base[:, 1])
    keep = is_obstacle & (rng <= max_range_m)
    if not keep.any():
        return np.zeros((0, 2))
    col, r, xy = uv_px[keep, 0], rng[keep], xy_base[keep]
    order = np.lexsort((r, col))  # by column, nearest first
    col, xy = col[order], xy[order]
    first = np.ones(len(col), bool)
    first[1:] = col[1:] != col[:-1]
    return np.asarray(xy[first], np.float64)


def surface_cells(obstacle: np.ndarray, explored: np.ndarray) -> np.ndarray:
    """Obstacle cells with explored free space among their 8 neighbours."""
    free = (explored & ~obstacle).astype(np.uint8)
    return obstacle & (cv2.dilate(free, np.ones((3, 3), np.uint8)) > 0)


def align_frame(
    obstacle: np.ndarray,
    explored: np.ndarray,
    origin_xy_m: tuple[float, float],
    resolution_m: float,
    scan_base: np.ndarray,
    pose: Pose2D,
    cfg: AlignmentConfig,
) -> Alignment:
    """Search poses near ``pose`` for the frame's scan ``scan_base`` ((N, 2) metres, base frame:
    forward, left; ``frame_scan``) against the map's surfaces (from its ``obstacle`` and
    ``explored`` layers, ``ij_grid`` order, cell (0, 0)'s corner at ``origin_xy_m``)."""
    pts = np.asarray(scan_base, np.float64).reshape(-1, 2)
    if len(pts) < cfg.min_points or not obstacle.any():
        return Alignment(pose, False)
    res = resolution_m
    cap = cfg.cap_m / res  # in cells
    # the map window the search can reach
    reach = cfg.max_range_m + cfg.max_shift_m + cfg.cap_m + res
    ox, oy = origin_xy_m
    h, w = obstacle.shape
    j0 = max(int(math.floor((pose.x_m - reach - ox) / res)) - 1, 0)
    j1 = min(int(math.ceil((pose.x_m + reach - ox) / res)) + 2, w)
    i0 = max(int(math.floor((pose.y_m - reach - oy) / res)) - 1, 0)
    i1 = min(int(math.ceil((pose.y_m + reach - oy) / res)) + 2, h)
    if i1 <= i0 or j1 <= j0:
        return Alignment(pose, False)
    win = surface_cells(obstacle[i0:i1, j0:j1], explored[i0:i1, j0:j1])
    if not win.any():
        return Alignment(pose, False)
    # distance (in cells, capped) from each cell centre to the nearest surface cell's centre,
    # interpolated to a quarter cell so that sub-cell moves change the score smoothly
    dist = cv2.distanceTransform((~win).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    dist = np.pad(np.minimum(dist, cap), 1, constant_values=cap)  # beyond the window: the cap
    f = _UPSAMPLE
    dist = cv2.resize(dist, (dist.shape[1] * f, dist.shape[0] * f), interpolation=cv2.INTER_LINEAR)
    wx, wy = ox + (j0 - 1) * res, oy + (i0 - 1) * res  # corner of the padded window
    hh, ww = dist.shape
    step = res / f

    def score(dyaw: float, sx: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean capped distance (cells) and inlier share of the scan at each shift, turned by dyaw."""
        c, si = math.cos(pose.yaw_rad + dyaw), math.sin(pose.yaw_rad + dyaw)
        x = pose.x_m + c * pts[:, 0] - si * pts[:, 1]
        y = pose.y_m + si * pts[:, 0] + c * pts[:, 1]
        jj = np.floor((x[None, :] + sx[:, None] - wx) / step).astype(np.int64)
        ii = np.floor((y[None, :] + sy[:, None] - wy) / step).astype(np.int64)
        np.clip(jj, 0, ww - 1, out=jj)
        np.clip(ii, 0, hh - 1, out=ii)
        d = dist[ii, jj]  # (S, N)
        return d.mean(axis=1), (d <= 1.0).mean(axis=1)

    # no pose scores below 0, so an estimate within the gain of 0 stands without a search
    zero = np.zeros(1)
    est_cells, est_share = score(0.0, zero, zero)
    if float(est_cells[0]) * res < cfg.min_gain_m:
        est = float(est_cells[0]) * res
        share0 = float(est_share[0])
        return Alignment(
            pose, False, score_m=est, estimate_score_m=est, inlier_share=share0, estimate_inlier_share=share0
        )
    n_yaw = int(round(cfg.max_yaw_deg / cfg.yaw_step_deg))
    yaws = np.radians(np.arange(-n_yaw, n_yaw + 1) * cfg.yaw_step_deg)
    n_sh = int(round(cfg.max_shift_m / cfg.shift_step_m))
    s = np.arange(-n_sh, n_sh + 1) * cfg.shift_step_m
    sx, sy = (a.reshape(-1) for a in np.meshgrid(s, s))  # (S,)
    scores = np.empty((len(yaws), len(sx)))
    inliers = np.empty((len(yaws), len(sx)))
    for k, dyaw in enumerate(yaws):
        scores[k], inliers[k] = score(float(dyaw), sx, sy)
    k0, s0 = n_yaw, len(sx) // 2  # the estimate: no rotation, no shift
    est, best = float(scores[k0, s0]) * res, float(scores.min()) * res
    share0 = float(inliers[k0, s0])
    kept = Alignment(pose, False, score_m=est, estimate_score_m=est, inlier_share=share0, estimate_inlier_share=share0)
    if est - best < cfg.min_gain_m:
        return kept
    # the best; of equal ones, the smallest correction
    near = scores <= scores.min() + 1e-9
    size = np.abs(np.arange(len(yaws)) - k0)[:, None] / max(n_yaw, 1) + np.hypot(sx, sy)[None, :] / max(
        cfg.max_shift_m, 1e-9
    )
    kb, sb = np.unravel_index(int(np.argmin(np.where(near, size, np.inf))), scores.shape)
    share = float(inliers[kb, sb])
    # an optimum on the window's edge in heading is not bracketed: the frame's structure (one
    # wall, a look-around's sliver of overlap) leaves the heading unconstrained, or the error is
    # beyond the window; either way the edge is no estimate of it
    if share < cfg.min_inlier_share or abs(kb - k0) == n_yaw:
        return kept
    dyaw = float(yaws[kb])
    corrected = Pose2D(pose.x_m + float(sx[sb]), pose.y_m + float(sy[sb]), wrap_angle(pose.yaw_rad + dyaw))
    return Alignment(
        corrected,
        True,
        yaw_deg=math.degrees(dyaw),
        shift_m=(float(sx[sb]), float(sy[sb])),
        score_m=float(scores[kb, sb]) * res,
        estimate_score_m=est,
        inlier_share=share,
        estimate_inlier_share=share0,
    )


def agrees(previous: Alignment | None, current: Alignment, cfg: AlignmentConfig) -> bool:
    """Whether two consecutive frames' proposals ask for the same correction (both corrected)."""
    return (
        previous is not None
        and previous.corrected
        and current.corrected
        and abs(previous.yaw_deg - current.yaw_deg) <= cfg.agree_yaw_deg + 1e-9
        and math.dist(previous.shift_m, current.shift_m) <= cfg.agree_shift_m + 1e-9
    )
