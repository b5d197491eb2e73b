"""Depth buffer to metres, checked on a known plane and against the formula's inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.types import Pose2D
from sim.camera import SIM_CAMERA, CameraSpec, depth_buffer_to_metres
from sim.simple_homes import box_object, room_home
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


def test_intrinsics_project_world_points_onto_their_pixels() -> None:
    # A 0.2 m wide post 3 m ahead and 0.4 m to the left of a camera facing +x at (1, 5).
    post = box_object(0, "chair", (4.0, 5.4), (0.2, 0.2, 2.4))
    world = SimWorld(room_home(6.0, 10.0, [post]))
    try:
        k = SIM_CAMERA.intrinsics
        r = world.render(Pose2D(1.0, 5.0, 0.0), SIM_CAMERA)
        cols = np.flatnonzero((r.instance_ids == 0).any(axis=0))
        # front face at x = 3.9 (Z = 2.9 m), back face at x = 4.1; sides at y = 5.5 / 5.3 (X = -0.5 / -0.3).
        # Seen from the right of it: the leftmost pixel is the front-left edge, the rightmost the back-right one.
        z = 2.9
        u_left, u_right = k.cx + k.fx * (-0.5) / z, k.cx + k.fx * (-0.3) / 3.1
        assert abs(cols.min() - u_left) <= 1.0 and abs(cols.max() + 1 - u_right) <= 1.0
        # and a pixel's depth back-projects onto the post's front face
        v = int(k.cy)
        u = int(cols.mean())
        assert r.depth_m[v, u] == pytest.approx(z, abs=0.01)
        # the optical centre row sits at the camera height: the post's top edge (2.4 m) projects to
        top = k.cy - k.fy * (2.4 - 1.31) / z
        rows = np.flatnonzero(r.instance_ids[:, u] == 0)
        assert abs(rows.min() - top) <= 1.0
    finally:
        world.close()
