"""What the fake robot drives around in: a ``FakeWorld`` renders the head camera and
answers collision queries. ``BoxWorld`` is a tiny analytic room for protocol tests (no
PyBullet); ``sim_world(...)`` in ``robot.fake_sim`` wraps the project's simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from agent.types import CAMERA_HEIGHT_M, ROBOT_RADIUS_M, SIM_INTRINSICS, Intrinsics, Pose2D
from robot.encoding import make_camera_pose


class FakeWorld(Protocol):
    """A world for the fake robot, in its own (map) frame.

    intrinsics: of the portrait head camera (360 x 640 like the Stretch's rotated D435).
    camera_height_m: optical centre above the floor.
    start_world: where the robot stands when the server starts.
    render(pose_world, tilt_rad) -> (rgb (H, W, 3) uint8 R,G,B, depth_m (H, W) float32
        metres along the optical axis, 0 = no reading), camera pitched down by tilt_rad.
    collides(x_m, y_m): the robot's footprint at that position hits something.
    """

    intrinsics: Intrinsics
    camera_height_m: float
    start_world: Pose2D

    def render(self, pose_world: Pose2D, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]: ...

    def collides(self, x_m: float, y_m: float) -> bool: ...

    def close(self) -> None: ...


@dataclass
class BoxWorld:
    """An empty rectangular room [x_min, x_max] x [y_min, y_max] with walls ``wall_height_m``
    high, each wall and the floor painted with its own checker pattern (so images are not
    blank and a turn visibly changes them). Optional square pillars block motion and sight.

    Rendering is a vectorised ray cast; depth is the camera-z of the first hit.
    """

    x_min: float = -2.0
    x_max: float = 3.0
    y_min: float = -2.0
    y_max: float = 2.0
    wall_height_m: float = 2.4
    pillars: tuple[tuple[float, float, float], ...] = ()  # (x, y, half side) in metres
    start_world: Pose2D = Pose2D(0.0, 0.0, 0.0)
    intrinsics: Intrinsics = SIM_INTRINSICS
    camera_height_m: float = CAMERA_HEIGHT_M
    robot_radius_m: float = ROBOT_RADIUS_M
    max_depth_m: float = 10.0

    def collides(self, x_m: float, y_m: float) -> bool:
        r = self.robot_radius_m
        if not (self.x_min + r <= x_m <= self.x_max - r and self.y_min + r <= y_m <= self.y_max - r):
            return True
        for px, py, half in self.pillars:
            # distance from the robot centre to the square, compared with the radius
            dx = max(abs(x_m - px) - half, 0.0)
            dy = max(abs(y_m - py) - half, 0.0)
            if math.hypot(dx, dy) < r:
                return True
        return False

    def render(self, pose_world: Pose2D, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]:
        intr = self.intrinsics
        T = make_camera_pose(pose_world.x_m, pose_world.y_m, pose_world.yaw_rad, self.camera_height_m, tilt_rad)
        u, v = np.meshgrid(np.arange(intr.width_px) + 0.5, np.arange(intr.height_px) + 0.5)
        rays_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
        d = rays_cam @ T[:3, :3].T  # world direction per pixel; camera-z component is 1
        o = T[:3, 3]
        t_best = np.full(u.shape, np.inf)
        colour = np.zeros(u.shape + (3,), np.float64)

        def consider(t: np.ndarray, valid: np.ndarray, paint) -> None:
            nonlocal t_best
            hit = valid & (t > 1e-6) & (t < t_best)
            if not np.any(hit):
                return
            p = o + t[..., None] * d
            colour[hit] = paint(p[hit])
            t_best = np.where(hit, t, t_best)

        def checker(a: np.ndarray, b: np.ndarray, size: float, c0, c1) -> np.ndarray:
            on = (np.floor(a / size) + np.floor(b / size)) % 2 == 0
            return np.where(on[:, None], np.array(c0, float), np.array(c1, float))

        with np.errstate(divide="ignore", invalid="ignore"):
            # floor z = 0
            t = -o[2] / d[..., 2]
            consider(t, d[..., 2] < 0, lambda p: checker(p[:, 0], p[:, 1], 0.5, (200, 190, 170), (120, 100, 80)))
            walls = (
                (0, self.x_min, (220, 60, 60), 1),
                (0, self.x_max, (60, 200, 60), 1),
                (1, self.y_min, (60, 60, 220), 0),
                (1, self.y_max, (220, 200, 60), 0),
            )
            for axis, value, tint, along in walls:
                t = (value - o[axis]) / d[..., axis]
                p_z = o[2] + t * d[..., 2]
                valid = (p_z >= 0) & (p_z <= self.wall_height_m)
                consider(
                    t, valid, lambda p, tint=tint, along=along: checker(p[:, along], p[:, 2], 0.3, tint, (30, 30, 30))
                )
            for px, py, half in self.pillars:
                for axis, value in ((0, px - half), (0, px + half), (1, py - half), (1, py + half)):
                    t = (value - o[axis]) / d[..., axis]
                    p = o + t[..., None] * d
                    other = 1 - axis
                    centre = py if other == 1 else px
                    valid = (
                        (np.abs(p[..., other] - centre) <= half) & (p[..., 2] >= 0) & (p[..., 2] <= self.wall_height_m)
                    )
                    consider(
                        t,
                        valid,
                        lambda q, other=other: checker(q[:, other], q[:, 2], 0.1, (250, 250, 250), (10, 10, 10)),
                    )

        depth = np.where(np.isfinite(t_best) & (t_best <= self.max_depth_m), t_best, 0.0).astype(np.float32)
        rgb = np.clip(colour, 0, 255).astype(np.uint8)
        return rgb, depth

    def close(self) -> None:
        pass
