"""The agent's memory of the robot's home, kept in the robot's own map frame (issue 31).

Runs on the Stretch share one ``agent.memory.HomeMemory``, the home ``robot-<hash>``
(``console.home_memory.robot_key``: one per robot address). Its frame is the robot's map frame,
the frame of stretch_ai's localisation in which the bridge reports the base pose: the memory's
anchor is the first run's start in that frame, and a later run's backend is put in the memory's
frame with ``agent.memory.InHomeFrame(backend, origin)``, origin being this run's start relative
to the anchor (``HomeSlot.origin_for``), as the simulator does it with its true start poses. The
starts come from ``robot.backend.StretchBackend.map_frame``; the agent's own observations are
unchanged (poses from the run's start, shifted by ``InHomeFrame`` only).

**When the memory is dropped.** Every remembered point is in the map frame, so the memory is
worth keeping only while that frame is the one the robot localises in. It is dropped (emptied
as Forget empties a home, its file removed, the run going on from nothing) and the operator told
why (the run's outcome and events, the memory panel's last drop, the log) when:

* a runstop is seen during a run (dropped when that run ends) or the robot is runstopped at a
  run's start: the base can be pushed by hand while runstopped, and stretch_ai's localisation
  is not trusted after one;
* the robot is not homed at a run's start: it was powered off since the last run, so its
  localisation has started again;
* the robot's bridge echoes a lower step than it had acknowledged at the end of the last run:
  it was started again, and its localisation with it;
* the base does not start where the last run left it (``MOVED_LIMIT_M``, ``MOVED_LIMIT_RAD``):
  it was moved by hand, or its localisation was reset (to the origin, after a SLAM restart);
* there is something remembered but no record of where the last run left the base;
* the operator forgets the home (``DELETE /api/memory/<home>``).

**What the console cannot see.** It sees the robot only while a run is connected. A runstop
pressed and released between runs, or a push between runs, shows only through the pose check:
a base pushed back to within the limits of where it was left is not noticed. A localisation that
drifted or jumped while nobody watched, but reports a pose within the limits, is trusted. A
robot powered off between runs is caught three ways: its localisation starts again at the
origin (the pose check, unless the base was left at the origin), it must be homed again (not
homed at the start) and its bridge counts steps from the start again. Where a check cannot be
made the others still are: a robot that reports no step is held to the pose check alone; a run
that failed before its start was fixed leaves the last trusted record in place, so the next start
is compared with where the last run that did start left the base; and with no record at all the
memory is dropped. Where in doubt, the console drops a memory rather than keep one that may put
remembered points in the wrong place.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, MutableMapping
from typing import Any

from agent.types import Action, BackendError, Observation, Pose2D, wrap_angle
from console.home_memory import HomeMemories, HomeSlot, RobotFrame
from robot.backend import MapFrameReport, StretchBackend

logger = logging.getLogger(__name__)

# How far the base may start from where the last run left it, in the map frame, before the
# frame is taken as lost. Above what a base at rest changes by: the jitter of a lidar
# localisation (centimetres, a degree or two) plus the tolerance of a move the run ended during
# (StretchConfig.goal_tolerance_m / _rad: 0.10 m, 11.5 deg; the base goes on to that goal, which
# is recorded as where it was left). Below a push by hand worth the name and a localisation
# restarted at the origin (from wherever the base stands). Chosen, not measured on a robot: a
# frame error just under the limits misplaces a remembered point by up to 0.3 m plus 0.35 m per
# metre of its range, which the agent's live views then have to correct.
MOVED_LIMIT_M = 0.3
MOVED_LIMIT_RAD = math.radians(20.0)

RUNSTOP_WHY = (
    "its base can be pushed by hand while it is runstopped, and its localisation is not trusted after a runstop"
)


def refused_start_reason(backend_reason: str) -> str | None:
    """Why a run whose start the robot refused (``BackendError`` reason at ``reset``) drops the
    memory; None when that refusal says nothing about the map frame."""
    if backend_reason == "runstopped":
        return f"the robot is runstopped at the start of this run: {RUNSTOP_WHY}"
    if backend_reason == "not_homed":
        return (
            "the robot is not homed at the start of this run: it was powered off since the last run, so its "
            "localisation has started again"
        )
    return None


def start_drop_reason(
    previous: RobotFrame | None,
    remembered: bool,
    start: MapFrameReport,
    limit_m: float = MOVED_LIMIT_M,
    limit_rad: float = MOVED_LIMIT_RAD,
) -> str | None:
    """Why the memory cannot be used from this run's start (``start``: the backend's report just
    after its reset), given where the last run left the base (``previous``); None: keep it.
    Nothing ``remembered``: nothing to drop."""
    if not remembered:
        return None
    if start.runstop_seen:
        return f"the robot was runstopped at the start of this run: {RUNSTOP_WHY}"
    if previous is None:
        return "there is no record of where the last run left the robot, so its map frame cannot be checked"
    if start.start_map is None:
        return "the robot's start in its map frame is not known, so its map frame cannot be checked"
    if previous.last_step is not None and start.first_step is not None and start.first_step < previous.last_step:
        return (
            f"the robot's bridge was started again since run {previous.run_id} (it echoes step {start.first_step} "
            f"now, step {previous.last_step} then): its localisation may have started again with it"
        )
    moved_m = start.start_map.distance_to(previous.end_map)
    turned_rad = abs(wrap_angle(start.start_map.yaw_rad - previous.end_map.yaw_rad))
    if moved_m > limit_m or turned_rad > limit_rad:
        return (
            f"the robot starts {moved_m:.2f} m and {math.degrees(turned_rad):.0f} deg from where run "
            f"{previous.run_id} left it (more than {limit_m:.2f} m or {math.degrees(limit_rad):.0f} deg): it was "
            "moved by hand, or its localisation was reset"
        )
    return None


def end_drop_reason(end: MapFrameReport, runstops_at_start: int) -> str | None:
    """Why the memory cannot be used after this run (``end``: the backend's report after it
    closed; ``runstops_at_start``: its ``runstopped_states`` when the run's start was fixed, 0 if
    it never was); None: keep it."""
    if end.runstopped_states > runstops_at_start:
        return f"the robot was runstopped during this run: {RUNSTOP_WHY}"
    return None


def end_frame(end: MapFrameReport, run_id: str | None) -> RobotFrame | None:
    """Where this run left the base (the goal of a move still under way: the base goes on to it),
    with the bridge's step count; None when the robot reported no pose."""
    where = end.moving_to if end.moving_to is not None else end.last_map
    if where is None:
        return None
    return RobotFrame(where, end.last_step, run_id)


