"""The fake robot's world from the project's simulator (``sim.world.SimWorld``).

The fake robot's map frame is the home's world frame; the head camera is the
simulator's Stretch camera (portrait 360 x 640, 42 deg HFOV, 1.31 m), pitched by the
commanded head tilt. Only the fake robot's observation thread renders, so the PyBullet
client is never used from two threads at once; collision queries use the simulator's
footprint index (no PyBullet call).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np

from agent.types import Intrinsics, Pose2D

log = logging.getLogger(__name__)


class SimFakeWorld:
    """``robot.fake_world.FakeWorld`` backed by a PyBullet home."""

    def __init__(self, world, start_world: Pose2D, viewpoints_xy_m: np.ndarray | None = None) -> None:
        """viewpoints_xy_m: (N, 2) world xy of the goal viewpoints when an episode is known
        (for reporting how a rehearsal ended), else None."""
        from sim.camera import SIM_CAMERA

        self.sim = world
        self.viewpoints_xy_m = viewpoints_xy_m
        self.goal_image_path: Path | None = None
        self.camera = SIM_CAMERA
        self.intrinsics: Intrinsics = SIM_CAMERA.intrinsics
        self.camera_height_m: float = SIM_CAMERA.height_m
        if world.collides(start_world.x_m, start_world.y_m):
            raise ValueError(f"start {start_world} collides with the home")
        self.start_world = start_world

    @classmethod
    def from_seed(
        cls, scene_seed: int, start_world: Pose2D | None = None, n_rooms: int | None = None, rng_seed: int = 0
    ) -> SimFakeWorld:
        """A generated home (``n_rooms`` None: the generator's choice, as ``SimWorld.from_seed``;
        the console's simulator homes use 3); without a start, a random navigable cell well
        away from walls."""
        from sim.scene_gen import generate_home
        from sim.world import SimWorld

        world = SimWorld(generate_home(scene_seed, n_rooms=n_rooms))
        try:
            if start_world is None:
                start_world = random_start(world, np.random.default_rng(rng_seed))
            return cls(world, start_world)
        except BaseException:
            world.close()
            raise

    @classmethod
    def from_episode(cls, episodes_dir: str | Path, episode_id: str) -> SimFakeWorld:
        """The home and start pose of one episode of an episode set."""
        from sim.episodes import load_episode_set
        from sim.world import SimWorld

        episodes = load_episode_set(Path(episodes_dir))
        try:
            episode = episodes.by_id(episode_id)
        except KeyError as exc:
            raise ValueError(str(exc)) from None
        world = SimWorld.from_seed(episode.scene_seed)
        try:
            fake_world = cls(world, episode.start_pose_world, episode.viewpoints_array())
        except BaseException:
            world.close()
            raise
        fake_world.goal_image_path = episodes.goal_image_path(episode)
        return fake_world

    def distance_to_goal_m(self, pose_world: Pose2D) -> float | None:
        """Distance from ``pose_world`` to the nearest goal viewpoint (None without an episode)."""
        if self.viewpoints_xy_m is None or len(self.viewpoints_xy_m) == 0:
            return None
        vp = np.asarray(self.viewpoints_xy_m, dtype=np.float64)
        return float(np.min(np.hypot(vp[:, 0] - pose_world.x_m, vp[:, 1] - pose_world.y_m)))

    def render(self, pose_world: Pose2D, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]:
        camera = dataclasses.replace(self.camera, pitch_rad=float(tilt_rad))
        frame = self.sim.render(pose_world, camera)
        return frame.rgb, frame.depth_m

    def collides(self, x_m: float, y_m: float) -> bool:
        return bool(self.sim.collides(x_m, y_m))

    def close(self) -> None:
        self.sim.close()


def random_start(world, rng: np.random.Generator, clearance_cells: int = 4) -> Pose2D:
    """A navigable cell whose neighbourhood (``clearance_cells`` at 5 cm) is navigable too."""
    from scipy.ndimage import binary_erosion

    grid = world.navigable_grid(0.05)
    free = binary_erosion(grid.navigable, iterations=clearance_cells)
    ij = np.argwhere(free if free.any() else grid.navigable)
    if len(ij) == 0:
        raise ValueError("the home has no navigable cell")
    x, y = grid.ij_to_xy(ij[rng.integers(len(ij))][None])[0]
    return Pose2D(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
