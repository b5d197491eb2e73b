"""Depth buffer to metres, checked on a known plane and against the formula's inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.types import Pose2D
from sim.camera import SIM_CAMERA, CameraSpec, depth_buffer_to_metres
from sim.simple_homes import room_home
from sim.world import SimWorld


def test_depth_formula_inverts_the_opengl_buffer() -> None:
    near, far = 0.05, 30.0
    z = np.array([[0.05, 0.5, 1.0], [2.5, 10.0, 29.0]])
    # OpenGL window depth of eye-space distance z
    buf = (far / (far - near)) * (1.0 - near / z)
    assert np.allclose(depth_buffer_to_metres(buf, near, far), z, rtol=1e-5)


def test_background_has_no_depth() -> None:
    assert depth_buffer_to_metres(np.ones((2, 2)), 0.05, 30.0).tolist() == [[0.0, 0.0], [0.0, 0.0]]


@pytest.fixture(scope="module")
def room():
    world = SimWorld(room_home(6.0, 10.0))
    yield world
    world.close()


def test_depth_of_a_wall_facing_the_camera_is_its_distance(room: SimWorld) -> None:
    # Facing +x from x = 2: the wall's inner face is at x = 6 - 0.05 = 5.95.
    cam = CameraSpec(90, 160, 42.0, 1.31, 0.0)
    r = room.render(Pose2D(2.0, 5.0, 0.0), cam)
    assert r.rgb.shape == (160, 90, 3) and r.rgb.dtype == np.uint8
    assert r.depth_m.dtype == np.float32 and r.instance_ids.dtype == np.int32
    # Rows near the image centre see the wall (floor and ceiling are further out at the edges).
    centre = r.depth_m[60:100, :]
    assert np.allclose(centre, 3.95, atol=0.01), (centre.min(), centre.max())


def test_depth_is_along_the_optical_axis_not_the_ray(room: SimWorld) -> None:
    # Looking at the wall at 45 deg would give ray lengths varying across the image;
    # depth along the axis of a plane facing the camera stays constant across columns.
    cam = CameraSpec(160, 90, 80.0, 1.31, 0.0)
    r = room.render(Pose2D(2.0, 5.0, 0.0), cam)
    row = r.depth_m[45, :]
    assert np.ptp(row) < 0.02 and math.isclose(float(row.mean()), 3.95, abs_tol=0.01)


def test_sim_camera_matches_the_task() -> None:
    assert (SIM_CAMERA.width_px, SIM_CAMERA.height_px) == (360, 640)
    assert math.isclose(SIM_CAMERA.intrinsics.hfov_deg, 42.0)
    assert math.isclose(SIM_CAMERA.vfov_deg, 68.6, abs_tol=0.1)
    assert SIM_CAMERA.height_m == 1.31 and SIM_CAMERA.pitch_rad == 0.0
