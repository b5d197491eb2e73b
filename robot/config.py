"""Configuration of the Stretch backend (workstation side of the stretch_ai bridge).

The agent's deployment parameters for the robot (re-ID threshold tau, camera
assumptions) live in ``agent/configs/stretch.yaml``, owned by the agent; this dataclass
holds only what the link to the robot needs. Load it from YAML with
``agent.configio.load_yaml(StretchConfig, path)`` (unknown keys are rejected).
"""

from __future__ import annotations

from dataclasses import dataclass

from robot.protocol import ACTION_PORT, OBS_PORT, STATE_PORT


@dataclass(frozen=True, slots=True)
class StretchConfig:
    """Address, timeouts and tolerances of the bridge link.

    host: the robot's address (the bridge binds; we connect).
    state_silence_s: more than this without a state message is a disconnect (docs/architecture.md section 6).
    connect_timeout_s: wait this long for the first state and observation messages.
    ack_timeout_s: wait this long for the echo of a base goal. On the robot the echo comes
        only after the base has arrived, so this must cover the whole motion (a 0.25 m
        move or a 30 deg turn takes a few seconds on a Stretch; the margin is for slow
        floors and the goto controller's settling). Also the bound for the head pose's echo.
    posture_timeout_s: same for the navigation posture at the start of a run (lift and arm
        move first, and the bridge blocks until they have).
    arrival_timeout_s: after the echo of a base goal, wait this long for the robot to report
        that the base has arrived (``at_goal``, or a failed motion; ``robot/arrival.py``). The
        bridge echoes only after arrival, so there this wait ends at once; a server whose
        navigation does not block (stretch_ai's MuJoCo server) echoes at once and the whole
        motion happens in this wait, so it must cover the motion like ``ack_timeout_s``.
        Past it the run ends with ``no_arrival``.
    still_window_s / still_tolerance_m / still_tolerance_rad: for a robot whose messages carry
        no ``at_goal``: the base has arrived when the state stream's base pose has stayed
        within these tolerances for this long, at the goal.
    resend_interval_s: re-send an unacknowledged action this often. Safe because goals are
        absolute and the bridge drops steps it has already handled; it covers a first
        message lost while the PUB/SUB connection is still being set up.
    settle_timeout_s: once the robot reports arrival (or its base stands still), wait this
        long for the reported base pose to reach the goal before calling the move failed.
    goal_tolerance_m / goal_tolerance_rad: a move has finished when the base is this close
        to its goal.
    observation_timeout_s: wait this long for an observation captured after the last move.
    observations_after_echo: take an observation for step N only when it arrived at least
        this many observations after the first one that echoed N. The bridge grabs the
        images, reads the pose, compresses, and reads the step only when it sends, all in
        one publishing loop: the observation that echoes N may hold images from before the
        motion ended, but the next one was grabbed after that send, so after the
        acknowledgement. 1 is that proof; 2 adds a publishing period of margin for a camera
        whose frames lag the grab; 0 takes the echoing observation itself (the old,
        unsafe rule, kept for the protocol benchmark).
    head_pan_rad / head_tilt_rad: head pose sent after the navigation posture; tilt is
        positive looking down (``Observation.camera_tilt_rad``; the bridge's sign is the
        opposite). 0 = level, the simulator's camera (docs/architecture.md section 1).
    head_tolerance_rad / head_timeout_s: the measured camera tilt (from ``camera_pose``)
        must reach the requested tilt within this tolerance and time.
    send_posture: send the navigation posture and head pose in ``reset()``.
    max_message_bytes: larger messages are dropped by ZeroMQ before unpickling.
    """

    host: str = "127.0.0.1"
    obs_port: int = OBS_PORT
    action_port: int = ACTION_PORT
    state_port: int = STATE_PORT
    state_silence_s: float = 1.0
    connect_timeout_s: float = 10.0
    ack_timeout_s: float = 30.0
    posture_timeout_s: float = 60.0
    arrival_timeout_s: float = 30.0
    still_window_s: float = 0.3
    still_tolerance_m: float = 0.005
    still_tolerance_rad: float = 0.01
    resend_interval_s: float = 1.0
    settle_timeout_s: float = 2.0
    goal_tolerance_m: float = 0.10
    goal_tolerance_rad: float = 0.20
    observation_timeout_s: float = 5.0
    observations_after_echo: int = 1
    head_pan_rad: float = 0.0
    head_tilt_rad: float = 0.0
    head_tolerance_rad: float = 0.15
    head_timeout_s: float = 15.0
    send_posture: bool = True
    max_message_bytes: int = 64 * 1024 * 1024

    def __post_init__(self) -> None:
        for name in ("obs_port", "action_port", "state_port"):
            port = getattr(self, name)
            if not 0 < port < 65536:
                raise ValueError(f"{name} must be a TCP port, got {port}")
        if len({self.obs_port, self.action_port, self.state_port}) != 3:
            raise ValueError("obs_port, action_port and state_port must differ")
        for name in (
            "state_silence_s",
            "connect_timeout_s",
            "ack_timeout_s",
            "posture_timeout_s",
            "arrival_timeout_s",
            "still_window_s",
            "still_tolerance_m",
            "still_tolerance_rad",
            "resend_interval_s",
            "settle_timeout_s",
            "observation_timeout_s",
            "head_timeout_s",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")
        if self.observations_after_echo < 0:
            raise ValueError("observations_after_echo must be 0 or more")
        if not self.host:
            raise ValueError("host must not be empty")

    def endpoint(self, port: int) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{port}"
