"""Small hand-built inputs for the console's unit tests: a scripted backend and agent
that exercise the run manager's loop without the simulator (integration tests use
the real PyBullet simulator)."""

from __future__ import annotations

import io
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from PIL import Image

from agent.types import (
    SIM_INTRINSICS,
    Action,
    BackendError,
    Observation,
    Pose2D,
)
from console.options import RunForm
from console.session import OptionsError, Outcome, ResolvedRun
from tests.helpers.polling import poll as poll  # re-exported: the console tests import it from here
from tests.helpers.scripted_agent import ScriptedAgent as ScriptedAgent  # re-exported


@dataclass(frozen=True, slots=True)
class ScriptedOptions:
    max_steps: int = 1000
    home: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in {"max_steps": self.max_steps, "home": self.home}.items() if v is not None}


def textured_rgb(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 255, size=(h // 8 + 1, w // 8 + 1, 3), dtype=np.uint8)
    return np.kron(base, np.ones((8, 8, 1), np.uint8))[:h, :w].copy()


def encode(rgb: np.ndarray, fmt: str, **kw: Any) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format=fmt, **kw)
    return buf.getvalue()


class Hold:
    """Holds a run at a step: the moves from step ``at`` on wait until the test moves the hold on
    (``move_to``) or releases it, so that it can look at the run there for as long as it needs
    (``timeout_s`` is a deadline: a failed test cannot leave a run held for ever)."""

    def __init__(self, at: int, timeout_s: float = 300.0) -> None:
        self._changed = threading.Condition()
        self.at: int | None = at
        self.timeout_s = timeout_s

    def move_to(self, at: int | None) -> None:
        """Hold the moves from step ``at`` on instead (None: hold none)."""
        with self._changed:
            self.at = at
            self._changed.notify_all()

    def release(self) -> None:
        self.move_to(None)

    def wait(self, step: int) -> None:
        with self._changed:
            self._changed.wait_for(lambda: self.at is None or step < self.at, self.timeout_s)


class ScriptedBackend:
    """Turns left every step; poses advance; ``fail_at`` raises a BackendError."""

    def __init__(
        self,
        goal: np.ndarray,
        fail_at: int | None = None,
        gate: threading.Event | None = None,
        step_s: float = 0.0,
        hold: Hold | None = None,
    ) -> None:
        self.goal = goal
        self.step_s = step_s  # how long a move takes (a robot is not instantaneous; pages need time to look)
        self.pose = Pose2D()
        self.step = 0
        self.applied: list[Action] = []
        self.closed = False
        self.fail_at = fail_at
        self.gate = gate
        self.hold = hold

    def _obs(self) -> Observation:
        h, w = SIM_INTRINSICS.height_px, SIM_INTRINSICS.width_px
        rgb = np.zeros((h, w, 3), np.uint8)
        rgb[:, :, 1] = (self.step * 20) % 255
        depth = np.full((h, w), 2.0, np.float32)
        return Observation(rgb, depth, self.pose, SIM_INTRINSICS, self.goal, step=self.step)

    def reset(self) -> Observation:
        return self._obs()

    def observe(self) -> Observation:
        return self._obs()

    def apply(self, action: Action) -> None:
        if self.gate is not None:
            self.gate.wait(10.0)
        if self.hold is not None:
            self.hold.wait(self.step)
        if self.step_s:
            time.sleep(self.step_s)
        if self.fail_at is not None and self.step == self.fail_at:
            raise BackendError("disconnected", "no state for 1.2 s")
        self.applied.append(action)
        self.step += 1
        if action == Action.TURN_LEFT:
            self.pose = Pose2D(self.pose.x_m, self.pose.y_m, self.pose.yaw_rad + 0.5)
        elif action == Action.MOVE_FORWARD:
            self.pose = self.pose.compose(Pose2D(0.25, 0.0, 0.0))

    def close(self) -> None:
        self.closed = True


@dataclass
class ScriptedSession:
    backend: ScriptedBackend
    agent: ScriptedAgent
    agent_config: Mapping[str, Any] = field(default_factory=lambda: {"name": "scripted"})

    def outcome(self, last_action: Action | None, reason: str) -> Outcome:
        if reason == "operator":
            return Outcome("stopped", "stopped by the operator")
        return Outcome("unscored", f"ended by {reason}; target unknown")

    def close(self) -> None:
        self.backend.close()


class ScriptedProvider:
    """A BackendProvider for unit tests (the product's providers live in console.providers)."""

    name = "scripted"
    label = "Scripted test backend"

    def __init__(
        self, stop_after: int = 5, fail_at: int | None = None, step_s: float = 0.0, hold: Hold | None = None
    ) -> None:
        self.stop_after = stop_after
        self.step_s = step_s
        self.fail_at = fail_at
        self.gate: threading.Event | None = None
        self.hold = hold  # shared by the runs: once released, it holds none
        self.sessions: list[ScriptedSession] = []

    def available(self) -> tuple[bool, str]:
        return True, ""

    def describe(self) -> Mapping[str, Any]:
        return {}

    def resolve(self, form: RunForm, goal_dhash: int, goal_sha256: str) -> ResolvedRun:
        if form.home is not None and form.home != "h0":
            raise OptionsError(f"no home {form.home!r}")
        if form.max_steps is not None and not 1 <= form.max_steps <= 1000:
            raise OptionsError("max_steps must be between 1 and 1000")
        return ResolvedRun("scripted", ScriptedOptions(form.max_steps or 1000, form.home), None)

    def open(self, resolved: ResolvedRun, goal_rgb: np.ndarray) -> ScriptedSession:
        session = ScriptedSession(
            ScriptedBackend(goal_rgb, self.fail_at, self.gate, self.step_s, self.hold), ScriptedAgent(self.stop_after)
        )
        self.sessions.append(session)
        return session
