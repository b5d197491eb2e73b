"""The observe-act-apply loop, written once (docs/architecture.md section 4), with step sinks.

    obs = backend.reset(); agent.reset(obs.goal_image)
    while not should_stop():
        action = agent.act(obs); record = agent.last_record
        (sinks that see the world as the agent saw it: before_apply)
        backend.apply(action)
        (every sink gets the step)
        if action == STOP or budget spent: break
        obs = backend.observe()

It needs only ``agent.types``: the console's run manager, the evaluation runner and the
benchmarks all call it and differ only in their sinks (store, event stream, viewer,
artifacts, evaluation record) and their stop condition. An exception from the backend or
the agent propagates to the caller with the steps done so far in ``LoopError.result``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from agent.types import Action, Agent, AgentRecord, Backend, Observation


@dataclass(frozen=True, slots=True, eq=False)
class LoopStep:
    """One step: the observation acted on, the action, the agent's record, timings."""

    step: int
    obs: Observation
    action: Action
    record: AgentRecord | None
    t_s: float  # wall clock after ``apply`` returned
    step_ms: float  # act + apply
    act_ms: float = 0.0  # of which act (the rest is apply)


class StepSink(Protocol):
    """Gets every step after the backend applied its action. A sink may also define
    ``before_apply(s: LoopStep)`` (called between ``act`` and ``apply``, with ``t_s`` and
    ``step_ms`` still 0): the evaluation's oracle attribution reads the ground truth of the
    frame the agent acted on there, before the backend moves on."""

    def step(self, s: LoopStep) -> None: ...


@dataclass(frozen=True, slots=True)
class LoopResult:
    """end: ``agent`` (it said STOP), ``budget`` (max_steps spent) or ``stopped`` (should_stop)."""

    end: str
    n_steps: int
    last_action: Action | None
    last_record: AgentRecord | None
    reset_s: float
    loop_s: float
    first_action_s: float | None = None  # perf_counter seconds from the call to the first apply's return
    act_s: float = 0.0  # seconds in agent.act over the loop
    backend_s: float = 0.0  # seconds in backend.apply and backend.observe over the loop
    backend_reset_s: float = 0.0  # of reset_s, backend.reset (the rest is agent.reset)


class LoopError(RuntimeError):
    """The backend or the agent raised; ``result`` holds what was done before."""

    def __init__(self, cause: BaseException, result: LoopResult) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}")
        self.cause = cause
        self.result = result


def run_loop(
    backend: Backend,
    agent: Agent,
    max_steps: int,
    sinks: Sequence[StepSink] = (),
    should_stop: Callable[[], bool] = lambda: False,
) -> LoopResult:
    """Run one episode or run to its end; see the module docstring."""
    t_call = time.perf_counter()
    obs = backend.reset()
    backend_reset_s = time.perf_counter() - t_call
    agent.reset(obs.goal_image)
    reset_s = time.perf_counter() - t_call
    t_loop = time.perf_counter()
    n, last_action, last_record, first_action_s = 0, None, None, None
    act_s = backend_s = 0.0
    before = [sink.before_apply for sink in sinks if hasattr(sink, "before_apply")]
    end = "budget"

    def result(how: str) -> LoopResult:
        return LoopResult(
            how,
            n,
            last_action,
            last_record,
            reset_s,
            time.perf_counter() - t_loop,
            first_action_s,
            act_s,
            backend_s,
            backend_reset_s,
        )

    try:
        for step in range(max_steps):
            if should_stop():
                end = "stopped"
                break
            t0 = time.perf_counter()
            action = agent.act(obs)
            record = agent.last_record
            t1 = time.perf_counter()
            act_s += t1 - t0
            if before:
                pre = LoopStep(step, obs, action, record, 0.0, 0.0)
                for fn in before:
                    fn(pre)
            t2 = time.perf_counter()
            backend.apply(action)
            now = time.perf_counter()
            backend_s += now - t2
            if first_action_s is None:
                first_action_s = now - t_call
            last_action, last_record, n = action, record, step + 1
            s = LoopStep(step, obs, action, record, time.time(), 1000.0 * ((t1 - t0) + (now - t2)), 1000.0 * (t1 - t0))
            for sink in sinks:
                sink.step(s)
            if action == Action.STOP:
                end = "agent"
                break
            if step + 1 == max_steps:
                break  # the budget is spent: nothing more to observe
            t3 = time.perf_counter()
            obs = backend.observe()
            backend_s += time.perf_counter() - t3
    except Exception as exc:
        raise LoopError(exc, result("error")) from exc
    return result(end)
