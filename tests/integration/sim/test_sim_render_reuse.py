"""The simulator step's render without its waste (issue 32) gives the very same frames.

In a generated 8-room home, a few robot-camera poses and a pitched goal-style camera are
rendered by ``SimWorld.render_view`` and by the render as it was before issue 32 (written out
below: a strided RGB copy, the depth formula with its temporaries, the instance-id image
through the look-up table): RGB, depth and segmentation must be equal bit for bit, also when
a camera comes back to a kept frame, and a goal mask from raw ids must equal the one from
the instance-id image for every instance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.types import Action, Pose2D
from sim.backend import SimBackend
from sim.camera import SIM_CAMERA, CameraSpec
from sim.episodes import scene_seed_for
from sim.render_reference import render_plain
from sim.scene_gen import generate_home
from sim.world import SimWorld


def _render_before(
    world: SimWorld, eye_xyz: tuple[float, float, float], yaw_rad: float, pitch_rad: float, camera: CameraSpec
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The render of ``SimWorld.render_view`` before issue 32: (rgb, depth_m, instance_ids), the
    ids through the look-up table as the render did then."""
    rgb, depth_m, seg = render_plain(world, eye_xyz, yaw_rad, pitch_rad, camera)
    raw = np.asarray(seg, np.int64)
    lut = world._seg_lut
    ids = lut[np.where((raw >= -1) & (raw < len(lut) - 1), raw, -1) + 1]
    return rgb, depth_m, ids


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit: same dtype, shape and bytes (a float compare would let -0.0 == 0.0 pass)."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module")
def world():
    w = SimWorld(generate_home(scene_seed_for("val", 0, 5)))  # 8 rooms
    yield w
    w.close()


def _views(world: SimWorld) -> list[tuple[tuple[float, float, float], float, float, CameraSpec]]:
    """Five robot-camera views, each from a free cell 1-3 m from an instance and facing it
    (most show some), and one pitched goal-style camera."""
    rng = np.random.default_rng(32)
    grid = world.navigable_grid(0.05)
    free_xy = grid.ij_to_xy(np.argwhere(grid.navigable))
    instances = world.home.instances
    views = []
    for k in range(6):
        cx, cy, _ = instances[(3 * k) % len(instances)].center_xyz_m()
        d = np.hypot(free_xy[:, 0] - cx, free_xy[:, 1] - cy)
        near = free_xy[(d > 1.0) & (d < 3.0)]
        x, y = near[rng.integers(len(near))] if len(near) else free_xy[rng.integers(len(free_xy))]
        yaw = math.atan2(cy - y, cx - x)
        if k < 5:
            views.append(((float(x), float(y), SIM_CAMERA.height_m), yaw, SIM_CAMERA.pitch_rad, SIM_CAMERA))
        else:
            cam = CameraSpec(256, 256, 75.0, 1.5, 0.4)
            views.append(((float(x), float(y), cam.height_m), yaw, cam.pitch_rad, cam))
    return views


def test_frames_equal_the_render_before_issue_32(world: SimWorld) -> None:
    views = _views(world)
    world._frames.clear()
    shown: set[int] = set()
    for again in (False, True):  # the second round comes back to kept frames
        reused = world.frames_reused
        for eye, yaw, pitch, cam in views:
            r = world.render_view(eye, yaw, pitch, cam)
            rgb, depth_m, ids = _render_before(world, eye, yaw, pitch, cam)
            assert _same(r.rgb, rgb) and r.rgb.flags.c_contiguous and r.rgb.flags.writeable
            assert _same(r.depth_m, depth_m) and r.depth_m.flags.writeable
            assert np.array_equal(r.instance_ids, ids)
            for tid in range(-1, len(world.home.objects)):
                assert _same(r.mask_of(tid), ids == tid)
            shown |= set(np.unique(ids[ids >= 0]).tolist())
        assert world.frames_reused - reused == (len(views) if again else 0)
    assert len(shown) >= 2  # the masks were checked on instances in view, not only on empty ones


def test_a_reused_frame_is_the_callers_own(world: SimWorld) -> None:
    eye, yaw, pitch, cam = _views(world)[0]
    a = world.render_view(eye, yaw, pitch, cam)
    a.rgb[:] = 0
    a.depth_m[:] = -1.0
    a.seg_raw[:] = 7
    b = world.render_view(eye, yaw, pitch, cam)
    rgb, depth_m, ids = _render_before(world, eye, yaw, pitch, cam)
    assert _same(b.rgb, rgb) and _same(b.depth_m, depth_m) and np.array_equal(b.instance_ids, ids)


def test_no_reuse_gives_the_same_frames() -> None:
    home = generate_home(scene_seed_for("val", 0, 5))
    kept, fresh = SimWorld(home), SimWorld(home, reuse_frames=0)
    try:
        for eye, yaw, pitch, cam in _views(kept) * 2:
            a, b = kept.render_view(eye, yaw, pitch, cam), fresh.render_view(eye, yaw, pitch, cam)
            assert _same(a.rgb, b.rgb) and _same(a.depth_m, b.depth_m) and _same(a.seg_raw, b.seg_raw)
        assert kept.frames_reused == 6 and fresh.frames_reused == 0
    finally:
        kept.close()
        fresh.close()


def test_a_run_that_turns_back_gets_the_same_observations(world: SimWorld) -> None:
    """Turning left then right comes back to the frame kept two steps earlier; the backend's
    observations and the oracle's goal mask equal the render before issue 32 at every step."""
    goal = world.home.instances[0].object_id
    grid = world.navigable_grid(0.05)
    x, y = grid.ij_to_xy(np.argwhere(grid.navigable)[0][None])[0]
    backend = SimBackend(world, np.zeros((8, 8, 3), np.uint8), Pose2D(float(x), float(y), 0.5), goal)
    reused = world.frames_reused
    obs = backend.reset()
    for action in (None, Action.TURN_LEFT, Action.TURN_RIGHT, Action.TURN_RIGHT, Action.TURN_LEFT, Action.STOP):
        if action is not None:
            backend.apply(action)
            obs = backend.observe()
        p = backend.pose_world
        rgb, depth_m, ids = _render_before(world, (p.x_m, p.y_m, SIM_CAMERA.height_m), p.yaw_rad, 0.0, SIM_CAMERA)
        assert _same(obs.rgb, rgb) and _same(obs.depth_m, depth_m)
        assert _same(backend.oracle.goal_mask(), ids == goal)
    assert world.frames_reused > reused
