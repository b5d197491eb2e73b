"""The stretch_ai ZeroMQ bridge's messages, as plain data (docs/architecture.md section 6).

The robot binds and publishes full observations (port 4401, ~10 Hz) and state
(4403, ~30 Hz) and subscribes to actions (4402). Every message is one pickled dict.
This module names the keys, builds action dicts, parses incoming dicts into frozen
dataclasses and does the pose arithmetic of the discrete actions. No sockets here.

Acknowledgement: every action carries an integer ``step`` greater than the robot's last
handled one (an action without it, or with an old one, is dropped). The robot echoes the
last handled step in its messages; a blocking ``xyt`` goal is echoed only after the base
has arrived, because the move blocks the robot's receive loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG, Action, BackendError, Observation, Pose2D, wrap_angle
from robot import encoding

OBS_PORT = 4401
ACTION_PORT = 4402
STATE_PORT = 4403

# The bridge's "no step handled yet" value.
NO_STEP = -1


class ProtocolError(ValueError):
    """A message lacks a field we rely on, or has one of the wrong kind."""


# --- actions (workstation -> robot) ---------------------------------------------------


def move_message(goal_world: Pose2D, step: int) -> dict[str, Any]:
    """An absolute, blocking base goal. ``nav_relative`` is always present: the bridge's
    receive thread raises on an ``xyt`` without it and never acknowledges again."""
    return {
        "xyt": [float(goal_world.x_m), float(goal_world.y_m), float(goal_world.yaw_rad)],
        "nav_relative": False,
        "nav_blocking": True,
        "step": int(step),
    }


def posture_message(step: int, posture: str = "navigation") -> dict[str, Any]:
    """Arm tucked, base in navigation (goto) mode; blocks the robot until done."""
    return {"posture": posture, "step": int(step)}


def head_message(pan_rad: float, tilt_rad: float, step: int) -> dict[str, Any]:
    """Head joint goal in the bridge's convention (tilt negative looks down); not blocking."""
    return {"head_to": [float(pan_rad), float(tilt_rad)], "step": int(step)}


def discrete_goal(base_world: Pose2D, action: Action) -> Pose2D:
    """The absolute base goal of a discrete action taken at ``base_world`` (docs/architecture.md section 1:
    forward 0.25 m, turns of 30 deg). STOP has no goal."""
    if action == Action.MOVE_FORWARD:
        local = Pose2D(FORWARD_STEP_M, 0.0, 0.0)
    elif action == Action.TURN_LEFT:
        local = Pose2D(0.0, 0.0, math.radians(TURN_ANGLE_DEG))
    elif action == Action.TURN_RIGHT:
        local = Pose2D(0.0, 0.0, -math.radians(TURN_ANGLE_DEG))
    else:
        raise ValueError(f"{action!r} has no base goal")
    return base_world.compose(local)


def pose_error(actual: Pose2D, goal: Pose2D) -> tuple[float, float]:
    """(position error in metres, absolute heading error in radians)."""
    return actual.distance_to(goal), abs(wrap_angle(actual.yaw_rad - goal.yaw_rad))


# --- messages (robot -> workstation) --------------------------------------------------


def _require(msg: Mapping[str, Any], key: str, kind: str) -> Any:
    if key not in msg:
        raise ProtocolError(f"{kind} message has no '{key}' (keys: {sorted(map(str, msg))})")
    return msg[key]


def _pose_from_xyt(value: Any, field: str) -> Pose2D:
    xyt = np.asarray(value, dtype=np.float64).reshape(-1)
    if xyt.shape != (3,) or not np.all(np.isfinite(xyt)):
        raise ProtocolError(f"{field}: expected finite (x, y, theta), got {value!r}")
    return Pose2D(float(xyt[0]), float(xyt[1]), wrap_angle(float(xyt[2])))


def _optional_step(msg: Mapping[str, Any]) -> int | None:
    value = msg.get("step")
    if value is None:
        return None
    try:
        return int(value)
    except (TypeError, ValueError):
        raise ProtocolError(f"step: expected an integer, got {value!r}") from None


def _flag(msg: Mapping[str, Any], key: str, default: bool | None) -> bool | None:
    if key not in msg or msg[key] is None:
        return default
    return bool(msg[key])


@dataclass(frozen=True, slots=True)
class RobotState:
    """One state message (port 4403).

    base_world: base pose in the robot's map frame.
    step: last handled action step. The bridge sends it in state messages as well as in
        observations (stretch_ai's ``get_state_message``); None when a message lacks it
        (older bridge versions sent it only in observations).
    is_homed / is_runstopped: None when the message does not say.
    received_s: local monotonic receive time.
    """

    base_world: Pose2D
    at_goal: bool | None
    is_homed: bool | None
    is_runstopped: bool | None
    step: int | None
    control_mode: str | None
    received_s: float


