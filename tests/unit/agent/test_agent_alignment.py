"""Frame-to-map alignment (agent.alignment): a frame given a heading and position error is fused
where it fits the map; a frame at its exact pose is fused where it was taken."""

import dataclasses
import math

import numpy as np
import pytest

from agent.alignment import Alignment, AlignmentConfig, agrees
from agent.mapping import GridMap, MappingConfig
from agent.policy import ModIINAgent
from agent.types import Intrinsics, Pose2D, wrap_angle
from tests.helpers.agent_runs import oracle_config
from tests.helpers.agent_scenes import observation, room_walls

SMALL = Intrinsics.from_hfov(180, 320, 42.0)  # the sim camera's shape at half size

# a 7 x 5 m room with furniture along its walls (so that a shift along a wall is seen too); the
# surfaces lie off the 5 cm cell boundaries, as almost all do in a home
BOXES = room_walls(-2.013, -1.988, 5.021, 3.017) + [
    (3.607, -1.9, 4.912, -1.193, 0.8),
    (-1.9, 1.812, -0.887, 2.9, 1.2),
    (1.993, 2.408, 2.611, 2.9, 0.5),
    (-1.9, -1.9, -1.283, -0.991, 0.9),
]
CFG = MappingConfig(depth_stride_px=1)
ALIGN = AlignmentConfig()


def looked_around(pose: Pose2D = Pose2D()) -> GridMap:
    grid = GridMap(CFG)
    for k in range(12):
        grid.update(observation(BOXES, Pose2D(pose.x_m, pose.y_m, pose.yaw_rad + k * math.radians(30))))
    return grid


def estimate_off(true: Pose2D, yaw_deg: float, dx: float, dy: float) -> Pose2D:
    return Pose2D(true.x_m + dx, true.y_m + dy, true.yaw_rad + math.radians(yaw_deg))


@pytest.mark.parametrize(
    ("true", "yaw_deg", "dx", "dy"),
    [
        (Pose2D(1.0, 0.5, math.radians(20)), 2.0, 0.025, -0.025),
        (Pose2D(2.0, 0.0, math.radians(-100)), -2.5, 0.0, 0.05),
        (Pose2D(0.5, 1.0, math.radians(170)), 1.5, -0.05, 0.0),
    ],
)
def test_a_frame_with_a_pose_error_is_aligned_to_the_map(true, yaw_deg, dx, dy):
    grid = looked_around()
    obs = dataclasses.replace(observation(BOXES, true), pose=estimate_off(true, yaw_deg, dx, dy))
    got = grid.align(grid.lift(obs), ALIGN)
    assert got.corrected
    assert got.score_m < got.estimate_score_m - ALIGN.min_gain_m
    assert abs(math.degrees(got.pose.yaw_rad - true.yaw_rad)) <= 0.5  # from 1.5-2.5 deg
    assert got.pose.distance_to(true) <= 0.03  # from 3.5-5 cm


def phantom_cells(grid: GridMap, truth: GridMap) -> int:
    """Obstacle cells of ``grid`` farther than a cell from any of ``truth``'s."""
    t = np.zeros(grid.shape, bool)
    ij = grid.xy_to_ij(truth.ij_to_xy(np.argwhere(truth.layers.obstacle)))
    ij = ij[grid.in_bounds(ij)]
    t[ij[:, 0], ij[:, 1]] = True
    near = np.zeros_like(t)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            near |= np.roll(np.roll(t, di, 0), dj, 1)
    return int(np.count_nonzero(grid.layers.obstacle & ~near))


def test_fused_at_the_aligned_pose_a_wall_is_not_drawn_twice():
    truth = looked_around()
    true = Pose2D(1.5, 0.0, math.radians(-30))
    truth.update(observation(BOXES, true))
    obs = dataclasses.replace(observation(BOXES, true), pose=estimate_off(true, 3.0, 0.0, 0.0))
    plain, aligned = looked_around(), looked_around()
    plain.update(obs)
    frame = aligned.lift(obs)
    got = aligned.align(frame, ALIGN)
    assert got.corrected
    aligned.update(dataclasses.replace(obs, pose=got.pose), frame)
    assert phantom_cells(plain, truth) >= 40  # 3 deg: the far walls land 10-25 cm off
    assert phantom_cells(aligned, truth) <= phantom_cells(plain, truth) // 5


def test_at_the_exact_pose_nothing_is_corrected():
    grid = looked_around()
    for pose in (Pose2D(1.0, 0.5, 0.3), Pose2D(2.0, -0.5, -2.0), Pose2D(0.0, 0.0, 1.2), Pose2D(3.0, 1.0, 2.8)):
        obs = observation(BOXES, pose)
        frame = grid.lift(obs)
        got = grid.align(frame, ALIGN)
        assert not got.corrected and got.pose == pose
        # the frame lies on the map where it was taken, to within the cells' quantisation
        assert got.estimate_score_m < 0.5 * grid.resolution_m
        grid.update(obs, frame)


