"""The Hello Robot Stretch as a backend choice (offered when a robot address is configured).

The run uses ``robot.backend.StretchBackend`` (the stretch_ai ZeroMQ bridge client) and the
agent's ``stretch`` deployment config. A real home has no ground truth, so these runs are
never scored: the outcome says whether the agent stopped and why.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent.types import MAX_STEPS, Action, Agent, Backend
from console.agents import build_agent
from console.options import RunForm, StretchRunOptions
from console.session import OptionsError, Outcome, ResolvedRun, RunSession

logger = logging.getLogger(__name__)


@dataclass
class StretchSession:
    backend: Backend
    agent: Agent
    agent_config: Mapping[str, Any] = field(default_factory=dict)

    def outcome(self, last_action: Action | None, reason: str) -> Outcome:
        if reason == "operator":
            return Outcome("stopped", "stopped by the operator")
        if reason == "agent":
            # why the agent stopped comes from its own record (RunManager: agent_stop_detail)
            return Outcome("unscored", "no ground truth on a real robot, so the run is not scored")
        return Outcome("unscored", "the step budget ran out (no ground truth on a real robot)")

    def close(self) -> None:
        self.backend.close()


class StretchProvider:
    name = "stretch"
    label = "Hello Robot Stretch"

    def __init__(self, host: str, agent_deployment: str = "stretch", robot_config: Any | None = None) -> None:
        """``robot_config``: a ``robot.config.StretchConfig`` for ports, timeouts and the head
        pose (default: the bridge's ports); its host is replaced by ``host``."""
        self.host = host
        self.agent_deployment = agent_deployment
        self.robot_config = robot_config

    def available(self) -> tuple[bool, str]:
        return True, ""

    def describe(self) -> Mapping[str, Any]:
        return {"host": self.host}

    def resolve(self, form: RunForm, goal_dhash: int, goal_sha256: str) -> ResolvedRun:
        unknown = form.given() - {"max_steps"}
        if unknown:
            raise OptionsError(f"options {sorted(unknown)} do not apply to the Stretch")
        max_steps = MAX_STEPS if form.max_steps is None else form.max_steps
        if not 1 <= max_steps <= MAX_STEPS:
            raise OptionsError(f"max_steps must be between 1 and {MAX_STEPS}")
        return ResolvedRun("stretch", StretchRunOptions(self.host, max_steps), None)

    def open(self, resolved: ResolvedRun, goal_rgb: np.ndarray) -> RunSession:
        import dataclasses

        from robot.backend import StretchBackend
        from robot.config import StretchConfig

        agent, agent_config = build_agent(self.agent_deployment)
        config = (
            StretchConfig(host=self.host)
            if self.robot_config is None
            else dataclasses.replace(self.robot_config, host=self.host)
        )
        backend = StretchBackend(goal_rgb, config)
        return StretchSession(backend, agent, agent_config)
