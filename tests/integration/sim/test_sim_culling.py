"""Skipping rooms the camera cannot see must not change a single pixel.

Eight random views per home (half at the robot's camera, half pitched like a goal photo) in
two 8-room homes, where from any spot several rooms are out of sight: each view compares a
culled render with a full one, pixel for pixel."""

from __future__ import annotations

import math

import numpy as np

from agent.types import Pose2D
from sim.camera import SIM_CAMERA, CameraSpec
from sim.episodes import scene_seed_for
from sim.scene_gen import generate_home
from sim.world import SimWorld


def test_culled_renders_are_identical() -> None:
    rng = np.random.default_rng(0)
    for seed in (scene_seed_for("val", 0, 5), 4):  # two 8-room homes
        home = generate_home(seed)
        culled, full = SimWorld(home, cull=True), SimWorld(home, cull=False)
        try:
            grid = culled.navigable_grid(0.05)
            free = np.argwhere(grid.navigable)
            for k in range(8):
                x, y = grid.ij_to_xy(free[rng.integers(len(free))][None])[0]
                yaw = float(rng.uniform(-math.pi, math.pi))
                if k % 2 == 0:
                    a, b = culled.render(Pose2D(x, y, yaw), SIM_CAMERA), full.render(Pose2D(x, y, yaw), SIM_CAMERA)
                else:  # a pitched goal-style camera
                    cam = CameraSpec(256, 256, float(rng.uniform(60, 90)), 1.5, float(rng.uniform(0.2, 0.7)))
                    eye = (x, y, cam.height_m)
                    a, b = (
                        culled.render_view(eye, yaw, cam.pitch_rad, cam),
                        full.render_view(eye, yaw, cam.pitch_rad, cam),
                    )
                assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth_m, b.depth_m)
                assert np.array_equal(a.instance_ids, b.instance_ids)
        finally:
            culled.close()
            full.close()