def test_a_frame_of_unmapped_space_is_not_aligned():
    # the map knows only a room 10 m away: nothing in this frame is on it
    grid = GridMap(CFG)
    far = [(b[0] + 10.0, b[1], b[2] + 10.0, b[3], b[4]) for b in BOXES]
    grid.update(observation(far, Pose2D(10.0, 0.0, 0.0)))
    true = Pose2D(1.0, 0.5, 0.4)
    obs = dataclasses.replace(observation(BOXES, true), pose=estimate_off(true, 2.0, 0.0, 0.0))
    got = grid.align(grid.lift(obs), ALIGN)
    assert not got.corrected and got.pose == obs.pose


def test_the_correction_stays_within_the_window_around_the_estimate():
    grid = looked_around()
    true = Pose2D(1.0, 0.5, math.radians(20))
    est = estimate_off(true, 9.0, 0.0, 0.0)  # beyond the window
    obs = dataclasses.replace(observation(BOXES, true), pose=est)
    got = grid.align(grid.lift(obs), ALIGN)
    assert abs(math.degrees(got.pose.yaw_rad - est.yaw_rad)) <= ALIGN.max_yaw_deg + 1e-9
    assert got.pose.distance_to(est) <= ALIGN.max_shift_m * math.sqrt(2) + 1e-9


def test_too_few_obstacle_points_are_not_aligned():
    grid = looked_around()
    true = Pose2D(1.0, 0.5, math.radians(20))
    obs = dataclasses.replace(observation(BOXES, true), pose=estimate_off(true, 2.0, 0.0, 0.0))
    frame = grid.lift(obs)
    got = grid.align(frame, dataclasses.replace(ALIGN, min_points=len(frame.cloud.xy_base) + 1))
    assert not got.corrected


def test_a_correction_is_taken_when_two_frames_in_a_row_ask_for_it():
    grid = looked_around()
    true = Pose2D(1.0, 0.5, math.radians(20))
    first = grid.align(
        grid.lift(dataclasses.replace(observation(BOXES, true), pose=estimate_off(true, 2.0, 0, 0))), ALIGN
    )
    true2 = Pose2D(1.0, 0.5, math.radians(50))  # turned: the same heading error
    second = grid.align(
        grid.lift(dataclasses.replace(observation(BOXES, true2), pose=estimate_off(true2, 2.0, 0, 0))), ALIGN
    )
    assert first.corrected and second.corrected
    assert agrees(first, second, ALIGN)
    assert not agrees(None, second, ALIGN)  # the first frame alone is not enough
    other = dataclasses.replace(second, yaw_deg=second.yaw_deg + 2 * ALIGN.agree_yaw_deg)
    assert not agrees(first, other, ALIGN)  # another correction: a chance fit
    assert not agrees(first, Alignment(true2, False), ALIGN)


def agent_beliefs(enabled: bool) -> list[Pose2D]:
    """The poses an agent records for a look-around at exact poses, then two frames (turned 30 deg
    apart) whose estimate is off by 2 deg."""
    config = oracle_config()
    config = dataclasses.replace(config, alignment=dataclasses.replace(config.alignment, enabled=enabled))
    agent = ModIINAgent(config, oracle_reid=lambda obs: False, oracle_ego_mask=lambda obs: np.zeros((1, 1), bool))
    frames = [(Pose2D(1.0, 0.5, k * math.radians(30)), 0.0) for k in range(12)]
    frames += [(Pose2D(1.0, 0.5, math.radians(20)), 2.0), (Pose2D(1.0, 0.5, math.radians(50)), 2.0)]
    beliefs = []
    for step, (true, error_deg) in enumerate(frames):
        obs = dataclasses.replace(
            observation(BOXES, true, intrinsics=SMALL, step=step), pose=estimate_off(true, error_deg, 0.0, 0.0)
        )
        if step == 0:
            agent.reset(obs.goal_image)
        agent.act(obs)
        beliefs.append(agent.last_record.pose)
    return beliefs


def test_the_agent_takes_a_correction_that_two_frames_in_a_row_ask_for():
    on, off = agent_beliefs(enabled=True), agent_beliefs(enabled=False)
    assert on[:12] == off[:12]  # exact poses: nothing corrected
    assert on[12] == off[12]  # the first tilted frame alone: its estimate
    assert math.degrees(off[13].yaw_rad - math.radians(50)) == pytest.approx(2.0)
    assert abs(math.degrees(wrap_angle(on[13].yaw_rad - math.radians(50)))) <= 0.5  # the second: aligned
