"""Image encodings and camera geometry of stretch_ai's observation messages (docs/architecture.md section 6).

* ``rgb``: 1-D uint8 array of JPEG bytes. The robot hands its rgb8 camera array straight
  to ``cv2.imencode`` (which assumes B,G,R), so ``cv2.imdecode`` gives back the original
  R,G,B order: no channel swap on either side.
* ``depth``: 1-D uint8 array of JPEG2000 bytes of a uint16 image in millimetres
  (0 = no reading).
* ``camera_pose``: (4, 4) ``T_world_camera`` of the upright (rotated) image, OpenCV
  camera convention (x right, y down, z forward); the world frame is the robot's map
  frame, z up with the floor at z = 0.
* ``camera_K``: (3, 3) intrinsics of the upright image. The ``rgb_width``/``rgb_height``
  fields have swapped meanings on the robot (``rgb_width`` holds the row count), so the
  image size is always taken from the decoded array.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from agent.types import Intrinsics

JPEG_QUALITY = 90  # the bridge's default (stretch.utils.compression.to_jpg)
JP2_COMPRESSION_X1000 = 800  # the bridge's default (stretch.utils.compression.to_jp2)
MM_PER_M = 1000.0


class DecodeError(ValueError):
    """An image or camera field in a message cannot be used."""


def _as_bytes_array(encoded: object, field: str) -> np.ndarray:
    if isinstance(encoded, (bytes, bytearray, memoryview)):
        return np.frombuffer(encoded, dtype=np.uint8)
    if isinstance(encoded, np.ndarray) and encoded.dtype == np.uint8 and encoded.ndim == 1 and encoded.size > 0:
        return encoded
    raise DecodeError(f"{field}: expected a 1-D uint8 array of encoded bytes, got {type(encoded).__name__}")


def encode_rgb(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> np.ndarray:
    """(H, W, 3) uint8 R,G,B -> 1-D uint8 JPEG bytes, exactly as the robot encodes it."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    ok, buf = cv2.imencode(".jpg", rgb, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.reshape(-1)


def decode_rgb(encoded: object) -> np.ndarray:
    """JPEG bytes -> (H, W, 3) uint8 in R,G,B order (see the module docstring)."""
    buf = _as_bytes_array(encoded, "rgb")
    rgb = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if rgb is None or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise DecodeError("rgb: not a decodable JPEG image")
    return rgb


def encode_depth(depth_m: np.ndarray, compression_x1000: int = JP2_COMPRESSION_X1000) -> np.ndarray:
    """(H, W) float metres -> 1-D uint8 JPEG2000 bytes of uint16 millimetres, as the robot does.

    Non-finite and negative depths become 0 (no reading); depths beyond 65.535 m saturate.
    """
    if depth_m.ndim != 2:
        raise ValueError(f"depth must be (H, W), got {depth_m.shape}")
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * MM_PER_M, nan=0.0, posinf=0.0, neginf=0.0)
    mm = np.clip(np.rint(mm), 0, np.iinfo(np.uint16).max).astype(np.uint16)
    ok, buf = cv2.imencode(".jp2", mm, [cv2.IMWRITE_JPEG2000_COMPRESSION_X1000, int(compression_x1000)])
    if not ok:
        raise ValueError("JPEG2000 encoding failed")
    return buf.reshape(-1)


def decode_depth(encoded: object) -> np.ndarray:
    """JPEG2000 bytes of uint16 millimetres -> (H, W) float32 metres (0 = no reading)."""
    buf = _as_bytes_array(encoded, "depth")
    mm = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if mm is None or mm.ndim != 2:
        raise DecodeError("depth: not a decodable single-channel JPEG2000 image")
    if mm.dtype != np.uint16:
        raise DecodeError(f"depth: expected uint16 millimetres, decoded {mm.dtype}")
    return (mm.astype(np.float32) / np.float32(MM_PER_M)).astype(np.float32)


def intrinsics_from_message(camera_K: object, image_shape: tuple[int, ...]) -> Intrinsics:
    """Intrinsics of the decoded image: ``camera_K`` with the size from the array's shape.

    Refuses a matrix whose principal point lies outside the central half of the image
    (real cameras are within a few percent of the centre): that is what a K of the
    unrotated (landscape) sensor paired with an upright image looks like.
    """
    K = np.asarray(camera_K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise DecodeError(f"camera_K: expected a finite 3x3 matrix, got shape {K.shape}")
    height_px, width_px = int(image_shape[0]), int(image_shape[1])
    intr = Intrinsics.from_matrix(K, width_px, height_px)
    if intr.fx <= 0 or intr.fy <= 0:
        raise DecodeError(f"camera_K: focal lengths must be positive, got fx={intr.fx} fy={intr.fy}")
    if abs(intr.cx - width_px / 2) > width_px / 4 or abs(intr.cy - height_px / 2) > height_px / 4:
        raise DecodeError(
            f"camera_K: principal point ({intr.cx:.1f}, {intr.cy:.1f}) is far from the centre of the "
            f"{width_px}x{height_px} image (K of the unrotated sensor?)"
        )
    return intr


def camera_pose_matrix(camera_pose: object) -> np.ndarray:
    T = np.asarray(camera_pose, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DecodeError(f"camera_pose: expected a finite 4x4 matrix, got shape {T.shape}")
    return T


def camera_height_m(T_world_camera: np.ndarray) -> float:
    """Optical centre above the floor (the map frame's z = 0)."""
    return float(T_world_camera[2, 3])


def camera_tilt_rad(T_world_camera: np.ndarray) -> float:
    """Pitch of the optical axis, positive looking down (``Observation.camera_tilt_rad``).

    The optical axis is the camera's z column; its world z component is -sin(tilt).
    """
    axis_z = float(np.clip(T_world_camera[2, 2], -1.0, 1.0))
    return math.asin(-axis_z)


def camera_yaw_rad(T_world_camera: np.ndarray) -> float:
    """Heading of the optical axis projected on the floor (CCW from the world's +x)."""
    return math.atan2(float(T_world_camera[1, 2]), float(T_world_camera[0, 2]))


def make_camera_pose(x_m: float, y_m: float, yaw_rad: float, height_m: float, tilt_rad: float) -> np.ndarray:
    """``T_world_camera`` (OpenCV axes) of a camera at (x, y, height) looking along ``yaw``,
    pitched down by ``tilt_rad`` -- what the fake robot publishes, and the inverse of
    ``camera_height_m``/``camera_tilt_rad``/``camera_yaw_rad``."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    forward = np.array([cy * ct, sy * ct, -st])  # optical axis (z)
    right = np.array([sy, -cy, 0.0])  # image x: to the right of the heading
    down = np.cross(forward, right)  # image y completes a right-handed frame
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = right, down, forward
    T[:3, 3] = (x_m, y_m, height_m)
    return T
