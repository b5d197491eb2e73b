"""The one observe-act-apply loop (console.loop) on the scripted backend and agent."""

from __future__ import annotations

import numpy as np
import pytest

from agent.types import Action, BackendError
from console.loop import LoopError, LoopStep, run_loop
from console_testkit import ScriptedAgent, ScriptedBackend, textured_rgb


class Collect:
    def __init__(self) -> None:
        self.steps: list[LoopStep] = []

    def step(self, s: LoopStep) -> None:
        self.steps.append(s)


def test_agent_stop_ends_the_loop_and_every_sink_sees_every_step() -> None:
    backend, agent = ScriptedBackend(textured_rgb(32, 32)), ScriptedAgent(stop_after=4)
    a, b = Collect(), Collect()
    result = run_loop(backend, agent, 1000, sinks=(a, b))
    assert result.end == "agent" and result.n_steps == 5 and result.last_action == Action.STOP
    assert [s.action for s in a.steps] == [Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_LEFT, Action.STOP]
    assert [s.step for s in b.steps] == [0, 1, 2, 3, 4] and backend.applied == [s.action for s in a.steps]
    assert a.steps[1].obs.step == 1 and result.first_action_s is not None


def test_budget_and_operator_stop() -> None:
    result = run_loop(ScriptedBackend(textured_rgb(32, 32)), ScriptedAgent(stop_after=10_000), 7)
    assert result.end == "budget" and result.n_steps == 7
    seen = Collect()
    backend = ScriptedBackend(textured_rgb(32, 32))
    result = run_loop(backend, ScriptedAgent(stop_after=10_000), 1000, sinks=(seen,), should_stop=lambda: len(seen.steps) >= 3)
    assert result.end == "stopped" and result.n_steps == 3 and len(backend.applied) == 3  # nothing sent after the stop


def test_a_backend_error_keeps_what_was_done() -> None:
    backend = ScriptedBackend(np.zeros((8, 8, 3), np.uint8), fail_at=2)
    with pytest.raises(LoopError) as err:
        run_loop(backend, ScriptedAgent(stop_after=100), 1000)
    assert isinstance(err.value.cause, BackendError) and err.value.result.n_steps == 2
