"""Has the base arrived? Judged from what the robot reports after it echoed a move's step.

stretch_ai's ROS 2 bridge blocks its receive loop until the base has arrived, so the echo
of an ``xyt`` goal's step already means arrival. A server whose navigation does not block
(stretch_ai's MuJoCo server hands the goal to its control thread and echoes at once)
echoes while the base is still moving; observations taken then show the motion, not its
end. Both report arrival in the ``at_goal`` flag of their state and observation messages:
false from the moment a goal is accepted until the goto controller is done (close to the
goal and the odometry speed near zero for a moment). ``ArrivalWatch`` waits for it:

* ``blocked``: an observation echoing the step says ``last_motion_failed``;
* ``arrived``: a message about the step reports ``at_goal`` and the state's base pose is
  within tolerance of the goal; when the robot reports no ``at_goal`` at all, the state
  stream's base pose standing still (within ``still_tolerance_*`` for ``still_window_s``)
  at the goal counts instead;
* ``off_goal``: the robot says it arrived (or, without ``at_goal``, its base stands
  still) but the base stays off the goal for ``settle_timeout_s`` without a failed motion;
* ``no_arrival``: none of these within ``arrival_timeout_s`` of the echo.

A message is *about* the step when it echoes it (an observation, or a state message that
carries ``step``) or, for a state message without ``step``, when it arrived after the echo.
Pure logic, no sockets: fed the link's latest state and observation and the time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from agent.types import Pose2D
from robot.protocol import RawObservation, RobotState, pose_error


@dataclass(frozen=True, slots=True)
class ArrivalLimits:
    """The bounds and tolerances of the wait (from ``StretchConfig``)."""

    arrival_timeout_s: float
    settle_timeout_s: float
    goal_tolerance_m: float
    goal_tolerance_rad: float
    still_window_s: float
    still_tolerance_m: float
    still_tolerance_rad: float


@dataclass(frozen=True, slots=True)
class ArrivalVerdict:
    """How the wait ended. kind: ``arrived``, ``blocked``, ``off_goal`` or ``no_arrival``.

    pose: the base pose last reported (state stream; None if no state arrived after the echo).
    how: what showed it (``at_goal``, ``still``, ``last_motion_failed``, or ``timeout``).
    after_s: from the echo to the verdict.
    """

    kind: str
    how: str
    pose: Pose2D | None
    after_s: float


class ArrivalWatch:
    """Waits for one move's arrival; call ``update`` on every new message or tick."""

    def __init__(self, step: int, goal: Pose2D, echoed_at_s: float, limits: ArrivalLimits) -> None:
        self.step = step
        self.goal = goal
        self.echoed_at_s = echoed_at_s
        self.limits = limits
        self.reports_at_goal = False  # a message about the step carried at_goal
        self.reported_not_arrived = False  # a message about the step said at_goal false
        self.observations_before_arrival = 0  # observations echoing the step with at_goal false
        self.pose: Pose2D | None = None  # latest base pose from a state message about the step
        self._claimed_at_s: float | None = None  # when the robot first said it arrived / stood still
        self._still_anchor: tuple[float, Pose2D] | None = None
        self._last_state_s: float | None = None
        self._last_obs_seq: int | None = None

    # --- judging ---------------------------------------------------------------------------

    def update(self, state: RobotState | None, obs: RawObservation | None, now_s: float) -> ArrivalVerdict | None:
        """The verdict once there is one, else None."""
        lim = self.limits
        state_ok = (
            state is not None
            and state.received_s >= self.echoed_at_s
            and (state.step is None or state.step >= self.step)
        )
        obs_ok = obs is not None and obs.step is not None and obs.step >= self.step
        if state_ok:
            assert state is not None
            self._note_state(state)
        at_goal = False
        if obs_ok:
            assert obs is not None
            if obs.at_goal is not None:
                self.reports_at_goal = True
                if obs.at_goal:
                    at_goal = True
                elif obs.seq != self._last_obs_seq and not obs.last_motion_failed:
                    self.reported_not_arrived = True
                    self.observations_before_arrival += 1
            self._last_obs_seq = obs.seq
        if state_ok:
            assert state is not None
            if state.at_goal is not None:
                self.reports_at_goal = True
                at_goal = at_goal or state.at_goal
                if not state.at_goal:
                    self.reported_not_arrived = True
        if self.pose is None:
            return self._timeout(now_s)  # no base pose reported after the echo yet
        if obs_ok and obs is not None and obs.last_motion_failed:
            # where it stopped: the state's pose (read after the echo); the observation's pose
            # was read before its step was stamped and may predate the motion's end
            return self._verdict("blocked", "last_motion_failed", now_s)
        err_m, err_rad = pose_error(self.pose, self.goal)
        at_pose = err_m <= lim.goal_tolerance_m and err_rad <= lim.goal_tolerance_rad
        if self.reports_at_goal:
            claim = "at_goal" if at_goal else ""
        else:
            claim = "still" if self.still_for_s() >= lim.still_window_s else ""
        if claim and at_pose:
            return self._verdict("arrived", claim, now_s)
        if claim:
            if self._claimed_at_s is None:
                self._claimed_at_s = now_s
            if now_s - self._claimed_at_s >= lim.settle_timeout_s:
                return self._verdict("off_goal", claim, now_s)
        else:
            self._claimed_at_s = None  # no longer claimed (moving again: it had only paused)
        return self._timeout(now_s)

    def still_for_s(self) -> float:
        """How long the reported base pose has stayed within the stillness tolerances."""
        if self._still_anchor is None or self._last_state_s is None:
            return 0.0
        return self._last_state_s - self._still_anchor[0]

    def _note_state(self, state: RobotState) -> None:
        if state.received_s == self._last_state_s:
            return
        self._last_state_s = state.received_s
        self.pose = state.base_world
        lim = self.limits
        anchor = self._still_anchor
        if anchor is not None:
            moved_m, turned_rad = pose_error(state.base_world, anchor[1])
            if moved_m <= lim.still_tolerance_m and turned_rad <= lim.still_tolerance_rad:
                return
        self._still_anchor = (state.received_s, state.base_world)

    def _timeout(self, now_s: float) -> ArrivalVerdict | None:
        if self._claimed_at_s is None and now_s - self.echoed_at_s >= self.limits.arrival_timeout_s:
            return self._verdict("no_arrival", "timeout", now_s)
        return None

    def _verdict(self, kind: str, how: str, now_s: float) -> ArrivalVerdict:
        return ArrivalVerdict(kind, how, self.pose, now_s - self.echoed_at_s)

    # --- words -----------------------------------------------------------------------------

    def describe(self) -> str:
        """Where the base is and what the robot says, for an error message."""
        if self.pose is None:
            return "no base pose was reported after the acknowledgement"
        err_m, err_rad = pose_error(self.pose, self.goal)
        still_s = self.still_for_s()
        motion = f"standing still for {still_s:.1f} s" if still_s >= self.limits.still_window_s else "still moving"
        flag = (
            "at_goal stayed false"
            if self.reports_at_goal
            else "the robot reports no at_goal, so arrival is judged from its base standing still at the goal"
        )
        return f"{flag}; the base is {err_m:.2f} m and {math.degrees(err_rad):.0f} deg from the goal, {motion}"
