"""Pictures drawn from agent records."""

from __future__ import annotations

import numpy as np

from agent.types import MapSnapshot, Pose2D
from console.pictures import GOAL_RGB, OBSTACLE_RGB, depth_rgb, match_picture, render_map, video_frame


def _snap() -> MapSnapshot:
    shape = (20, 30)  # 1.0 m (y) x 1.5 m (x) at 5 cm
    z = np.zeros(shape, bool)
    explored = np.ones(shape, bool)
    obstacle = z.copy()
    obstacle[:, 29] = True  # a wall along x = origin + 1.45 m
    goal = z.copy()
    goal[18, 2] = True  # a goal cell near the top-left (high y, low x)
    return MapSnapshot(0.05, (0.0, 0.0), obstacle, explored, z, z, goal, z)


def test_map_orientation_x_right_y_up() -> None:
    img, view = render_map(_snap(), pose=Pose2D(0.5, 0.5, 0.0), size_px=200)
    assert img.shape == (200, 200, 3) and img.dtype == np.uint8
    u, v = np.round(view.to_px(np.array([[1.475, 0.5]]))[0]).astype(int)
    assert tuple(img[v, u]) == OBSTACLE_RGB
    u, v = np.round(view.to_px(np.array([[0.125, 0.925]]))[0]).astype(int)
    assert tuple(img[v, u]) == GOAL_RGB
    assert v < 100  # high y is near the top of the picture


def test_map_without_snapshot_draws_the_trajectory() -> None:
    img, _ = render_map(None, trajectory_xy_m=np.array([[0, 0], [1, 0], [1, 1]]), pose=Pose2D(1, 1, 1.0), size_px=120)
    assert img.shape == (120, 120, 3)


def test_depth_and_match_and_frame_pictures() -> None:
    depth = np.linspace(0, 6, 64 * 36, dtype=np.float32).reshape(64, 36)
    d = depth_rgb(depth)
    assert d.shape == (64, 36, 3) and (d[0, 0] == 0).all()  # depth 0 is invalid: black
    goal = np.zeros((100, 100, 3), np.uint8)
    obs = np.zeros((640, 360, 3), np.uint8)
    m = match_picture(goal, obs, np.array([[10, 10]]), np.array([[100, 300]]), height_px=160)
    assert m.shape[0] == 160 and m.shape[1] == 160 + 90
    f = video_frame(obs, np.zeros((50, 50, 3), np.uint8), "step 1", height_px=120)
    assert f.shape[0] == 120 + 22
