"""The one observe-act-apply loop (agent.loop) on a scripted backend and agent."""

from __future__ import annotations

import numpy as np
import pytest

from agent.loop import LoopError, LoopStep, run_loop
from agent.types import Action, BackendError, Intrinsics, Observation, Pose2D
from tests.helpers.scripted_agent import ScriptedAgent

K = Intrinsics(8.0, 8.0, 4.0, 4.0, 8, 8)


class Backend:
    """Counts its calls; pose x = number of applied actions; ``fail_at`` raises on that apply."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.applied: list[Action] = []
        self.observed = 0
        self.fail_at = fail_at
        self.log: list[str] = []

    def _obs(self) -> Observation:
        n = len(self.applied)
        return Observation(
            np.zeros((8, 8, 3), np.uint8),
            np.ones((8, 8), np.float32),
            Pose2D(float(n), 0.0, 0.0),
            K,
            np.zeros((8, 8, 3), np.uint8),
            step=n,
        )

    def reset(self) -> Observation:
        return self._obs()

    def observe(self) -> Observation:
        self.observed += 1
        self.log.append("observe")
        return self._obs()

    def apply(self, action: Action) -> None:
        if self.fail_at is not None and len(self.applied) == self.fail_at:
            raise BackendError("disconnected", "the robot went away")
        self.log.append("apply")
        self.applied.append(action)

    def close(self) -> None:
        pass


class Collect:
    def __init__(self) -> None:
        self.steps: list[LoopStep] = []

    def step(self, s: LoopStep) -> None:
        self.steps.append(s)


class BeforeApply(Collect):
    """Sees each step before the backend applies it (the backend's pose is still the agent's)."""

    def __init__(self, backend: Backend) -> None:
        super().__init__()
        self.backend = backend
        self.applied_before: list[int] = []

    def before_apply(self, s: LoopStep) -> None:
        self.applied_before.append(len(self.backend.applied))


def test_agent_stop_ends_the_loop_and_every_sink_sees_every_step() -> None:
    backend, agent = Backend(), ScriptedAgent(stop_after=4)
    a, b = Collect(), Collect()
    result = run_loop(backend, agent, 1000, sinks=(a, b))
    assert result.end == "agent" and result.n_steps == 5 and result.last_action == Action.STOP
    assert [s.action for s in a.steps] == [
        Action.MOVE_FORWARD,
        Action.TURN_LEFT,
        Action.MOVE_FORWARD,
        Action.TURN_LEFT,
        Action.STOP,
    ]
    assert [s.step for s in b.steps] == [0, 1, 2, 3, 4] and backend.applied == [s.action for s in a.steps]
    assert a.steps[1].obs.step == 1 and result.first_action_s is not None
    assert backend.observed == 4  # nothing is observed after STOP
    assert result.act_s > 0 and result.backend_s > 0 and result.last_record.reason == "scripted step 4"


def test_before_apply_sinks_see_the_frame_the_agent_acted_on() -> None:
    backend = Backend()
    sink = BeforeApply(backend)
    run_loop(backend, ScriptedAgent(stop_after=3), 1000, sinks=(sink,))
    # before step k's apply, k actions had been applied: the world is still as the agent saw it
    assert sink.applied_before == [0, 1, 2, 3] and [s.step for s in sink.steps] == [0, 1, 2, 3]


def test_budget_and_operator_stop() -> None:
    backend = Backend()
    result = run_loop(backend, ScriptedAgent(stop_after=10_000), 7)
    assert result.end == "budget" and result.n_steps == 7
    assert backend.observed == 6 and backend.log[-1] == "apply"  # the spent budget is not observed again
    seen = Collect()
    backend = Backend()
    result = run_loop(
        backend, ScriptedAgent(stop_after=10_000), 1000, sinks=(seen,), should_stop=lambda: len(seen.steps) >= 3
    )
    assert result.end == "stopped" and result.n_steps == 3 and len(backend.applied) == 3  # nothing sent after the stop


def test_a_backend_error_keeps_what_was_done() -> None:
    backend = Backend(fail_at=2)
    with pytest.raises(LoopError) as err:
        run_loop(backend, ScriptedAgent(stop_after=100), 1000)
    assert isinstance(err.value.cause, BackendError) and err.value.result.n_steps == 2
    assert err.value.result.end == "error"
