"""The viewer's replay of a finished run (``console.replay``): a "Replay" folder in the side
panel with a step slider and jumps (first detection, stop), and the chosen step drawn by the live
scene as the agent had it then: its pose, the trajectory so far, plan, target, goal points and
candidates, the map as the agent knew it and its camera thumbnail.

A replayed step is rebuilt as the ``StepRecord`` the live view would have drawn: the agent's
record from the stored step (its fields from the one step schema, ``StepSchema.record_fields``)
and the step's replay extras (candidates, goal points, plan, target).
"""

from __future__ import annotations

import io
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from agent.types import CAMERA_HEIGHT_M, SIM_INTRINSICS, Action, AgentRecord, CandidateInfo, Pose2D
from console.replay import decode_map, replay_marks
from console.session import StepRecord
from console.words import step_words

if TYPE_CHECKING:
    from console.store import RunStore
    from console.viewer.scene import LiveScene


@dataclass(frozen=True, slots=True)
class ReplayState:
    """The run being replayed: its stored steps (the one step schema's JSON) and extras."""

    run_id: str
    store: RunStore
    steps: list[dict[str, Any]]
    extras: Mapping[int, Mapping[str, Any]]
    marks: dict[str, Any]
    slider: Any


class ReplayGui:
    """Shows the steps of one finished run; a live run ends it (``end``)."""

    def __init__(
        self,
        server: Any,
        scene: LiveScene,
        handles_lock: threading.RLock,
        publish: Callable[[StepRecord], None],
    ) -> None:
        self.server = server
        self.scene = scene
        self._handles_lock = handles_lock  # the viewer's one lock for viser handles
        self._publish = publish  # draws a replayed step (the live scene, in replay mode)
        self.state: ReplayState | None = None
        self._folder: Any = None
        self.step: int | None = None  # the step shown last

    def show(
        self,
        store: RunStore,
        row: Mapping[str, Any],
        steps: list[dict[str, Any]],
        extras: Mapping[int, Mapping[str, Any]],
        step: int,
    ) -> None:
        """Show one step of a finished run; the first call for a run builds its replay folder."""
        run_id = row["id"]
        with self._handles_lock:
            if self.state is None or self.state.run_id != run_id:
                self.scene.clear()
                self.scene.show_goal(_goal_picture(store, run_id))
                self._build(store, run_id, steps, extras)
            assert self.state is not None
            slider = self.state.slider
            if int(slider.value) != step + 1:
                slider.value = step + 1  # its callback shows the step
            else:
                self._show_step(step)

    def _build(
        self, store: RunStore, run_id: str, steps: list[dict[str, Any]], extras: Mapping[int, Mapping[str, Any]]
    ) -> None:
        if self._folder is not None:
            self._folder.remove()
        marks = replay_marks(steps, extras)
        gui = self.server.gui
        self._folder = gui.add_folder(f"Replay of run {run_id}", order=5.0)
        with self._folder:
            slider = gui.add_slider("Step", min=1, max=max(1, len(steps)), step=1, initial_value=1)
            # the state exists before any callback can read it
            self.state = ReplayState(run_id, store, steps, extras, marks, slider)
            slider.on_update(lambda _e: self._show_step(int(slider.value) - 1))
            stop = marks["stop"] if marks["stop"] is not None else marks["last"]
            for label, target in [("First detection", marks["first_detection"]), ("Stop", stop)]:
                button = gui.add_button(label, disabled=target is None)
                if target is not None:
                    button.on_click(lambda _e, t=target: setattr(slider, "value", int(t) + 1))

    def _show_step(self, step: int) -> None:
        rp = self.state
        if rp is None:
            return
        step = max(0, min(step, len(rp.steps) - 1))
        me = rp.steps[step]
        with self._handles_lock:
            self._publish(_replayed_record(rp, step))
            self.scene.status.content = f"**Replay of run {rp.run_id}** - {step_words(me)}"
        self.step = me["step"]

    def end(self) -> None:
        if self._folder is not None:
            self._folder.remove()
        self._folder = None
        self.state = None


def _replayed_record(rp: ReplayState, index: int) -> StepRecord:
    """The ``StepRecord`` of the ``index``-th stored step, as the live view would have drawn it."""
    me = rp.steps[index]
    ex = rp.extras.get(me["step"], {})
    found = rp.store.replay_map_at(rp.run_id, me["step"])
    jpeg = rp.store.replay_frame(rp.run_id, me["step"])
    rgb = _jpeg_rgb(jpeg) if jpeg is not None else np.full((64, 36, 3), 200, np.uint8)
    pose = Pose2D(me["x_m"], me["y_m"], me["yaw_rad"] or 0.0)
    target = ex.get("target")
    record = AgentRecord(
        **{
            # the agent's own fields as stored (the one step schema), then what the extras keep
            **rp.store.step_schema.record_fields(me),
            "step": me["step"],
            "action": Action(me["action"]),
            "pose": pose,
            "goal_points_xyz": np.asarray(ex.get("goal_points") or np.zeros((0, 3)), np.float32).reshape(-1, 3),
            "target_xy_m": None if target is None else (float(target[0]), float(target[1])),
            "target_kind": ex.get("target_kind"),
            "plan_xy_m": np.asarray(ex.get("plan") or np.zeros((0, 2)), np.float32).reshape(-1, 2),
            "map": decode_map(found[1]) if found is not None else None,
            "candidates": tuple(
                CandidateInfo(
                    c["id"], c["state"], tuple(c["xy_m"]), c["n_views"], c["best_score"], c["distance_m"], c.get("why")
                )
                for c in ex.get("candidates", [])
            ),
        }
    )
    upto = rp.steps[: index + 1]
    return StepRecord(
        run_id=rp.run_id,
        step=me["step"],
        t_s=me["t_s"],
        action=Action(me["action"]),
        pose=pose,
        rgb=rgb,
        depth_m=np.zeros(rgb.shape[:2], np.float32),
        intrinsics=SIM_INTRINSICS,
        camera_height_m=CAMERA_HEIGHT_M,
        camera_tilt_rad=0.0,
        goal_rgb=np.zeros((8, 8, 3), np.uint8),
        record=record,
        trajectory_xy_m=np.array([[s["x_m"], s["y_m"]] for s in upto], np.float64),
        reid_history=tuple((s["step"], s["reid_score"], s["reid_tau"]) for s in upto),
    )


def _jpeg_rgb(jpeg: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))


def _goal_picture(store: RunStore, run_id: str) -> np.ndarray:
    """The run's goal photo (runs/<id>/goal.png next to the store), grey if missing."""
    path = Path(store.db_path).parent / "runs" / run_id / "goal.png"
    if path.is_file():
        return np.asarray(Image.open(path).convert("RGB"))
    return np.full((64, 64, 3), 200, np.uint8)
