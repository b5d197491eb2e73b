"""The live view's geometry: camera orientation (rotation matrix and quaternion) and the line
segments viser draws for paths (``console.viewer``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def camera_rotation(yaw_rad: float, tilt_rad: float) -> np.ndarray:
    """World-from-camera rotation (3x3) for an OpenCV camera (x right, y down, z forward)
    on a robot heading ``yaw_rad`` with the optical axis pitched down by ``tilt_rad``."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    forward = np.array([c * math.cos(tilt_rad), s * math.cos(tilt_rad), -math.sin(tilt_rad)])
    right = np.array([s, -c, 0.0])
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


def rotation_to_wxyz(R: np.ndarray) -> tuple[float, float, float, float]:
    """A proper rotation matrix -> unit quaternion (w, x, y, z) (Shepperd's method)."""
    m = np.asarray(R, np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return (w / n, x / n, y / n, z / n)


def segments(xy: np.ndarray, z_m: float) -> np.ndarray:
    """(N, 2) polyline -> (N-1, 2, 3) line segments at height z_m."""
    xy = np.asarray(xy, np.float32).reshape(-1, 2)
    if len(xy) < 2:
        return np.zeros((0, 2, 3), np.float32)
    pts = np.concatenate([xy, np.full((len(xy), 1), z_m, np.float32)], axis=1)
    return np.stack([pts[:-1], pts[1:]], axis=1)


def set_segments(handle: Any, segments: np.ndarray, colour: tuple[int, int, int]) -> None:
    """Replace a line-segment node's points; its per-point colours must match in count."""
    handle.points = segments.astype(np.float32)
    handle.colors = np.broadcast_to(np.array(colour, np.uint8), segments.shape).copy()
