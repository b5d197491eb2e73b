"""``StretchBackend``: the agent's ``Backend`` on a Hello Robot Stretch (docs/architecture.md sections 4, 6).

The same loop that runs in simulation runs here::

    obs = backend.reset(); agent.reset(obs.goal_image)
    while True:
        action = agent.act(obs); backend.apply(action)
        if action == Action.STOP: break
        obs = backend.observe()

* ``reset()`` connects, refuses to go on when the robot is runstopped or not homed,
  seeds the step counter from the robot's echo, sends the navigation posture and the
  head pose, waits until the camera tilt is there, and fixes the run's start pose.
* ``apply()`` turns a discrete action into an absolute ``xyt`` goal composed from the
  current base pose, sends it, waits for the echo, then waits for arrival as the robot
  reports it (``robot/arrival.py``: ``at_goal``, or a failed motion; on the bridge, whose
  moves block, the echo comes after the motion and arrival is already reported; a server
  that echoes before the base arrives is waited out, with a warning) and checks that the
  base got there. STOP sends nothing: the last move has arrived, so the base is already
  standing still, and the bridge has no stop action.
* ``observe()`` returns an observation provably captured after the last move's arrival:
  one that arrived after the first observation echoing its step and reporting the motion
  over (the bridge stamps the step and ``at_goal`` at send time, after grabbing the
  images), within a bounded wait.
* ``map_frame`` (a ``MapFrameReport``) says where the run is in the robot's own map frame (the
  frame of stretch_ai's localisation): the run's start, the last base pose the robot reported,
  a move still under way, whether a runstop was seen, the bridge's step count. The agent never
  sees it (its poses are relative to the run's start); the console keys the agent's memory of
  the home to it across runs and drops that memory when the frame cannot be trusted
  (``console.robot_memory``).

Every failure is a ``BackendError`` with a reason code: ``disconnected`` (no state for
more than ``state_silence_s``), ``runstopped``, ``not_homed``, ``ack_timeout``,
``no_arrival``, ``move_failed``, ``head_failed``, ``no_observation``, ``bad_observation``, ``protocol``,
``closed``, ``cancelled`` (``cancel()`` from another thread: the run was stopped). Runstop, homing and silence are checked before sending and throughout every
wait, so a runstop pressed mid-move ends the run at once.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from agent.types import Action, BackendError, Observation, Pose2D
from robot import encoding
from robot.arrival import ArrivalLimits, ArrivalVerdict, ArrivalWatch
from robot.config import StretchConfig
from robot.link import BridgeLink
from robot.protocol import (
    RawObservation,
    RobotState,
    discrete_goal,
    head_message,
    move_message,
    pose_error,
    posture_message,
    to_observation,
)
from robot.reports import MapFrameReport, MoveReport, rounded

log = logging.getLogger(__name__)

_TICK_S = 0.05  # how often waits re-check safety when no message arrives
_HEAD_STILL_RAD = math.radians(0.5)  # camera tilt change between observations that counts as still
_CAMERA_OFFSET_WARN_M = 0.05  # a map error the agent's 5 cm cells would show
_CAMERA_PAN_WARN_RAD = math.radians(3.0)


class StretchBackend:
    """A Stretch behind stretch_ai's ZeroMQ bridge, as an ``agent.types.Backend``.

    goal_image: (h, w, 3) uint8 RGB, any size (a phone photo); returned in every observation.
    link_factory: builds the link (tests may wrap it); default ``BridgeLink``.
    """

    def __init__(
        self,
        goal_image: np.ndarray,
        config: StretchConfig | None = None,
        link_factory: Callable[[StretchConfig], BridgeLink] = BridgeLink,
    ) -> None:
        goal_image = np.asarray(goal_image)
        if goal_image.ndim != 3 or goal_image.shape[2] != 3 or goal_image.dtype != np.uint8:
            raise ValueError(f"goal_image must be (h, w, 3) uint8, got {goal_image.shape} {goal_image.dtype}")
        self.goal_image = goal_image
        self.config = config or StretchConfig()
        self._link_factory = link_factory
        self._link: BridgeLink | None = None
        self._closed = False
        self._cancelled: str | None = None  # set from another thread: waits end with "cancelled"
        self._start_world: Pose2D | None = None
        self._next_step = 0
        self._required_step: int | None = None  # observations must echo at least this
        # (step, seq): the last move's arrival; observations must come after observation seq
        # (None: after the first observation that echoed the step and reported arrival)
        self._arrival_mark: tuple[int, int | None] | None = None
        self._warned_early_acks = False
        self._actions_applied = 0
        self.moves: list[MoveReport] = []
        self.camera_offset: Pose2D | None = None  # head camera in the base frame, measured at reset
        self.last_observation_seq = 0  # the link's number of the observation last returned
        # what ``map_frame`` reports, read from the link (kept when it closes)
        self._last_map: Pose2D | None = None
        self._moving_to: Pose2D | None = None
        self._runstopped_states = 0
        self._first_step: int | None = None
        self._last_step: int | None = None

    # --- Backend protocol ----------------------------------------------------------------

    def reset(self) -> Observation:
        link = self._open()
        cfg = self.config
        self._wait_until(
            lambda: link.state is not None and link.observation is not None,
            cfg.connect_timeout_s,
            "disconnected",
            lambda: (
                f"no {'state' if link.state is None else 'observation'} messages from the robot at "
                f"{cfg.host} (ports {cfg.obs_port}/{cfg.state_port}) within {cfg.connect_timeout_s:.0f} s"
                + self._problem_suffix()
            ),
            check_link=False,
        )
        state = self._check_safe()
        if state.is_runstopped is None or state.is_homed is None:
            log.warning(
                "this bridge's state messages do not report is_runstopped/is_homed: "
                "the backend cannot refuse to move a runstopped or unhomed robot"
            )
        echoed = link.echoed_step
        if echoed is None:
            raise BackendError("protocol", "the robot's messages carry no 'step': cannot acknowledge actions")
        self._next_step = echoed + 1
        self._required_step = echoed
        self._first_step = echoed
        log.info("connected to the Stretch at %s; robot's last step %d", cfg.host, echoed)
        if cfg.send_posture:
            self._send_and_wait(lambda s: posture_message(s), cfg.posture_timeout_s, "navigation posture")
            step = self._send_and_wait(
                lambda s: head_message(cfg.head_pan_rad, -cfg.head_tilt_rad, s), cfg.ack_timeout_s, "head pose"
            )
            self._wait_for_head(step)
        self._arrival_mark = None
        raw = self._fresh_observation()
        self._start_world = raw.base_world
        self._actions_applied = 0
        self.moves = []
        obs = self._to_observation(raw)
        self._report_camera_mount(raw)
        return obs

    def observe(self) -> Observation:
        if self._start_world is None:
            raise BackendError("protocol", "observe() before reset()")
        return self._to_observation(self._fresh_observation())

    def apply(self, action: Action) -> None:
        if self._start_world is None:
            raise BackendError("protocol", "apply() before reset()")
        action = Action(action)
        if action == Action.STOP:
            self._actions_applied += 1
            return
        t0 = time.monotonic()
        start = self._check_safe().base_world  # the freshest base pose (state stream, ~30 Hz)
        goal = discrete_goal(start, action)
        sent_at = time.monotonic()
        resends: list[int] = []
        self._moving_to = goal  # until its arrival (or its failure, the base stopped) is seen
        step = self._send_and_wait(
            lambda s: move_message(goal, s), self.config.ack_timeout_s, f"{action.name}", resends
        )
        ack_wait_s = time.monotonic() - sent_at
        try:
            watch, verdict = self._wait_for_arrival(goal, step, action.name)
        except BackendError as exc:
            if exc.reason == "move_failed":  # the base stopped, away from the goal
                self._moving_to = None
            raise
        self._moving_to = None
        assert verdict.pose is not None  # every verdict but no_arrival has a pose
        end, blocked = verdict.pose, verdict.kind == "blocked"
        self._actions_applied += 1
        report = MoveReport(
            step,
            action,
            start,
            goal,
            end,
            ack_wait_s,
            time.monotonic() - t0,
            resends[0],
            blocked,
            arrival_wait_s=verdict.after_s,
            acked_before_arrival=watch.reported_not_arrived and not blocked,
            observations_before_arrival=watch.observations_before_arrival,
        )
        self.moves.append(report)
        log.debug(
            "step %d %s: ack after %.2f s, arrival %.2f s later (%s), end error %.3f m",
            step,
            action.name,
            ack_wait_s,
            verdict.after_s,
            verdict.how,
            end.distance_to(goal),
        )

    def cancel(self, why: str = "the run was stopped") -> None:
        """Make the current and every later wait for the robot end at once with a
        ``BackendError("cancelled")`` (thread-safe; called by whoever stops the run while
        ``apply``/``observe``/``reset`` waits on another thread). Nothing is sent: the bridge
        has no stop action, so a move already sent runs to its end; the runstop button is
        the emergency stop."""
        self._cancelled = why

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._link is not None:
            self._read_map_frame(self._link)  # the last word on the map frame, kept after the link
            self._link.close()
            self._link = None

    @property
    def map_frame(self) -> MapFrameReport:
        """The run in the robot's map frame (``MapFrameReport``): read from the link while it is
        open, as the link last saw it after ``close``. Thread-safe."""
        link = self._link
        if link is not None:
            self._read_map_frame(link)
        return MapFrameReport(
            start_map=self._start_world,
            last_map=self._last_map,
            moving_to=self._moving_to,
            runstopped_states=self._runstopped_states,
            first_step=self._first_step,
            last_step=self._last_step,
        )

    def _read_map_frame(self, link: BridgeLink) -> None:
        state, obs = link.state, link.observation
        if state is not None:
            self._last_map = state.base_world
        elif obs is not None:
            self._last_map = obs.base_world
        self._runstopped_states = max(self._runstopped_states, link.runstopped_states)
        echoed = link.echoed_step
        if echoed is not None:
            self._last_step = echoed

    # --- pieces ------------------------------------------------------------------------

    def _open(self) -> BridgeLink:
        if self._closed:
            raise BackendError("closed", "the Stretch backend has been closed")
        if self._link is None:
            try:
                self._link = self._link_factory(self.config)
            except RuntimeError as exc:
                raise BackendError("disconnected", str(exc)) from exc
        return self._link

    def _require_link(self) -> BridgeLink:
        if self._closed or self._link is None:
            raise BackendError("closed", "the Stretch backend is not connected (closed, or reset() not called)")
        return self._link

    def _problem_suffix(self) -> str:
        problem = self._link.last_problem if self._link is not None else None
        return f"; last problem: {problem}" if problem else ""

    def _check_safe(self, now: float | None = None) -> RobotState:
        """Raise unless the robot is connected, homed and not runstopped (and the run goes on)."""
        link = self._require_link()
        if self._cancelled is not None:
            raise BackendError("cancelled", f"nothing more is sent to the robot: {self._cancelled}")
        if link.failure:
            raise BackendError("disconnected", link.failure)
        state = link.state
        now = time.monotonic() if now is None else now
        if state is None:
            raise BackendError("disconnected", "no state message from the robot yet")
        silence_s = now - state.received_s
        if silence_s > self.config.state_silence_s:
            raise BackendError(
                "disconnected",
                f"no state message from the robot for {silence_s:.1f} s (limit {self.config.state_silence_s:.1f} s)"
                + self._problem_suffix(),
            )
        if state.is_runstopped:
            raise BackendError("runstopped", "the robot is runstopped: release the runstop button and start a new run")
        if state.is_homed is False:
            raise BackendError("not_homed", "the robot is not homed: run stretch_robot_home.py on the robot first")
        return state

    def _wait_until(
        self,
        done: Callable[[], bool],
        timeout_s: float,
        reason: str,
        message: Callable[[], str],
        check_link: bool = True,
        on_tick: Callable[[float], None] | None = None,
    ) -> None:
        """Poll ``done`` until it holds; re-check safety every tick; never wait past ``timeout_s``."""
        link = self._require_link()
        deadline = time.monotonic() + timeout_s
        while True:
            now = time.monotonic()
            if done():
                return
            if self._closed:
                raise BackendError("closed", "the Stretch backend was closed while waiting for the robot")
            if self._cancelled is not None:
                raise BackendError("cancelled", f"stopped waiting for the robot: {self._cancelled}")
            if check_link:
                self._check_safe(now)
            if now >= deadline:
                raise BackendError(reason, message())
            if on_tick is not None:
                on_tick(now)
            link.wait(done, min(_TICK_S, deadline - now))

    def _send_and_wait(
        self,
        build: Callable[[int], dict[str, Any]],
        timeout_s: float,
        what: str,
        resends_out: list[int] | None = None,
    ) -> int:
        """Send an action with the next step and wait for its echo, re-sending meanwhile."""
        link = self._require_link()
        step = self._next_step
        self._next_step += 1
        message = build(step)
        link.send(message)
        last_sent = [time.monotonic()]
        resends = [0]

        def resend(now: float) -> None:
            if now - last_sent[0] >= self.config.resend_interval_s:
                link.send(message)
                last_sent[0] = now
                resends[0] += 1

        def acked() -> bool:
            echoed = link.echoed_step
            return echoed is not None and echoed >= step

        self._wait_until(
            acked,
            timeout_s,
            "ack_timeout",
            lambda: (
                f"the robot did not acknowledge {what} (step {step}) within {timeout_s:.0f} s "
                f"(last echoed step {link.echoed_step})"
            ),
            on_tick=resend,
        )
        self._required_step = step
        if resends_out is not None:
            resends_out.append(resends[0])
        return step

    def _wait_for_arrival(self, goal: Pose2D, step: int, what: str) -> tuple[ArrivalWatch, ArrivalVerdict]:
        """After the echo: wait until the robot reports the base arrived at the goal, or says
        the motion failed (``robot/arrival.py``); ``no_arrival`` or ``move_failed`` otherwise."""
        link = self._require_link()
        cfg = self.config
        limits = ArrivalLimits(
            arrival_timeout_s=cfg.arrival_timeout_s,
            settle_timeout_s=cfg.settle_timeout_s,
            goal_tolerance_m=cfg.goal_tolerance_m,
            goal_tolerance_rad=cfg.goal_tolerance_rad,
            still_window_s=cfg.still_window_s,
            still_tolerance_m=cfg.still_tolerance_m,
            still_tolerance_rad=cfg.still_tolerance_rad,
        )
        watch = ArrivalWatch(step, goal, time.monotonic(), limits)
        outcome: list[ArrivalVerdict] = []

        def judged() -> bool:
            verdict = watch.update(link.state, link.observation, time.monotonic())
            if verdict is not None:
                outcome[:] = [verdict]
            return verdict is not None

        # The watch ends every wait within its own bounds; the outer bound is a backstop.
        backstop_s = cfg.arrival_timeout_s + cfg.settle_timeout_s + 1.0
        self._wait_until(
            judged,
            backstop_s,
            "no_arrival",
            lambda: f"step {step} {what}: no verdict on arrival within {backstop_s:.0f} s",
        )
        verdict = outcome[0]
        if verdict.kind == "no_arrival":
            text = (
                f"the robot acknowledged step {step} ({what}) but did not report that its base arrived "
                f"within {cfg.arrival_timeout_s:.1f} s of the acknowledgement (StretchConfig.arrival_timeout_s): "
                f"{watch.describe()}"
            )
            log.error("%s", text)
            raise BackendError("no_arrival", text)
        if verdict.kind == "off_goal":
            assert verdict.pose is not None
            err_m, err_rad = pose_error(verdict.pose, goal)
            said = "reported arrival" if verdict.how == "at_goal" else "stopped its base"
            raise BackendError(
                "move_failed",
                f"the robot {said} after step {step} but its base stopped {err_m:.2f} m and "
                f"{math.degrees(err_rad):.0f} deg from the goal (tolerance {cfg.goal_tolerance_m:.2f} m, "
                f"{math.degrees(cfg.goal_tolerance_rad):.0f} deg) without reporting a failed motion",
            )
        if verdict.kind == "blocked":
            assert verdict.pose is not None
            log.info(
                "step %d: the robot reports a failed motion (blocked) %.2f m short",
                step,
                verdict.pose.distance_to(goal),
            )
        if watch.reported_not_arrived and verdict.kind == "arrived" and not self._warned_early_acks:
            self._warned_early_acks = True
            log.warning(
                "the robot acknowledged step %d (%s) %.1f s before its base arrived (at_goal false at the echo): "
                "its navigation does not block, so every move waits for at_goal (bounded by %.0f s) and "
                "observations are taken after it",
                step,
                what,
                verdict.after_s,
                cfg.arrival_timeout_s,
            )
        # Observations must be captured after the arrival: after the first observation that
        # echoed the step and reported it (its flags are read at send time, like its step); a
        # robot whose observations carry no at_goal: after one received after this point.
        obs = link.observation
        if obs is not None and obs.at_goal is None and link.first_observation_arrived(step) is None:
            self._arrival_mark = (step, obs.seq + 1)
        else:
            self._arrival_mark = (step, None)
        return watch, verdict

    def _wait_for_head(self, step: int) -> None:
        link = self._require_link()
        cfg = self.config
        wanted = cfg.head_tilt_rad

        def tilt_of(obs: RawObservation | None) -> float | None:
            if obs is None or obs.step is None or obs.step < step:
                return None
            try:
                return encoding.camera_tilt_rad(encoding.camera_pose_matrix(obs.T_world_camera))
            except encoding.DecodeError:
                return None

        # (received_s, tilt, verdict) of the last observation judged
        previous: list[tuple[float, float, bool]] = []

        def there() -> bool:
            # Within tolerance and no longer moving: two successive observations agree.
            obs = link.observation
            tilt = tilt_of(obs)
            if tilt is None or obs is None:
                return False
            if previous and previous[0][0] == obs.received_s:
                return previous[0][2]
            settled = bool(previous) and abs(previous[0][1] - tilt) <= _HEAD_STILL_RAD
            verdict = settled and abs(tilt - wanted) <= cfg.head_tolerance_rad
            previous[:] = [(obs.received_s, tilt, verdict)]
            return verdict

        def failure() -> str:
            tilt = tilt_of(link.observation)
            seen = (
                "no observation after the head command" if tilt is None else f"{rounded(math.degrees(tilt), 1):.1f} deg"
            )
            return (
                f"the camera tilt did not reach {rounded(math.degrees(wanted), 1):.1f} deg (down) "
                f"within {cfg.head_timeout_s:.0f} s: {seen}"
            )

        self._wait_until(there, cfg.head_timeout_s, "head_failed", failure)

    def _fresh_observation(self) -> RawObservation:
        """The latest observation provably captured after the last acknowledged step and,
        after a move, after the arrival the robot reported.

        The bridge stamps an observation with the last handled step (and ``at_goal``) only
        when it sends it, after grabbing its images and reading its pose (docs/architecture.md
        section 6): the observation that echoes step N can hold images from before N's motion
        ended. Its publishing loop is sequential, so an observation received after that one
        was grabbed after it was sent, hence after N's acknowledgement
        (``StretchConfig.observations_after_echo``). A server that acknowledges before the
        base arrives sends observations echoing N while still moving; then the count starts
        at the first observation echoing N that also reports the motion over."""
        link = self._require_link()
        required = self._required_step
        n_after = self.config.observations_after_echo
        arrival = self._arrival_mark if self._arrival_mark is not None and self._arrival_mark[0] == required else None
        chosen: list[RawObservation] = []

        def first_counted() -> int | None:
            """The observation the count starts from (None while there is none)."""
            assert required is not None
            first = link.first_observation_echoing(required)
            if first is None or arrival is None:
                return first
            after = link.first_observation_arrived(required) if arrival[1] is None else arrival[1]
            return None if after is None else max(first, after)

        def fresh() -> bool:
            obs = link.observation
            if obs is None:
                return False
            if required is not None:
                if obs.step is None or obs.step < required:
                    return False
                first = first_counted()
                if first is None or obs.seq - first < n_after:
                    return False
            chosen[:] = [obs]
            return True

        def failure() -> str:
            first = link.first_observation_echoing(required) if required is not None else None
            latest = link.observation
            if first is None:
                seen = (
                    "no observation at all" if latest is None else f"the latest observation echoes step {latest.step}"
                )
                why = f"no observation has echoed it ({seen})"
            elif first_counted() is None:
                why = "no observation echoing it has reported the base arrived (at_goal), though the robot did"
            else:
                first = first_counted() or first
                n_since = (latest.seq - first) if latest is not None else 0
                why = (
                    f"{n_since} observation(s) arrived after the first one that echoed it (and its arrival), "
                    f"{n_after} needed (the robot's observation stream stalled?)"
                )
            return (
                f"no observation captured after the acknowledgement of step {required} within "
                f"{self.config.observation_timeout_s:.1f} s: {why}"
            )

        self._wait_until(fresh, self.config.observation_timeout_s, "no_observation", failure)
        self.last_observation_seq = chosen[0].seq
        return chosen[0]

    def _report_camera_mount(self, raw: RawObservation) -> None:
        """Log where the head camera sits relative to the base. ``Observation`` carries only the
        camera's height and tilt (the agent assumes it above the base origin, looking along the
        heading), so a horizontal offset or a residual pan shifts the agent's map by that much."""
        T = encoding.camera_pose_matrix(raw.T_world_camera)
        local = Pose2D(float(T[0, 3]), float(T[1, 3]), encoding.camera_yaw_rad(T)).relative_to(raw.base_world)
        self.camera_offset = local
        text = (
            f"head camera {rounded(local.x_m, 3):+.3f} m ahead, {rounded(local.y_m, 3):+.3f} m left of the base "
            f"origin, pan {rounded(math.degrees(local.yaw_rad), 1):+.1f} deg, height {rounded(T[2, 3], 2):.2f} m, "
            f"tilt {rounded(math.degrees(encoding.camera_tilt_rad(T)), 1):.1f} deg down"
        )
        if math.hypot(local.x_m, local.y_m) > _CAMERA_OFFSET_WARN_M or abs(local.yaw_rad) > _CAMERA_PAN_WARN_RAD:
            log.warning("%s: the agent assumes the camera above the base origin looking ahead", text)
        else:
            log.info("%s", text)

    def _to_observation(self, raw: RawObservation) -> Observation:
        assert self._start_world is not None
        return to_observation(raw, self._start_world, self.goal_image, self._actions_applied)

    # --- context manager ---------------------------------------------------------------

    def __enter__(self) -> StretchBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