def parse_state(msg: Mapping[str, Any], received_s: float) -> RobotState:
    try:
        return _parse_state(msg, received_s)
    except (TypeError, ValueError) as exc:  # odd types inside the dict (ProtocolError is a ValueError)
        raise exc if isinstance(exc, ProtocolError) else ProtocolError(f"state message: {exc}") from exc


def _parse_state(msg: Mapping[str, Any], received_s: float) -> RobotState:
    if not isinstance(msg, Mapping):
        raise ProtocolError(f"state message must be a dict, got {type(msg).__name__}")
    mode = msg.get("control_mode")
    return RobotState(
        base_world=_pose_from_xyt(_require(msg, "base_pose", "state"), "base_pose"),
        at_goal=_flag(msg, "at_goal", None),
        is_homed=_flag(msg, "is_homed", None),
        is_runstopped=_flag(msg, "is_runstopped", None),
        step=_optional_step(msg),
        control_mode=str(mode) if mode is not None else None,
        received_s=received_s,
    )


@dataclass(frozen=True, slots=True, eq=False)
class RawObservation:
    """One full observation message (port 4401), images still encoded.

    rgb_encoded / depth_encoded: 1-D uint8 JPEG / JPEG2000 bytes.
    camera_K: (3, 3) float64 pixels. T_world_camera: (4, 4) float64 (map frame).
    base_world: from ``gps`` + ``compass``. The bridge reads it just after grabbing the
        images, and ``step`` only when it sends the message, so an observation that echoes
        step N may hold images from before step N's motion ended (docs/architecture.md section 6).
    seq: the link's count of observations received so far (1 for the first; 0 until the
        link numbers it). A higher ``seq`` is a later message from the robot.
    """

    rgb_encoded: np.ndarray
    depth_encoded: np.ndarray
    camera_K: np.ndarray
    T_world_camera: np.ndarray
    base_world: Pose2D
    step: int | None
    last_motion_failed: bool
    at_goal: bool | None
    received_s: float
    seq: int = 0


def parse_observation(msg: Mapping[str, Any], received_s: float) -> RawObservation:
    try:
        return _parse_observation(msg, received_s)
    except (TypeError, ValueError) as exc:
        raise exc if isinstance(exc, ProtocolError) else ProtocolError(f"observation message: {exc}") from exc


def _parse_observation(msg: Mapping[str, Any], received_s: float) -> RawObservation:
    if not isinstance(msg, Mapping):
        raise ProtocolError(f"observation message must be a dict, got {type(msg).__name__}")
    gps = np.asarray(_require(msg, "gps", "observation"), dtype=np.float64).reshape(-1)
    compass = np.asarray(_require(msg, "compass", "observation"), dtype=np.float64).reshape(-1)
    if gps.shape != (2,) or compass.shape != (1,):
        raise ProtocolError(f"gps/compass: expected (x, y) and [theta], got {gps.shape} and {compass.shape}")
    camera_K = np.asarray(_require(msg, "camera_K", "observation"), dtype=np.float64)
    camera_pose = _require(msg, "camera_pose", "observation")
    if camera_pose is None:
        raise ProtocolError("observation message has camera_pose None (tf not available on the robot yet?)")
    return RawObservation(
        rgb_encoded=_require(msg, "rgb", "observation"),
        depth_encoded=_require(msg, "depth", "observation"),
        camera_K=camera_K,
        T_world_camera=np.asarray(camera_pose, dtype=np.float64),
        base_world=_pose_from_xyt([gps[0], gps[1], compass[0]], "gps/compass"),
        step=_optional_step(msg),
        last_motion_failed=bool(msg.get("last_motion_failed", False)),
        at_goal=_flag(msg, "at_goal", None),
        received_s=received_s,
    )


def to_observation(raw: RawObservation, start_world: Pose2D, goal_image: np.ndarray, step: int) -> Observation:
    """The agent's ``Observation`` of a robot observation: images decoded, the base pose relative to
    the run's start ``start_world``, the camera's height and tilt from its pose; ``step``: the
    actions applied so far. An image or camera field that cannot be used is a ``BackendError``
    ``bad_observation``."""
    try:
        rgb = encoding.decode_rgb(raw.rgb_encoded)
        depth_m = encoding.decode_depth(raw.depth_encoded)
        if depth_m.shape != rgb.shape[:2]:
            raise encoding.DecodeError(f"depth {depth_m.shape} is not aligned with rgb {rgb.shape[:2]}")
        intrinsics = encoding.intrinsics_from_message(raw.camera_K, rgb.shape)
        T_world_camera = encoding.camera_pose_matrix(raw.T_world_camera)
    except encoding.DecodeError as exc:
        raise BackendError("bad_observation", f"unusable observation from the robot: {exc}") from exc
    return Observation(
        rgb=rgb,
        depth_m=depth_m,
        pose=raw.base_world.relative_to(start_world),
        intrinsics=intrinsics,
        goal_image=goal_image,
        camera_height_m=encoding.camera_height_m(T_world_camera),
        camera_tilt_rad=encoding.camera_tilt_rad(T_world_camera),
        step=step,
        timestamp_s=raw.received_s,
    )