class RobotInHome:
    """The Stretch's backend in its home memory's frame (an ``agent.types.Backend``).

    ``reset`` resets the robot, drops the memory when its frame cannot be trusted (module
    docstring), then puts the run in the memory's frame (``InHomeFrame``, origin: this start
    relative to the memory's anchor, both in the robot's map frame). ``finish`` (after ``close``)
    drops it when a runstop was seen, else records where the run left the base, and releases the
    memory (saved). ``cancel`` reaches the robot's backend, as the run manager's stop needs.

    ``agent_config``: the run's stored configuration, completed with ``memory_origin`` and, when
    dropped, ``memory_dropped``; ``notify``: tells the operator (the run's events and outcome).
    """

    def __init__(
        self,
        backend: StretchBackend,
        memories: HomeMemories,
        slot: HomeSlot,
        run_id: str | None,
        agent_config: MutableMapping[str, Any],
        notify: Callable[[str], None] | None = None,
    ) -> None:
        from agent.memory import InHomeFrame

        self.backend = backend
        self.memories = memories
        self.slot = slot
        self.run_id = run_id
        self.agent_config = agent_config
        self._notify = notify
        # every observation, the first too, reaches the agent through InHomeFrame; its origin is
        # set by ``_start``, which its ``reset`` calls before it shifts the first observation
        self._framed = InHomeFrame(_CheckedStart(self), Pose2D())
        self._judged = False  # the start was checked and the run put in the memory's frame
        self._runstops_at_start = 0  # the robot's runstopped state messages seen by then
        self._finished = False

    @property
    def origin(self) -> Pose2D:
        """This run's start in the memory's frame (the identity until ``reset``)."""
        return self._framed.origin

    def reset(self) -> Observation:
        return self._framed.reset()

    def _start(self) -> Observation:
        """The robot's reset, its start checked (the memory dropped when it cannot be trusted) and
        the origin set; the observation as the robot's backend gave it."""
        try:
            obs = self.backend.reset()
        except BackendError as exc:
            why = refused_start_reason(exc.reason)
            if why is not None and not self.slot.is_empty():
                self._drop(why, "this run fails at its start; the next one starts from nothing")
            raise
        start = self.backend.map_frame
        assert start.start_map is not None  # reset fixed it
        why = start_drop_reason(self.slot.robot_frame, not self.slot.is_empty(), start)
        if why is not None:
            self._drop(why, "this run starts from nothing")
        origin = self.slot.origin_for(start.start_map)
        self._framed.origin = origin
        self._runstops_at_start = start.runstopped_states
        self.agent_config["memory_origin"] = [origin.x_m, origin.y_m, origin.yaw_rad]
        self._judged = True
        logger.info(
            "run %s in the memory of %s: start %s in the robot's map frame, origin %s",
            self.run_id,
            self.slot.key,
            start.start_map,
            origin,
        )
        return obs

    def observe(self) -> Observation:
        return self._framed.observe()

    def apply(self, action: Action) -> None:
        self._framed.apply(action)

    def cancel(self, why: str = "the run was stopped") -> None:
        self.backend.cancel(why)

    def close(self) -> None:
        self._framed.close()

    def finish(self) -> None:
        """After ``close``: the end's verdict and record, then the memory released (and saved)."""
        if self._finished:
            return
        self._finished = True
        try:
            end = self.backend.map_frame
            why = end_drop_reason(end, self._runstops_at_start)
            frame = end_frame(end, self.run_id) if why is None and self._judged else None
            if why is not None and not self.slot.is_empty():
                self._drop(why, "the next run starts from nothing")
            elif why is not None or self._judged:  # a record only of a run whose start was checked
                with self.slot.lock:
                    self.slot.robot_frame = frame
        finally:
            self.memories.release(self.slot)

    def _drop(self, why: str, then: str) -> None:
        self.memories.drop(self.slot, why, self.run_id)
        self.agent_config["memory_dropped"] = why
        message = f"the memory of {self.slot.key} is dropped: {why}; {then}"
        if self._notify is not None:
            self._notify(message)
        else:
            logger.warning("%s", message)


class _CheckedStart:
    """The robot's backend as ``RobotInHome``'s ``InHomeFrame`` sees it: its ``reset`` is
    ``RobotInHome._start`` (the start checked, the origin set), the rest the robot's."""

    def __init__(self, owner: RobotInHome) -> None:
        self.owner = owner

    def reset(self) -> Observation:
        return self.owner._start()

    def observe(self) -> Observation:
        return self.owner.backend.observe()

    def apply(self, action: Action) -> None:
        self.owner.backend.apply(action)

    def close(self) -> None:
        self.owner.backend.close()
