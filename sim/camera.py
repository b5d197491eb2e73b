"""Pinhole cameras for PyBullet's TinyRenderer (docs/architecture.md sections 1 and 8).

PyBullet's ``computeProjectionMatrixFOV`` takes the *vertical* field of view; our
specs hold the horizontal one (as Habitat and the Stretch config do) and convert.
The depth buffer is non-linear; ``depth_buffer_to_metres`` turns it into depth
along the optical axis: ``far * near / (far - (far - near) * buf)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agent.types import CAMERA_HEIGHT_M, CAMERA_HEIGHT_PX, CAMERA_HFOV_DEG, CAMERA_WIDTH_PX, Intrinsics

NEAR_M = 0.05
FAR_M = 30.0


@dataclass(frozen=True, slots=True)
class CameraSpec:
    """A camera: image size, horizontal FOV, optical centre height above the floor and
    pitch (positive looking down, radians)."""

    width_px: int
    height_px: int
    hfov_deg: float
    height_m: float = CAMERA_HEIGHT_M
    pitch_rad: float = 0.0
    near_m: float = NEAR_M
    far_m: float = FAR_M

    @property
    def vfov_deg(self) -> float:
        t = math.tan(math.radians(self.hfov_deg) / 2.0) * self.height_px / self.width_px
        return math.degrees(2.0 * math.atan(t))

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_hfov(self.width_px, self.height_px, self.hfov_deg)


# The Stretch head camera in simulation: portrait 360 x 640, 42 deg HFOV, 1.31 m, level.
SIM_CAMERA = CameraSpec(CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX, CAMERA_HFOV_DEG, CAMERA_HEIGHT_M, 0.0)
GOAL_IMAGE_PX = 512


@dataclass(frozen=True, slots=True, eq=False)
class Render:
    """One rendered frame.

    rgb:          (H, W, 3) uint8, R,G,B.
    depth_m:      (H, W) float32 metres along the optical axis; 0 where nothing was hit.
    instance_ids: (H, W) int64 goal-instance id per pixel, -1 for anything else; computed on
                  first use from the renderer's raw segmentation buffer, because only oracles,
                  metrics and goal sampling read it (not the agent's step).
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    seg_raw: np.ndarray  # (H, W) int32 the renderer's body/link ids (or instance ids when seg_lut is None)
    seg_lut: np.ndarray | None = None  # raw id + 1 -> instance id (-1: not a goal instance)
    _ids: list = field(default_factory=list, repr=False)  # one-element cache of instance_ids

    @property
    def instance_ids(self) -> np.ndarray:
        if not self._ids:
            if self.seg_lut is None:
                ids = np.asarray(self.seg_raw, np.int64)
            else:
                seg = np.asarray(self.seg_raw, np.int64)
                seg = np.where((seg >= -1) & (seg < len(self.seg_lut) - 1), seg, -1)
                ids = self.seg_lut[seg + 1]
            self._ids.append(ids)
        return self._ids[0]


def depth_buffer_to_metres(buf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """OpenGL depth buffer values in [0, 1] -> (H, W) float32 metres along the optical axis."""
    buf = np.asarray(buf, dtype=np.float64)
    depth = far_m * near_m / (far_m - (far_m - near_m) * buf)
    depth[buf >= 1.0 - 1e-7] = 0.0  # background: no reading
    return depth.astype(np.float32)


def camera_axes(yaw_rad: float, pitch_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """World-frame forward (optical axis) and up vectors of a camera with this yaw and downward pitch."""
    cy, sy, cp, sp = math.cos(yaw_rad), math.sin(yaw_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    forward = np.array([cy * cp, sy * cp, -sp])
    up = np.array([cy * sp, sy * sp, cp])
    return forward, up


def T_world_camera(eye_xyz: np.ndarray, yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """4x4 pose of the camera in the world, OpenCV camera axes (x right, y down, z forward)."""
    forward, up = camera_axes(yaw_rad, pitch_rad)
    right = np.cross(forward, up)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, -up, forward, eye_xyz
    return T


def look_at_angles(eye_xyz: np.ndarray, target_xyz: np.ndarray) -> tuple[float, float]:
    """(yaw_rad, pitch_rad down) pointing the optical axis from eye to target."""
    d = np.asarray(target_xyz, float) - np.asarray(eye_xyz, float)
    return math.atan2(d[1], d[0]), math.atan2(-d[2], math.hypot(d[0], d[1]))
