"""What ``StretchBackend`` reports besides observations: each base goal's ``MoveReport`` and the
run's place in the robot's own map frame (``MapFrameReport``), and ``rounded`` for the numbers it
logs."""

from __future__ import annotations

from dataclasses import dataclass

from agent.types import Action, Pose2D


def rounded(value: float, ndigits: int) -> float:
    """``value`` rounded for printing, never a negative zero ("-0.0" reads as a sign error)."""
    return round(value, ndigits) + 0.0


@dataclass(frozen=True, slots=True)
class MoveReport:
    """What happened to one base goal.

    ack_wait_s: from the first send to the echo (includes the motion on the robot).
    total_s: the whole ``apply`` call. blocked: the robot reported a failed motion
    (``last_motion_failed``; the fake robot's collision) and stopped short of the goal.
    arrival_wait_s: from the echo to the arrival the robot reported (about 0 on the bridge,
    whose moves block; the motion itself on a server that echoes at once).
    acked_before_arrival: a message echoing the step said ``at_goal`` false before the
    robot reported arrival: this server acknowledges moves before the base arrives.
    observations_before_arrival: observations echoing the step with ``at_goal`` false
    (each one would have been a stale observation for a client that trusted the echo).
    """

    step: int
    action: Action
    start_world: Pose2D
    goal_world: Pose2D
    end_world: Pose2D
    ack_wait_s: float
    total_s: float
    resends: int
    blocked: bool
    arrival_wait_s: float
    acked_before_arrival: bool
    observations_before_arrival: int


@dataclass(frozen=True, slots=True)
class MapFrameReport:
    """Where a run is in the robot's own map frame: the frame of the bridge's ``base_pose`` and
    ``gps``/``compass`` (stretch_ai's localisation), for a console that keeps the agent's memory of
    the home across runs (``console.robot_memory``). The agent never sees it: its poses stay
    relative to ``start_map``.

    start_map: the run's start (fixed by ``reset``); None until then.
    last_map: the last base pose the robot reported (its latest state message, else its latest
        observation); None before any.
    moving_to: a base goal sent whose arrival was not seen (the run ended during the move; the
        bridge has no stop, so the base goes on to it); None when the base was not moving.
    runstopped_states: how many state messages said the robot was runstopped while this
        backend was connected (at the start, or at any moment of the run, also between two
        steps: the link reads every state message); ``runstop_seen``: any.
    first_step: the step the robot echoed when this backend connected (the bridge's count of
        the actions it has handled since it started: it starts again with the bridge); None
        before.
    last_step: the highest step the robot has echoed; None before any.
    """

    start_map: Pose2D | None
    last_map: Pose2D | None
    moving_to: Pose2D | None
    runstopped_states: int
    first_step: int | None
    last_step: int | None

    @property
    def runstop_seen(self) -> bool:
        return self.runstopped_states > 0
