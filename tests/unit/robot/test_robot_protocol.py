"""Action messages, message parsing and the pose arithmetic of discrete actions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.types import FORWARD_STEP_M, Action, Pose2D, wrap_angle
from robot import protocol

coords = st.floats(-100, 100)
angles = st.floats(-math.pi, math.pi - 1e-9)
poses = st.builds(Pose2D, coords, coords, angles)


def test_move_message_is_absolute_blocking_and_always_says_nav_relative() -> None:
    msg = protocol.move_message(Pose2D(1.0, -2.0, 0.5), step=12)
    assert msg == {"xyt": [1.0, -2.0, 0.5], "nav_relative": False, "nav_blocking": True, "step": 12}
    assert all(type(v) is float for v in msg["xyt"]) and type(msg["step"]) is int


def test_posture_and_head_messages_carry_a_step() -> None:
    assert protocol.posture_message(3) == {"posture": "navigation", "step": 3}
    assert protocol.head_message(0.0, -0.2, 4) == {"head_to": [0.0, -0.2], "step": 4}


def test_stop_has_no_goal() -> None:
    with pytest.raises(ValueError):
        protocol.discrete_goal(Pose2D(), Action.STOP)


@settings(max_examples=300, deadline=None)
@given(poses)
def test_forward_goal_is_a_quarter_metre_along_the_heading(base: Pose2D) -> None:
    goal = protocol.discrete_goal(base, Action.MOVE_FORWARD)
    assert base.distance_to(goal) == pytest.approx(FORWARD_STEP_M, abs=1e-9)
    assert goal.x_m - base.x_m == pytest.approx(FORWARD_STEP_M * math.cos(base.yaw_rad), abs=1e-9)
    assert goal.y_m - base.y_m == pytest.approx(FORWARD_STEP_M * math.sin(base.yaw_rad), abs=1e-9)
    local = goal.relative_to(base)
    assert (local.x_m, local.y_m) == pytest.approx((FORWARD_STEP_M, 0.0), abs=1e-9)
    assert math.cos(goal.yaw_rad - base.yaw_rad) == pytest.approx(1.0)


@settings(max_examples=300, deadline=None)
@given(poses, st.sampled_from([Action.TURN_LEFT, Action.TURN_RIGHT]))
def test_turns_keep_the_position_and_change_heading_by_30_degrees(base: Pose2D, action: Action) -> None:
    goal = protocol.discrete_goal(base, action)
    assert (goal.x_m, goal.y_m) == (pytest.approx(base.x_m, abs=1e-9), pytest.approx(base.y_m, abs=1e-9))
    sign = 1.0 if action == Action.TURN_LEFT else -1.0
    assert wrap_angle(goal.yaw_rad - base.yaw_rad - sign * math.radians(30)) == pytest.approx(-math.pi, abs=1e-9) or (
        abs(wrap_angle(goal.yaw_rad - base.yaw_rad - sign * math.radians(30))) < 1e-9
    )
    back = protocol.discrete_goal(goal, Action.TURN_RIGHT if action == Action.TURN_LEFT else Action.TURN_LEFT)
    assert protocol.pose_error(back, base)[0] < 1e-9 and protocol.pose_error(back, base)[1] < 1e-9


@settings(max_examples=300, deadline=None)
@given(poses, st.lists(st.sampled_from([Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT]), max_size=12))
def test_goals_composed_in_the_map_frame_equal_goals_in_the_start_frame(start: Pose2D, actions) -> None:
    """What the robot does in its map frame is what the agent sees relative to its start."""
    world, local = start, Pose2D()
    for action in actions:
        world = protocol.discrete_goal(world, action)
        local = protocol.discrete_goal(local, action)
    rel = world.relative_to(start)
    assert protocol.pose_error(rel, local)[0] < 1e-6
    assert protocol.pose_error(rel, local)[1] < 1e-6


@settings(max_examples=200, deadline=None)
@given(poses, poses)
def test_relative_pose_round_trip(a: Pose2D, b: Pose2D) -> None:
    back = a.compose(b.relative_to(a))
    assert protocol.pose_error(back, b)[0] < 1e-6 and protocol.pose_error(back, b)[1] < 1e-9


def test_parse_state_and_observation() -> None:
    state = protocol.parse_state(
        {
            "base_pose": np.array([1.0, 2.0, 3.5]),
            "is_homed": True,
            "is_runstopped": np.bool_(False),
            "step": 4,
            "at_goal": True,
        },
        received_s=5.0,
    )
    assert state.base_world.yaw_rad == pytest.approx(3.5 - 2 * math.pi)
    assert state.is_homed is True and state.is_runstopped is False and state.step == 4
    old = protocol.parse_state({"base_pose": [0, 0, 0]}, 0.0)  # an older bridge: no flags, no step
    assert old.is_homed is None and old.is_runstopped is None and old.step is None

    obs = protocol.parse_observation(
        {
            "rgb": np.zeros(3, np.uint8),
            "depth": np.zeros(3, np.uint8),
            "camera_K": np.eye(3, dtype=np.float32),
            "camera_pose": np.eye(4),
            "gps": np.array([1.0, 2.0]),
            "compass": np.array([0.25]),
            "step": 9,
            "rgb_width": 640,
            "rgb_height": 360,
        },
        received_s=1.0,
    )
    assert obs.base_world == Pose2D(1.0, 2.0, 0.25) and obs.step == 9 and not obs.last_motion_failed


@pytest.mark.parametrize(
    "msg, match",
    [
        ({}, "base_pose"),
        ({"base_pose": [1, 2]}, "base_pose"),
        ({"base_pose": [0, 0, float("nan")]}, "base_pose"),
        ({"base_pose": [0, 0, 0], "step": "x"}, "step"),
    ],
)
def test_bad_state_messages_are_protocol_errors(msg, match) -> None:
    with pytest.raises(protocol.ProtocolError, match=match):
        protocol.parse_state(msg, 0.0)


def test_observation_without_camera_pose_is_a_protocol_error() -> None:
    msg = {"rgb": 0, "depth": 0, "camera_K": np.eye(3), "camera_pose": None, "gps": [0, 0], "compass": [0]}
    with pytest.raises(protocol.ProtocolError, match="camera_pose"):
        protocol.parse_observation(msg, 0.0)


@pytest.mark.parametrize(
    "msg",
    [
        {"base_pose": {"x": 1}},
        {"base_pose": "abc"},
        {"base_pose": [0, 0, 0], "step": [1, 2]},
    ],
)
def test_odd_types_in_state_messages_are_protocol_errors(msg) -> None:
    with pytest.raises(protocol.ProtocolError):
        protocol.parse_state(msg, 0.0)


def test_odd_types_in_observation_messages_are_protocol_errors() -> None:
    msg = {"rgb": 0, "depth": 0, "camera_K": {"K": 1}, "camera_pose": np.eye(4), "gps": [0, 0], "compass": [0]}
    with pytest.raises(protocol.ProtocolError):
        protocol.parse_observation(msg, 0.0)
    with pytest.raises(protocol.ProtocolError):
        protocol.parse_observation([1, 2], 0.0)
