import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.projection import lift_pixels, project_points
from agent.types import Intrinsics, Pose2D

INTR = Intrinsics.from_hfov(360, 640, 42.0)


def test_centre_pixel_lands_straight_ahead():
    pose = Pose2D(1.0, 2.0, math.pi / 2)  # facing +y
    cloud = lift_pixels(np.array([180.0]), np.array([320.0]), np.array([3.0]), INTR, pose, 1.31)
    np.testing.assert_allclose(cloud.xyz_run[0], [1.0, 5.0, 1.31], atol=1e-5)
    np.testing.assert_allclose(cloud.xy_base[0], [3.0, 0.0], atol=1e-6)


def test_known_floor_point_with_tilt():
    # camera 1.0 m high looking 45 deg down: the centre pixel hits the floor 1 m ahead at depth sqrt(2)
    pose = Pose2D(0.0, 0.0, 0.0)
    cloud = lift_pixels(np.array([180.0]), np.array([320.0]), np.array([math.sqrt(2)]), INTR, pose, 1.0, math.pi / 4)
    np.testing.assert_allclose(cloud.xyz_run[0], [1.0, 0.0, 0.0], atol=1e-5)


def test_left_pixel_is_to_the_left():
    cloud = lift_pixels(np.array([0.0]), np.array([320.0]), np.array([2.0]), INTR, Pose2D(), 1.31)
    assert cloud.xyz_run[0, 1] > 0.5  # +y is left


@settings(max_examples=50, deadline=None)
@given(
    u=st.floats(0, 359),
    v=st.floats(0, 639),
    z=st.floats(0.2, 20.0),
    x=st.floats(-10, 10),
    y=st.floats(-10, 10),
    yaw=st.floats(-math.pi, math.pi),
    tilt=st.floats(-0.6, 0.6),
)
def test_project_inverts_lift(u, v, z, x, y, yaw, tilt):
    pose = Pose2D(x, y, yaw)
    cloud = lift_pixels(np.array([u]), np.array([v]), np.array([z]), INTR, pose, 1.31, tilt)
    uv, depth = project_points(cloud.xyz_run, INTR, pose, 1.31, tilt)
    np.testing.assert_allclose(uv[0], [u, v], atol=2e-2 * max(1.0, z))
    np.testing.assert_allclose(depth[0], z, rtol=1e-4, atol=1e-4)
