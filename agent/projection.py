"""Inverse perspective projection: depth pixels -> 3D points in the robot base and run frames.

Frames (see ``agent.types``):

* camera: OpenCV (x right, y down, z forward); depth is z.
* base: x forward, y left, z up, origin on the floor below the camera.
* run: the start-relative world frame of ``Observation.pose`` (z up, floor at z = 0).

The camera sits ``camera_height_m`` above the floor and is pitched down by
``camera_tilt_rad`` (0 = level). With the optical axis rotated down by theta, the
camera axes expressed in the base frame are::

    x_cam -> (0, -1, 0)            (right = -left)
    y_cam -> (-sin t, 0, -cos t)   (image down)
    z_cam -> ( cos t, 0, -sin t)   (optical axis)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.types import Intrinsics, Pose2D


@dataclass(frozen=True, slots=True, eq=False)
class PointCloud:
    """Points lifted from a depth image.

    xyz_run: (N, 3) float32 metres in the run frame (z = height above the floor).
    xy_base: (N, 2) float32 metres in the base frame (forward, left), for ranges/bearings.
    uv_px:   (N, 2) int32 pixel (column, row) each point came from.
    """

    xyz_run: np.ndarray
    xy_base: np.ndarray
    uv_px: np.ndarray

    def at_pose(self, pose: Pose2D) -> PointCloud:
        """The same points with the robot at ``pose`` (the run-frame x, y from the base frame)."""
        xy = pose.transform_xy(self.xy_base).astype(np.float32)
        return PointCloud(np.column_stack([xy, self.xyz_run[:, 2]]), self.xy_base, self.uv_px)


def camera_rays_base(
    u_px: np.ndarray, v_px: np.ndarray, intrinsics: Intrinsics, tilt_rad: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel ray (scaled so that camera z = 1) in the base frame: (forward, left, up) each (N,)."""
    xn = (np.asarray(u_px, np.float32) - intrinsics.cx) / intrinsics.fx
    yn = (np.asarray(v_px, np.float32) - intrinsics.cy) / intrinsics.fy
    s, c = math.sin(tilt_rad), math.cos(tilt_rad)
    forward = c - yn * s
    left = -xn
    up = -s - yn * c
    return forward.astype(np.float32), left.astype(np.float32), up.astype(np.float32)


def lift_pixels(
    u_px: np.ndarray,
    v_px: np.ndarray,
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    pose: Pose2D,
    camera_height_m: float,
    camera_tilt_rad: float = 0.0,
) -> PointCloud:
    """Lift pixels with their depth (z along the optical axis, metres) to 3D.

    u_px, v_px, depth_m: (N,) arrays of equal length; no validity filtering here.
    """
    z = np.asarray(depth_m, np.float32)
    fwd, left, up = camera_rays_base(u_px, v_px, intrinsics, camera_tilt_rad)
    fwd = fwd * z
    left = left * z
    height = camera_height_m + up * z
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    x = pose.x_m + c * fwd - s * left
    y = pose.y_m + s * fwd + c * left
    xyz = np.stack([x, y, height], axis=1).astype(np.float32)
    uv = np.stack([np.asarray(u_px), np.asarray(v_px)], axis=1).astype(np.int32)
    return PointCloud(xyz, np.stack([fwd, left], axis=1).astype(np.float32), uv)


def lift_depth_image(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    pose: Pose2D,
    camera_height_m: float,
    camera_tilt_rad: float = 0.0,
    stride_px: int = 1,
    min_depth_m: float = 0.05,
    max_depth_m: float = math.inf,
) -> PointCloud:
    """Lift every ``stride_px``-th pixel of a depth image (H, W) float32 metres.

    Pixels with depth 0, non-finite, below ``min_depth_m`` or above ``max_depth_m``
    are not lifted (0 means "no reading" in ``Observation``).
    """
    h, w = depth_m.shape
    v, u = np.mgrid[0:h:stride_px, 0:w:stride_px]
    z = depth_m[::stride_px, ::stride_px]
    valid = np.isfinite(z) & (z >= min_depth_m) & (z <= max_depth_m)
    return lift_pixels(u[valid], v[valid], z[valid], intrinsics, pose, camera_height_m, camera_tilt_rad)


def project_points(
    xyz_run: np.ndarray, intrinsics: Intrinsics, pose: Pose2D, camera_height_m: float, camera_tilt_rad: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``lift_pixels``: run-frame points (N, 3) -> pixel (u, v) (N, 2) float and depth (N,)."""
    xyz = np.asarray(xyz_run, np.float64).reshape(-1, 3)
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    dx, dy = xyz[:, 0] - pose.x_m, xyz[:, 1] - pose.y_m
    fwd = c * dx + s * dy
    left = -s * dx + c * dy
    up = xyz[:, 2] - camera_height_m
    st, ct = math.sin(camera_tilt_rad), math.cos(camera_tilt_rad)
    # rows of the base->camera rotation are the camera axes in the base frame
    xc = -left
    yc = -st * fwd - ct * up
    zc = ct * fwd - st * up
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * xc / zc + intrinsics.cx
        v = intrinsics.fy * yc / zc + intrinsics.cy
    return np.stack([u, v], axis=1), zc
