"""Encodings and camera geometry of the bridge's observation messages."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.types import SIM_INTRINSICS
from robot import encoding


def test_rgb_round_trip_keeps_r_g_b_order() -> None:
    rgb = np.zeros((64, 36, 3), np.uint8)
    rgb[:, :12] = (255, 0, 0)  # red band
    rgb[:, 12:24] = (0, 255, 0)
    rgb[:, 24:] = (0, 0, 255)
    out = encoding.decode_rgb(encoding.encode_rgb(rgb))
    assert out.shape == rgb.shape and out.dtype == np.uint8
    assert out[32, 4, 0] > 200 and out[32, 4, 2] < 50  # still red, not swapped to blue
    assert out[32, 30, 2] > 200 and out[32, 30, 0] < 50
    assert np.abs(out.astype(int) - rgb).mean() < 8


def test_depth_round_trip_millimetres_zero_and_far_values() -> None:
    rng = np.random.default_rng(0)
    depth = np.tile(np.linspace(0.3, 8.0, 36, dtype=np.float32), (64, 1))
    depth += rng.uniform(0, 0.001, depth.shape).astype(np.float32)
    depth[:5] = 0.0  # no reading
    depth[5, 5] = np.nan
    out = encoding.decode_depth(encoding.encode_depth(depth))
    assert out.dtype == np.float32 and out.shape == depth.shape
    assert np.all(out[:5] == 0) and out[5, 5] == 0
    valid = np.isfinite(depth) & (depth > 0)
    # Lossy JPEG2000 at the bridge's setting: a few millimetres; depth beyond 3.5 m is kept.
    assert np.max(np.abs(out[valid] - depth[valid])) < 0.02
    assert out[40, -1] > 7.9


def test_decoders_refuse_what_is_not_an_encoded_image() -> None:
    with pytest.raises(encoding.DecodeError):
        encoding.decode_rgb(np.zeros((4, 4), np.uint8))
    with pytest.raises(encoding.DecodeError):
        encoding.decode_depth(np.frombuffer(b"garbage!", np.uint8))
    with pytest.raises(encoding.DecodeError, match="JPEG2000|uint16"):
        encoding.decode_depth(encoding.encode_rgb(np.zeros((8, 8, 3), np.uint8)))


def test_intrinsics_take_the_size_from_the_array_not_the_message() -> None:
    K = SIM_INTRINSICS.K.astype(np.float32)
    intr = encoding.intrinsics_from_message(K, (640, 360, 3))
    assert (intr.width_px, intr.height_px) == (360, 640)
    assert intr.fx == pytest.approx(SIM_INTRINSICS.fx, rel=1e-6)
    assert intr.hfov_deg == pytest.approx(42.0, abs=1e-3)


def test_a_landscape_K_with_a_portrait_image_is_refused() -> None:
    K = np.array([[600.0, 0, 320.0], [0, 600.0, 180.0], [0, 0, 1]])  # K of the unrotated 640x360 sensor
    with pytest.raises(encoding.DecodeError, match="principal point"):
        encoding.intrinsics_from_message(K, (640, 360))
    with pytest.raises(encoding.DecodeError, match="3x3"):
        encoding.intrinsics_from_message(np.eye(4), (640, 360))


angles = st.floats(-math.pi + 1e-6, math.pi - 1e-6)
coords = st.floats(-50, 50)


@settings(max_examples=200, deadline=None)
@given(coords, coords, angles, st.floats(0.2, 2.0), st.floats(-1.2, 1.2))
def test_camera_pose_height_tilt_and_yaw_round_trip(x, y, yaw, height, tilt) -> None:
    T = encoding.make_camera_pose(x, y, yaw, height, tilt)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    assert encoding.camera_height_m(T) == pytest.approx(height)
    assert encoding.camera_tilt_rad(T) == pytest.approx(tilt, abs=1e-9)
    assert math.cos(encoding.camera_yaw_rad(T) - yaw) == pytest.approx(1.0, abs=1e-9)
    # OpenCV axes: image x points right of the heading, image y has a downward component
    assert R[:, 0] @ np.array([-math.sin(yaw), math.cos(yaw), 0.0]) == pytest.approx(-1.0)
    assert R[2, 1] < 0


def test_a_level_camera_looks_along_the_heading() -> None:
    T = encoding.make_camera_pose(1.0, 2.0, math.pi / 2, 1.31, 0.0)
    assert np.allclose(T[:3, 2], [0, 1, 0], atol=1e-12)  # optical axis = heading (+y)
    assert np.allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    assert encoding.camera_tilt_rad(T) == pytest.approx(0.0)
