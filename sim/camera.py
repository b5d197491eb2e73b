"""Pinhole cameras for PyBullet's TinyRenderer (docs/architecture.md sections 1 and 8).

PyBullet's ``computeProjectionMatrixFOV`` takes the *vertical* field of view; our
specs hold the horizontal one (as Habitat and the Stretch config do) and convert.
The depth buffer is non-linear; ``depth_buffer_to_metres`` turns it into depth
along the optical axis: ``far * near / (far - (far - near) * buf)``.

A frame is converted once per render (issue 32): RGB out of PyBullet's RGBA with
``cv2.cvtColor`` (a strided numpy copy costs 40 times more), depth in place in one float64
array (no temporaries), and the segmentation kept raw: a goal mask compares raw ids
(``Render.mask_of``), the whole instance-id image is built only for the readers that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
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
    instance_ids: (H, W) int32 goal-instance id per pixel, -1 for anything else; computed on
                  first use from the renderer's raw segmentation buffer, because only oracles,
                  metrics and goal sampling read it (not the agent's step). One instance's
                  pixels: ``mask_of`` (no instance-id image).
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

    def mask_of(self, instance_id: int) -> np.ndarray:
        """(H, W) bool: the pixels of one instance, exactly ``instance_ids == instance_id``, from
        the raw ids its bodies have (one per instance: a compare, not a look-up per pixel; the
        evaluation counts the goal's pixels every step)."""
        if self._ids or self.seg_lut is None or instance_id < 0:
            return self.instance_ids == instance_id
        raw = np.flatnonzero(self.seg_lut == instance_id) - 1  # raw ids the look-up maps to it
        if len(raw) == 1:
            return self.seg_raw == raw[0]
        return np.isin(self.seg_raw, raw)

    def copy(self) -> Render:
        """The same frame in arrays of its own."""
        return Render(self.rgb.copy(), self.depth_m.copy(), self.seg_raw.copy(), self.seg_lut)


def rgba_to_rgb(rgba: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 -> (H, W, 3) uint8, contiguous, the alpha channel dropped."""
    return cv2.cvtColor(np.ascontiguousarray(rgba, dtype=np.uint8), cv2.COLOR_RGBA2RGB)


def depth_buffer_to_metres(buf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """OpenGL depth buffer values in [0, 1] -> (H, W) float32 metres along the optical axis.

    Computed in float64 in one working array, operation by operation as the formula reads
    (the same values as with temporaries, without allocating five frame-sized arrays)."""
    depth = np.array(buf, dtype=np.float64)  # a copy: the caller's buffer is left alone
    background = depth >= 1.0 - 1e-7  # no reading
    np.multiply(depth, far_m - near_m, out=depth)
    np.subtract(far_m, depth, out=depth)
    np.divide(far_m * near_m, depth, out=depth)
    depth[background] = 0.0
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
