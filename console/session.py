"""What the run manager needs from a backend choice, and what it publishes per step.

A *backend choice* (simulator, Stretch) is a ``BackendProvider``: it checks a
run's options quickly in the request (``resolve``, raising ``OptionsError`` ->
HTTP 422) and builds the backend and the agent on the worker thread (``open``),
returning a ``RunSession``. The console owns the loop that joins them
(CONTRIBUTING: only console/ and sim/evaluation/ wire agents and backends).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from agent.types import Action, Agent, AgentRecord, Backend, Intrinsics, Pose2D
from console.options import RunForm, RunOptions

if TYPE_CHECKING:
    from console.home_memory import HomeMemories


class OptionsError(ValueError):
    """A run's options are invalid (unknown home, malformed start pose, ...)."""


class ProviderUnavailable(RuntimeError):
    """The backend choice exists but cannot be used now (e.g. no robot configured)."""


@dataclass(frozen=True, slots=True)
class ResolvedRun:
    """A run's options after validation.

    spec:    the backend's typed, frozen options (``console.options``), parsed once from the form.
    target:  what is known about the goal instance (JSON-able) or None when unknown;
             a known target means the run is scored.
    run_id:  the run's id, given by the run manager before the backend is opened (a home's
             memory notes which run asked for each of its goals: ``console.home_memory``).
    notify:  given by the run manager with the run id: what the session has to tell the operator
             while the run goes on (the robot's memory dropped: ``console.robot_memory``) is
             logged, published as a ``log`` event of the run and added to its outcome.
    """

    backend: str
    spec: RunOptions
    target: Mapping[str, Any] | None
    run_id: str | None = None
    notify: Callable[[str], None] | None = field(default=None, compare=False, repr=False)

    @property
    def options(self) -> dict[str, Any]:
        """The options serialised (stored with the run, shown by the API)."""
        return self.spec.to_json()

    @property
    def max_steps(self) -> int:
        """The step budget (docs/architecture.md section 1: 1000)."""
        return int(self.spec.max_steps)


@dataclass(frozen=True, slots=True)
class Outcome:
    """How a run ended. ``outcome``: success | failure | unscored | stopped | error.

    ``metrics`` holds success, spl, ne_m, ... when the target was known."""

    outcome: str
    detail: str
    metrics: Mapping[str, Any] | None = None


def check_memory_option(value: str | None) -> str | None:
    """The ``memory`` option of a backend with a home memory: None (default, "on") or "off"."""
    if value is None or value == "on":
        return None
    if value == "off":
        return "off"
    raise OptionsError(f"memory must be 'on' or 'off', not {value!r}")


def close_run(backend: Any, on_close: Callable[[], None] | None) -> None:
    """A session's end: its backend closed, then ``on_close`` (the memory saved, the robot's run
    finished), that one also when closing the backend failed."""
    try:
        backend.close()
    finally:
        if on_close is not None:
            on_close()


class RunSession(Protocol):
    """A backend and an agent, ready for one run.

    ``world_from_start``: optional pose of the run's start in a world frame known to
    the viewer (the simulator's home frame); None on a real robot."""

    backend: Backend
    agent: Agent
    agent_config: Mapping[str, Any]

    def outcome(self, last_action: Action | None, reason: str) -> Outcome: ...

    def close(self) -> None: ...


class BackendProvider(Protocol):
    name: str
    label: str

    def available(self) -> tuple[bool, str]:
        """(usable now, why not) for the pages' backend choice."""
        ...

    def describe(self) -> Mapping[str, Any]:
        """JSON for the pages: homes, episodes, starts, gallery... whatever the choice offers."""
        ...

    def resolve(self, form: RunForm, goal_dhash: int, goal_sha256: str) -> ResolvedRun:
        """Check the form in the request (``OptionsError`` -> 422) and parse it into typed options."""
        ...

    def open(self, resolved: ResolvedRun, goal_rgb: np.ndarray) -> RunSession: ...


@runtime_checkable
class MemoryProvider(Protocol):
    """A backend choice whose runs share the agent's memory of their home (``console.home_memory``):
    the simulator's homes, the robot's one home. ``routes/memory.py`` shows and forgets them and
    starts a known object's request again."""

    name: str
    label: str

    def memory_keys(self) -> list[str]:
        """The homes that can have a memory now (empty: none)."""
        ...

    def memories(self) -> HomeMemories: ...

    def run_memory_key(self, spec: RunOptions) -> str | None:
        """The home whose memory a run with these options uses; None: none (memory off)."""
        ...

    def stored_memory_key(self, options: Mapping[str, Any]) -> str | None:
        """The home of a stored run of this backend, from its options; None: none."""
        ...


@dataclass(frozen=True, slots=True, eq=False)
class StepRecord:
    """An immutable account of one step, published after ``backend.apply`` (docs/architecture.md section 4).

    rgb / depth_m / intrinsics: the observation the agent acted on (start-relative pose).
    record: the agent's own account (None if the agent offers none).
    trajectory_xy_m: (N, 2) float64 positions of every step so far, including this one.
    """

    run_id: str
    step: int
    t_s: float
    action: Action
    pose: Pose2D
    rgb: np.ndarray
    depth_m: np.ndarray
    intrinsics: Intrinsics
    camera_height_m: float
    camera_tilt_rad: float
    goal_rgb: np.ndarray
    record: AgentRecord | None
    trajectory_xy_m: np.ndarray
    reid_history: tuple[tuple[int, float | None, float | None], ...] = field(default=())
    step_ms: float = 0.0
