"""The run manager: one robot, so one active run at a time, on a worker thread.

The worker runs the project's one loop (CONTRIBUTING, "Contracts"; ``agent.loop.run_loop``,
with this run's step sink ``_RunSink``):

    obs = backend.reset(); agent.reset(obs.goal_image)
    while True:
        action = agent.act(obs); record = agent.last_record
        backend.apply(action)
        if action == STOP or budget spent: break
        obs = backend.observe()

and after every step publishes an immutable ``StepRecord`` to the store (SQLite
row), the status stream (event), the viewer (a non-blocking offer: the viewer
thread throttles) and the artifact writer. An operator stop is honoured between
steps; the robot is never sent another action after it. A backend that waits on
hardware (the Stretch: a move is acknowledged only after the motion) offers ``cancel()``;
a stop calls it, so the run ends as ``stopped`` at once instead of after the wait's
timeout. A move already sent runs to its end (the bridge has no stop action): the
runstop button is the emergency stop.

How a run ended is the agent's own account when the agent stopped (its last record's
mode and reason, e.g. ``exhausted``), for every backend; the backend's session adds
whether and how the run is scored. What the session tells the operator while the run goes on
(``ResolvedRun.notify``: the robot's memory dropped) is logged, published as a ``log`` event
of the run at once and added to the run's outcome; the session's configuration is stored again
when the run ends (a robot run's memory frame is known only after its reset).
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from agent.loop import LoopError, LoopResult, LoopStep, run_loop
from agent.types import Action, BackendError, Pose2D
from console.artifacts import ArtifactWriter, run_dir
from console.events import EventHub
from console.jsonio import json_safe
from console.photos import GoalPhoto
from console.replay import ReplayRecorder
from console.session import BackendProvider, Outcome, ResolvedRun, RunSession, StepRecord
from console.step_schema import StepRow
from console.store import RunStore
from console.words import distance_driven_m, run_summary

logger = logging.getLogger(__name__)


class RunConflict(RuntimeError):
    """A run is already active (HTTP 409)."""

    def __init__(self, active_run_id: str) -> None:
        super().__init__(f"run {active_run_id} is active; stop it or wait for it to end")
        self.active_run_id = active_run_id


class ViewerSink(Protocol):
    def run_started(self, run_id: str, goal_rgb: np.ndarray, info: Mapping[str, Any]) -> None: ...

    def offer(self, rec: StepRecord) -> None: ...

    def run_ended(
        self, run_id: str, status: str, outcome: Outcome, summary: Mapping[str, str] | None = None
    ) -> None: ...


@dataclass(slots=True)
class _Active:
    run_id: str
    thread: threading.Thread
    stop: threading.Event
    stop_reason: str = ""
    session: RunSession | None = None  # once opened: stop() cancels its backend's waits


class RunManager:
    def __init__(
        self,
        store: RunStore,
        hub: EventHub,
        data_dir: Path,
        providers: Mapping[str, BackendProvider],
        viewer: ViewerSink | None = None,
    ) -> None:
        self.store = store
        self.hub = hub
        self.data_dir = Path(data_dir)
        self.providers = dict(providers)
        self.viewer = viewer
        self._lock = threading.Lock()
        self._active: _Active | None = None
        self._closed = False

    # --- control -----------------------------------------------------------

    @property
    def active_run_id(self) -> str | None:
        with self._lock:
            return self._active.run_id if self._active is not None else None

    def start(
        self,
        resolved: ResolvedRun,
        goal: GoalPhoto,
        upload: bytes,
        received_s: float,
        request_timings: Mapping[str, float] | None = None,
        goal_from_run: str | None = None,
    ) -> str:
        """Create the run record and its worker thread; returns the run id. ``request_timings``:
        what the request spent before (``decode_s``, ``resolve_s``), kept in the run's timings.
        ``goal_from_run``: the run whose goal photo this one was given (kept in its goal's record).

        Raises ``RunConflict`` when a run is active, RuntimeError after shutdown."""
        provider = self.providers[resolved.backend]
        timings: dict[str, Any] = dict(request_timings or {})
        with self._lock:
            if self._closed:
                raise RuntimeError("the console is shutting down")
            if self._active is not None and self._active.thread.is_alive():
                raise RunConflict(self._active.run_id)
            run_id = uuid.uuid4().hex[:12]
            t0 = time.perf_counter()
            writer = ArtifactWriter(run_dir(self.data_dir, run_id), replay=ReplayRecorder(self.store, run_id))
            writer.write_goal(goal.png_bytes, upload, goal.extension)  # goal.png after the first action
            goal_info = {
                "format": goal.source_format,
                "size_px": list(goal.original_size_px),
                "agent_size_px": [int(goal.rgb.shape[1]), int(goal.rgb.shape[0])],
                "sha256": goal.sha256,
                "dhash": f"{goal.dhash:016x}",
                "path": "goal.png",
            }
            if goal_from_run is not None:
                goal_info["from_run"] = goal_from_run
            self.store.create_run(
                run_id,
                backend=resolved.backend,
                options=resolved.options,
                goal=goal_info,
                target=resolved.target,
                created_s=received_s,
            )
            timings["record_s"] = time.perf_counter() - t0  # the upload's file and the run's row
            stop = threading.Event()
            notes: list[str] = []

            def notify(text: str) -> None:
                self._note(run_id, notes, text)

            # the home's memory notes the run id with its goal
            resolved = replace(resolved, run_id=run_id, notify=notify)
            thread = threading.Thread(
                target=self._work,
                args=(run_id, provider, resolved, goal.rgb, writer, stop, received_s, timings, notes),
                name=f"run-{run_id}",
                daemon=True,
            )
            self._active = _Active(run_id, thread, stop)
            thread.start()
        self.hub.publish("status", run_id, {"status": "pending", "backend": resolved.backend})
        logger.info("run %s started (%s, %s)", run_id, resolved.backend, dict(resolved.options))
        return run_id

    def stop(self, run_id: str, reason: str = "stopped by the operator") -> bool:
        """Ask the active run to stop after its current step. False if it is not active."""
        with self._lock:
            active = self._active
            if active is None or active.run_id != run_id or not active.thread.is_alive():
                return False
            first = not active.stop.is_set()
            if first:
                active.stop_reason = reason
                active.stop.set()
            session = active.session
        detail = reason
        if first and session is not None and _cancel_backend(session, reason):
            detail = f"{reason}; {EMERGENCY_STOP_NOTE}"
        self.store.update_run(run_id, status="stopping")
        self.hub.publish("status", run_id, {"status": "stopping", "detail": detail})
        return True

    def wait(self, run_id: str, timeout_s: float) -> bool:
        """Join the run's worker thread; True if it has ended."""
        with self._lock:
            active = self._active
        if active is None or active.run_id != run_id:
            return True
        active.thread.join(timeout_s)
        return not active.thread.is_alive()

    def shutdown(self, timeout_s: float = 30.0) -> None:
        """Stop the robot first: stop the active run and wait for its worker to close the backend."""
        with self._lock:
            self._closed = True
            active = self._active
        if active is not None and active.thread.is_alive():
            logger.info("shutdown: stopping run %s", active.run_id)
            self.stop(active.run_id, "the console is shutting down")
            active.thread.join(timeout_s)
            if active.thread.is_alive():
                logger.error(
                    "run %s did not stop within %.0f s; it will be marked interrupted", active.run_id, timeout_s
                )

    # --- the worker --------------------------------------------------------

    def _work(
        self,
        run_id: str,
        provider: BackendProvider,
        resolved: ResolvedRun,
        goal_rgb: np.ndarray,
        writer: ArtifactWriter,
        stop: threading.Event,
        received_s: float,
        timings: dict[str, Any],
        notes: list[str] | None = None,
    ) -> None:
        started_s = time.time()
        # upload to the first action, in consecutive parts that add up (bench_console prints them)
        timings["request_s"] = started_s - received_s  # HTTP, photo, options, run record, thread start
        t_prepare = time.perf_counter()
        self.store.update_run(run_id, status="running", started_s=started_s)
        self.hub.publish("status", run_id, {"status": "running", "detail": "preparing the backend and the agent"})
        session: RunSession | None = None
        last_action: Action | None = None
        n_steps = 0
        status, outcome = "failed", Outcome("error", "the run did not start")
        traj_rows: list[dict[str, Any]] = []
        part_sums: dict[str, float] = {}
        t_loop: float | None = None
        t_last_step: float | None = None  # when the last recorded step was published
        stop_record = None  # the agent's record of its STOP
        try:
            t0 = time.perf_counter()
            timings["prepare_s"] = t0 - t_prepare  # the run's status row and event
            session = provider.open(resolved, goal_rgb)
            t_opened = time.perf_counter()
            timings["open_s"] = t_opened - t0
            timings.update(getattr(session, "open_timings", None) or {})  # backend / agent construction
            with self._lock:
                if self._active is not None and self._active.run_id == run_id:
                    self._active.session = session
            if stop.is_set():  # stopped while opening: reset() must not wait either
                _cancel_backend(session, self._stop_reason(run_id) or "stopped by the operator")
            self.store.update_run(run_id, agent_config=dict(session.agent_config))
            if self.viewer is not None:
                self.viewer.run_started(run_id, goal_rgb, {"backend": resolved.backend, **dict(resolved.options)})
            # The project's one loop (agent.loop); this run's step sink publishes every step.
            sink = _RunSink(self, run_id, goal_rgb, writer, received_s, timings, traj_rows, part_sums)
            t_loop = t_last_step = time.perf_counter()
            timings["setup_s"] = t_loop - t_opened  # the agent config row, the viewer
            try:
                result = run_loop(
                    session.backend, session.agent, resolved.max_steps, sinks=(sink,), should_stop=stop.is_set
                )
            except LoopError as exc:  # handled below like any backend or agent failure, steps kept
                last_action, n_steps = exc.result.last_action, exc.result.n_steps
                _loop_timings(timings, exc.result)
                t_loop += exc.result.reset_s
                t_last_step = sink.t_last_step or t_loop
                raise exc.cause from None
            except BaseException:  # the resets failed: no loop ran
                t_loop = None
                raise
            _loop_timings(timings, result)
            t_loop += result.reset_s  # loop time starts after the resets
            t_last_step = sink.t_last_step or t_loop
            last_action, n_steps = result.last_action, result.n_steps
            reason = {"agent": "agent", "budget": "budget", "stopped": "operator"}[result.end]
            stop_record = result.last_record if result.end == "agent" else None
            if reason == "operator":
                status = "stopped"
                outcome = session.outcome(last_action, "operator")
                outcome = Outcome(outcome.outcome, self._stop_reason(run_id) or outcome.detail, outcome.metrics)
            else:
                status = "finished"
                outcome = session.outcome(last_action, reason)
                if reason == "agent":
                    outcome = Outcome(outcome.outcome, agent_stop_detail(stop_record, outcome.detail), outcome.metrics)
        except BackendError as exc:
            if stop.is_set() and exc.reason == "cancelled" and session is not None:
                # the operator's stop ended a wait for the robot: a stop, not a failure
                logger.info("run %s: stopped while waiting for the robot (%s)", run_id, exc)
                status = "stopped"
                outcome = session.outcome(last_action, "operator")
                why = self._stop_reason(run_id) or outcome.detail
                outcome = Outcome(outcome.outcome, f"{why}; {EMERGENCY_STOP_NOTE}", outcome.metrics)
            else:
                logger.error("run %s: backend error (%s): %s", run_id, exc.reason, exc)
                status, outcome = "failed", Outcome("error", f"backend error ({exc.reason}): {exc}")
        except Exception as exc:  # the run fails, the console lives on; the traceback goes to the log
            logger.exception("run %s failed", run_id)
            status, outcome = "failed", Outcome("error", f"{type(exc).__name__}: {exc}")
        finally:
            if t_loop is not None:  # kept when the loop raised, too
                timings["loop_s"] = time.perf_counter() - t_loop
            if session is not None:
                try:
                    session.close()
                except Exception:  # closing must not hide the run's own outcome
                    logger.exception("run %s: closing the backend failed", run_id)
        if notes:  # what the session told the operator during the run (``ResolvedRun.notify``)
            outcome = Outcome(outcome.outcome, "; ".join([outcome.detail, *notes]), outcome.metrics)
        t0 = time.perf_counter()
        try:
            summary = {"run_id": run_id, "status": status, "outcome": outcome.outcome, "metrics": outcome.metrics}
            writer.finish(traj_rows, summary)
        except Exception:
            logger.exception("run %s: writing artifacts failed", run_id)
        timings["artifacts_s"] = time.perf_counter() - t0
        if n_steps and t_loop is not None and t_last_step is not None:
            # loop start to the last recorded step: a failing wait after it is not a step
            timings["mean_step_ms"] = 1000.0 * (t_last_step - t_loop) / n_steps
            timings["agent_mean_ms"] = {k: v / n_steps for k, v in part_sums.items()}
        ended_s = time.time()
        timings["total_s"] = ended_s - received_s
        if session is not None:  # completed during the run (a robot run's memory origin)
            self.store.update_run(run_id, agent_config=dict(session.agent_config))
        self.store.update_run(
            run_id,
            status=status,
            ended_s=ended_s,
            outcome=outcome.outcome,
            outcome_detail=outcome.detail,
            metrics=dict(outcome.metrics) if outcome.metrics is not None else None,
            timings=timings,
            n_steps=n_steps,
            error=outcome.detail if status == "failed" else None,
        )
        self.hub.publish(
            "status",
            run_id,
            {
                "status": status,
                "outcome": outcome.outcome,
                "detail": outcome.detail,
                "metrics": json_safe(outcome.metrics),
                "n_steps": n_steps,
            },
        )
        if self.viewer is not None:
            try:
                # the run in the pages' words (the stored row: target, times, steps)
                row = self.store.get_run(run_id)
                said = run_summary(row, distance_driven_m(traj_rows)) if row is not None else None
                self.viewer.run_ended(run_id, status, outcome, said)
            except Exception:
                logger.exception("viewer failed at the end of run %s", run_id)
        logger.info("run %s %s: %s (%s) after %d steps", run_id, status, outcome.outcome, outcome.detail, n_steps)
        with self._lock:
            if self._active is not None and self._active.run_id == run_id:
                self._active = None

    def _note(self, run_id: str, notes: list[str], text: str) -> None:
        """A session's word to the operator during its run: logged, kept for the run's outcome and
        published at once as a ``log`` event of the run."""
        notes.append(text)
        logger.warning("run %s: %s", run_id, text)
        self.hub.publish("log", run_id, {"message": f"run {run_id}: {text}", "source": "run"})

    def _stop_reason(self, run_id: str) -> str:
        with self._lock:
            active = self._active
            return active.stop_reason if active is not None and active.run_id == run_id else ""

    def _publish_step(self, rec: StepRecord, row: StepRow, row_json: Mapping[str, Any]) -> None:
        self.store.add_step(rec.run_id, row)
        # the event carries the one step schema's JSON (console.step_schema), as the API and trajectory.json
        self.hub.publish("step", rec.run_id, {"status": "running", **row_json})
        if self.viewer is not None:
            self.viewer.offer(rec)


EMERGENCY_STOP_NOTE = (
    "the robot is sent nothing more; a move already sent runs to its end (the bridge has no "
    "stop command): the runstop button is the emergency stop"
)

_AGENT_STOP_WORDS = {
    "stopped": "the agent stopped at what it took for the object",
    "exhausted": "the agent gave up (exhausted)",
}


def agent_stop_detail(record: Any, session_detail: str) -> str:
    """How an agent-ended run ended, in the agent's own words (its STOP record's mode and
    reason), followed by what the session says about scoring. ``session_detail`` parts
    ("; "-separated) that only repeat "the agent stopped ..." are dropped."""
    if record is None:
        return session_detail
    mode, why = str(getattr(record, "mode", "")), str(getattr(record, "reason", ""))
    head = _AGENT_STOP_WORDS.get(mode, f"the agent stopped ({mode})")
    if why:
        head = f"{head}: {why}"
    rest = [part for part in session_detail.split("; ") if part and not part.startswith("the agent stopped")]
    return "; ".join([head, *rest])


def _loop_timings(timings: dict[str, Any], result: LoopResult) -> None:
    """The resets (backend, agent) and the first step (``first_step_s``: the resets' end to the
    first apply's return; its act and apply are ``first_act_s`` and ``first_apply_s``)."""
    timings["reset_s"] = result.reset_s
    timings["reset_backend_s"] = result.backend_reset_s
    timings["reset_agent_s"] = result.reset_s - result.backend_reset_s
    if result.first_action_s is not None:
        timings["first_step_s"] = result.first_action_s - result.reset_s


def _cancel_backend(session: RunSession, why: str) -> bool:
    """Cancel the backend's waits if it offers that; True if it does."""
    cancel = getattr(session.backend, "cancel", None)
    if not callable(cancel):
        return False
    try:
        cancel(why)
    except Exception:  # a stop must still reach the loop (between steps)
        logger.exception("cancelling the backend's waits failed")
        return False
    return True


class _RunSink:
    """A run's step sink: the immutable ``StepRecord`` of each step to the store, the status
    stream, the viewer and the artifact writer (with the replay), plus the run's timings."""

    def __init__(
        self,
        manager: RunManager,
        run_id: str,
        goal_rgb: np.ndarray,
        writer: ArtifactWriter,
        received_s: float,
        timings: dict[str, Any],
        traj_rows: list[dict[str, Any]],
        part_sums: dict[str, float],
    ) -> None:
        self.manager = manager
        self.run_id = run_id
        self.goal_rgb = goal_rgb
        self.writer = writer
        self.received_s = received_s
        self.timings = timings
        self.traj_rows = traj_rows
        self.part_sums = part_sums
        self.trajectory: list[tuple[float, float]] = []
        self.reid_history: list[tuple[int, float | None, float | None]] = []
        self.t_last_step: float | None = None  # when the last recorded step was published

    def step(self, s: LoopStep) -> None:
        if s.step == 0:
            self.timings["upload_to_first_action_s"] = s.t_s - self.received_s
            self.timings["first_act_s"] = s.act_ms / 1000.0
            self.timings["first_apply_s"] = (s.step_ms - s.act_ms) / 1000.0
        record, obs = s.record, s.obs
        self.trajectory.append((obs.pose.x_m, obs.pose.y_m))
        self.reid_history.append(
            (s.step, None if record is None else record.reid_score, None if record is None else record.reid_tau)
        )
        rec = StepRecord(
            run_id=self.run_id,
            step=s.step,
            t_s=s.t_s,
            action=s.action,
            pose=obs.pose,
            rgb=obs.rgb,
            depth_m=obs.depth_m,
            intrinsics=obs.intrinsics,
            camera_height_m=obs.camera_height_m,
            camera_tilt_rad=obs.camera_tilt_rad,
            goal_rgb=self.goal_rgb,
            record=record,
            trajectory_xy_m=np.asarray(self.trajectory, np.float64),
            reid_history=tuple(self.reid_history),
            step_ms=s.step_ms,
        )
        schema = self.manager.store.step_schema  # the one step definition (console.step_schema)
        row = schema.from_step(rec)
        row_json = schema.to_json(row)
        self.traj_rows.append(row_json)
        for k, v in row.timings.items():
            self.part_sums[k] = self.part_sums.get(k, 0.0) + float(v)
        self.writer.add_replay(rec)  # before the step event: a client told of step N finds its pictures
        self.manager._publish_step(rec, row, row_json)
        self.writer.add_step(rec)
        if s.step == 0:  # goal.png: not needed before the first action
            try:
                self.writer.flush_goal()
            except OSError:  # a file of the run, never a reason to end it
                logger.exception("run %s: writing goal.png failed", self.run_id)
        self.t_last_step = time.perf_counter()


def start_pose_dict(pose: Pose2D) -> dict[str, float]:
    return {"x_m": pose.x_m, "y_m": pose.y_m, "yaw_rad": pose.yaw_rad}
