"""The realism profiles (sim/realism.py, docs/realism.md): each component does what it says,
the same seed gives the same noise, and a run under the profile keeps the truth for scoring."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.types import Action, Pose2D
from sim.backend import SimBackend
from sim.camera import CameraSpec
from sim.realism import (
    PROFILES,
    ActuationModel,
    DepthModel,
    GoalPhotoModel,
    PoseModel,
    Realism,
    RealismProfile,
    RealismRun,
    depth_edges,
    get_profile,
    noisy_depth,
    phone_photo,
    stereo_occlusion,
)
from sim.simple_homes import box_object, room_home
from sim.world import SimWorld

GREY = np.full((240, 200, 3), 128, np.uint8)
SMALL_CAMERA = CameraSpec(90, 160, 42.0)  # the noise is per pixel: a small frame renders fast
FX = 469.0  # the simulated head camera's focal length (360 px, 42 deg)


def _plane(z: float, shape: tuple[int, int] = (240, 200)) -> np.ndarray:
    return np.full(shape, z, np.float32)


@pytest.fixture(scope="module")
def world():
    w = SimWorld(room_home(6.0, 6.0, [box_object(0, "couch", (4.5, 4.5), (1.0, 1.0, 0.8))]))
    yield w
    w.close()


# --- depth ---------------------------------------------------------------------------------


def test_depth_error_grows_with_range_squared_as_intel_formula_says() -> None:
    m = DepthModel(edge_invalid_prob=0.0, flying_prob=0.0, dark_invalid_prob=0.0, holes_per_frame=0.0)
    rng = np.random.default_rng(1)
    sds = {}
    for z in (1.0, 2.0, 3.0):
        errs = np.concatenate([(noisy_depth(_plane(z), GREY, FX, m, rng) - z).ravel() for _ in range(4)])
        sds[z] = float(errs.std())
        expected = z**2 * m.subpixel / (m.native_focal_px * m.baseline_m)
        # the RMS the model is built on (Intel's formula), within the sampling and quantisation error
        assert sds[z] == pytest.approx(expected, rel=0.12), (z, sds[z], expected)
        assert abs(float(errs.mean())) < 0.2 * expected  # unbiased
    assert sds[3.0] / sds[1.0] == pytest.approx(9.0, rel=0.15)
    assert sds[2.0] / (2.0) < 0.02  # Intel's specification: under 2% at 2 m


def test_depth_is_quantised_and_limited_to_the_sensors_range() -> None:
    m = DepthModel()
    rng = np.random.default_rng(2)
    z = np.concatenate([_plane(0.1, (60, 200)), _plane(1.5, (60, 200)), _plane(4.0, (60, 200)), _plane(8.0, (60, 200))])
    out = noisy_depth(z, GREY, FX, m, rng)
    assert not out[:60].any(), "nearer than the minimum range: no reading"
    assert not out[180:].any(), "beyond the maximum range: no reading"
    valid = out[out > 0]
    assert valid.min() >= m.min_range_m and valid.max() <= m.max_range_m
    mm = valid / m.depth_unit_m
    assert np.allclose(mm, np.round(mm), atol=1e-2), "depth in the driver's millimetre units"
    assert (out[60:120] > 0).mean() > 0.9  # mid-range mostly valid (holes and nothing else)


def test_a_near_edge_hides_a_band_as_wide_as_the_disparity_jump() -> None:
    z = _plane(3.0, (200, 100))
    z[120:, :] = 1.0  # a near surface below row 120 (the baseline runs along the rows)
    hidden = stereo_occlusion(z, FX, 0.05, axis=0)
    band = FX * 0.05 * (1 / 1.0 - 1 / 3.0)  # disparity jump in pixels
    rows = np.nonzero(hidden[:, 50])[0]
    assert len(rows) == pytest.approx(band, abs=1.5)
    assert rows.max() == 119 and rows.min() >= 120 - band - 1  # the far side, next to the edge
    assert not hidden[120:].any()  # the near surface itself is seen


def test_edges_lose_depth_or_fly_and_dark_surfaces_drop_out() -> None:
    z = _plane(2.0, (200, 200))
    z[:, 100:] = 1.2
    assert depth_edges(z, 0.1)[:, 99:101].all() and not depth_edges(z, 0.1)[:, :98].any()
    m = DepthModel(holes_per_frame=0.0, dark_invalid_prob=0.0)
    out = noisy_depth(z, GREY[:200], FX, dataclasses.replace(m, baseline_axis=0), np.random.default_rng(3))
    edge_px = out[:, 99:101]
    # about edge_invalid_prob of the edge pixels have no reading; some read between the surfaces
    assert (edge_px == 0).mean() == pytest.approx(m.edge_invalid_prob, abs=0.08)
    between = (edge_px > 1.3) & (edge_px < 1.9)
    assert between.mean() > 0.1
    dark = GREY.copy()
    dark[:, :100] = 10
    m2 = DepthModel(holes_per_frame=0.0, edge_invalid_prob=0.0, flying_prob=0.0)
    out2 = noisy_depth(_plane(2.0, (240, 200)), dark, FX, m2, np.random.default_rng(4))
    assert (out2[:, :100] == 0).mean() == pytest.approx(m2.dark_invalid_prob, abs=0.03)
    assert (out2[:, 100:] == 0).mean() < 0.01


# --- motion and pose -----------------------------------------------------------------------


def test_moves_scatter_as_the_published_model_says() -> None:
    run = RealismRun(get_profile("stretch", ["actuation"]), seed=0, key="moves")
    a = ActuationModel()
    fwd = np.array([run.actual_motion(Action.MOVE_FORWARD) for _ in range(3000)])
    made = fwd[~fwd[:, 3].astype(bool)]  # moves without a slip
    assert made[:, 0].mean() == pytest.approx(0.25 + a.forward_mean_m, abs=0.004)
    assert made[:, 0].std() == pytest.approx(a.forward_sd_m, rel=0.1)
    assert made[:, 1].std() == pytest.approx(a.lateral_sd_m, rel=0.1)
    assert fwd[:, 3].mean() == pytest.approx(a.slip_prob, abs=0.01)
    turns = np.degrees([run.actual_motion(Action.TURN_RIGHT)[2] for _ in range(2000)])
    assert turns.mean() == pytest.approx(-(30 + a.turn_mean_deg), abs=0.3)
    assert turns.std() == pytest.approx(a.turn_sd_deg, rel=0.1)


def _drive(profile: RealismProfile, seed: int, steps: int) -> list[float]:
    """Position error of the estimate after each forward step of a straight drive."""
    run = RealismRun(profile, seed, "drive")
    pose = Pose2D()
    run.start_estimate(pose)
    errs = []
    for k in range(1, steps + 1):
        after = pose.compose(Pose2D(0.25, 0.0, 0.0))
        run.update_estimate(Action.MOVE_FORWARD, pose, after, False, Pose2D(0.25, 0.0, 0.0), k)
        pose = after
        assert run.estimate_world is not None
        errs.append(math.hypot(run.estimate_world.x_m - pose.x_m, run.estimate_world.y_m - pose.y_m))
    return errs


def test_odometry_drift_grows_with_distance_and_the_localiser_bounds_it() -> None:
    odometry_only = RealismProfile("odom", pose=PoseModel(localise_every=0))
    drift = np.array([_drive(odometry_only, s, 160) for s in range(40)])  # 40 m each
    near, far = drift[:, 15].mean(), drift[:, 159].mean()  # after 4 m and after 40 m
    assert far > 4 * near > 0
    corrected = np.array([_drive(PROFILES["stretch"], s, 160) for s in range(40)])
    p = PoseModel()
    assert corrected[:, 100:].mean() < 3 * p.localise_xy_sd_m + 0.03
    assert corrected.max() < 0.5
    # a correction is a jump: just after one the error is the localiser's residual
    assert corrected[:, p.localise_every - 1 :: p.localise_every].mean() == pytest.approx(
        p.localise_xy_sd_m * math.sqrt(math.pi / 2), rel=0.25
    )


def test_a_slip_is_counted_by_the_odometry_as_the_commanded_move() -> None:
    run = RealismRun(RealismProfile("odom", pose=PoseModel(localise_every=0, odom_dist_sd_frac=0.0)), 0, "slip")
    run.start_estimate(Pose2D())
    run.update_estimate(Action.MOVE_FORWARD, Pose2D(), Pose2D(0.05, 0, 0), True, Pose2D(0.25, 0, 0), 1)
    assert run.estimate_world is not None and run.estimate_world.x_m == pytest.approx(0.25)


# --- goal photo ----------------------------------------------------------------------------


def test_goal_photo_is_a_4_by_3_processed_crop() -> None:
    view = (np.random.default_rng(5).random((512, 512, 3)) * 255).astype(np.uint8)
    shapes = set()
    for s in range(12):
        photo = phone_photo(view, GoalPhotoModel(), np.random.default_rng(s))
        h, w = photo.shape[:2]
        assert max(h, w) == 512 and min(h, w) == 384
        shapes.add((h, w))
        assert photo.dtype == np.uint8 and not np.array_equal(photo, view[:h, :w])
    assert shapes == {(512, 384), (384, 512)}  # portrait and landscape both occur
    assert np.array_equal(
        phone_photo(view, GoalPhotoModel(), np.random.default_rng(7)),
        phone_photo(view, GoalPhotoModel(), np.random.default_rng(7)),
    )


# --- profiles, seeds, a run ----------------------------------------------------------------


def test_profiles_components_and_unknown_names() -> None:
    assert PROFILES["clean"].clean and Realism().start("x") is None
    assert PROFILES["stretch"].components == ("depth", "rgb", "actuation", "pose", "goal_photo")
    only = get_profile("stretch", ["depth", "pose"])
    assert only.components == ("depth", "pose") and only.name == "stretch[depth+pose]"
    with pytest.raises(ValueError, match="unknown realism component"):
        get_profile("stretch", ["wheels"])
    with pytest.raises(ValueError, match="unknown realism profile"):
        get_profile("mars")


def _scripted_run(world: SimWorld, realism: Realism | None, key: str = "ep") -> tuple[list, SimBackend]:
    b = SimBackend(world, GREY, Pose2D(1.5, 1.5, 0.3), camera=SMALL_CAMERA, realism=realism, run_key=key)
    obs = [b.reset()]
    for a in [Action.MOVE_FORWARD] * 5 + [Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_RIGHT] * 2:
        b.apply(a)
        obs.append(b.observe())
    return obs, b


def test_same_seed_same_noise_and_each_component_draws_alone(world: SimWorld) -> None:
    stretch = Realism(PROFILES["stretch"], seed=3)
    a, ba = _scripted_run(world, stretch)
    b, bb = _scripted_run(world, stretch)
    assert ba.trajectory_world == bb.trajectory_world
    for x, y in zip(a, b, strict=True):
        assert x.pose == y.pose and np.array_equal(x.rgb, y.rgb) and np.array_equal(x.depth_m, y.depth_m)
    c, bc = _scripted_run(world, Realism(PROFILES["stretch"], seed=4))
    assert bc.trajectory_world != ba.trajectory_world and not np.array_equal(c[3].depth_m, a[3].depth_m)
    # the motion without the sensors' noise: the same trajectory as with it (separate streams)
    d, bd = _scripted_run(world, Realism(get_profile("stretch", ["actuation", "pose"]), seed=3))
    assert bd.trajectory_world == ba.trajectory_world
    assert [o.pose for o in d] == [o.pose for o in a]


def test_a_run_under_the_profile_keeps_the_truth_for_scoring(world: SimWorld) -> None:
    obs, b = _scripted_run(world, Realism(PROFILES["stretch"], seed=0))
    assert obs[0].pose == Pose2D()  # the Backend contract: the start is (0, 0, 0)
    truth = [p.relative_to(b.start_pose_world) for p in b.trajectory_world]
    believed = [o.pose for o in obs]
    assert truth[-1] != believed[-1]  # the agent's pose is an estimate
    assert b.estimate_trajectory_world[-1].relative_to(b.start_pose_world) == believed[-1]
    gaps = [math.hypot(t.x_m - e.x_m, t.y_m - e.y_m) for t, e in zip(truth, believed, strict=True)]
    assert 0 < max(gaps) < 0.5
    # moves no longer land on the 0.25 m / 30 deg lattice, and the path length is the true one
    steps = [math.hypot(q.x_m - p.x_m, q.y_m - p.y_m) for p, q in zip(b.trajectory_world, b.trajectory_world[1:])]
    assert any(0 < s and abs(s - 0.25) > 0.005 for s in steps)
    assert b.path_length_m == pytest.approx(sum(steps))
    assert b.goal_image.shape != GREY.shape or not np.array_equal(b.goal_image, GREY)
    assert b.goal_image_rendered is not b.goal_image
    # the sensors: noisy depth with holes, colour changed
    clean_obs, clean_b = _scripted_run(world, None)
    assert (obs[0].depth_m == 0).any() and not (clean_obs[0].depth_m == 0).any()
    assert not np.array_equal(obs[0].rgb, clean_obs[0].rgb)
    for o, p in zip(clean_obs, clean_b.trajectory_world, strict=True):  # clean: the agent's pose is the truth
        t = p.relative_to(clean_b.start_pose_world)
        assert o.pose.x_m == pytest.approx(t.x_m, abs=1e-9) and o.pose.y_m == pytest.approx(t.y_m, abs=1e-9)
