"""The Hello Robot Stretch as a backend choice (offered when a robot address is configured).

The run uses ``robot.backend.StretchBackend`` (the stretch_ai ZeroMQ bridge client) and the
agent's ``stretch`` deployment config. A real home has no ground truth, so these runs are
never scored: the outcome says whether the agent stopped and why.

With a memory directory (``imgnav console`` gives ``<data>/memory``), runs on the robot share
the agent's memory of its home, one home per robot address (``robot-<hash>``,
``console.home_memory.robot_key``), kept in the robot's own map frame and dropped, with a
message, when that frame cannot be trusted (``console.robot_memory``: a runstop, the base moved
between runs, the robot's bridge or localisation started again). ``memory=off`` runs from
nothing and leaves the memory as it was. Without a memory directory, robot runs have none.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent.types import MAX_STEPS, Action, Agent, Backend
from console.agents import build_agent
from console.home_memory import HOME_KEY, HomeMemories, robot_key
from console.options import RunForm, RunOptions, StretchRunOptions
from console.session import OptionsError, Outcome, ResolvedRun, RunSession, check_memory_option, close_run

logger = logging.getLogger(__name__)


@dataclass
class StretchSession:
    backend: Backend
    agent: Agent
    agent_config: Mapping[str, Any] = field(default_factory=dict)
    on_close: Callable[[], None] | None = None  # after the backend is closed (the memory's end of run)

    def outcome(self, last_action: Action | None, reason: str) -> Outcome:
        if reason == "operator":
            return Outcome("stopped", "stopped by the operator")
        if reason == "agent":
            # why the agent stopped comes from its own record (RunManager: agent_stop_detail)
            return Outcome("unscored", "no ground truth on a real robot, so the run is not scored")
        return Outcome("unscored", "the step budget ran out (no ground truth on a real robot)")

    def close(self) -> None:
        close_run(self.backend, self.on_close)


class StretchProvider:
    name = "stretch"
    label = "Hello Robot Stretch"

    def __init__(
        self,
        host: str,
        agent_deployment: Any = "stretch",
        robot_config: Any | None = None,
        memory_dir: Path | None = None,
    ) -> None:
        """``robot_config``: a ``robot.config.StretchConfig`` for ports, timeouts and the head
        pose (default: the bridge's ports); its host is replaced by ``host``. ``agent_deployment``:
        a deployment name or ``console.agents.Deployment``. ``memory_dir``: where the robot's home
        memory is kept (``<data>/memory``); None: robot runs have no memory."""
        self.host = host
        self.agent_deployment = agent_deployment
        self.robot_config = robot_config
        self.memory_dir = None if memory_dir is None else Path(memory_dir)
        self._lock = threading.Lock()
        self._memories: HomeMemories | None = None

    def config(self) -> Any:
        """The ``robot.config.StretchConfig`` of this console's runs (``host`` in it)."""
        from robot.config import StretchConfig

        if self.robot_config is None:
            return StretchConfig(host=self.host)
        return dataclasses.replace(self.robot_config, host=self.host)

    # --- the robot's home memory (console.robot_memory) -----------------------------------

    def memory_home(self) -> str | None:
        """The robot's home memory key, None when this console keeps no memory for it."""
        if self.memory_dir is None:
            return None
        c = self.config()
        return robot_key(c.host, c.obs_port, c.action_port, c.state_port)

    def memory_keys(self) -> list[str]:
        home = self.memory_home()
        return [] if home is None else [home]

    def memories(self) -> HomeMemories:
        """The robot's home memory store, for the deployment's memory bounds, mapping and matcher."""
        if self.memory_dir is None:
            raise RuntimeError("this console keeps no memory for the robot")
        with self._lock:
            if self._memories is None:
                from agent.config import load_agent_config

                config = load_agent_config(str(self.agent_deployment))
                self._memories = HomeMemories(self.memory_dir, config.memory, config.mapping, config.reid.matcher)
            return self._memories

    def run_memory_key(self, spec: RunOptions) -> str | None:
        """The home whose memory a run uses; None: none (memory off, or no memory kept)."""
        if not isinstance(spec, StretchRunOptions) or spec.memory == "off":
            return None
        return spec.home

    def stored_memory_key(self, options: Mapping[str, Any]) -> str | None:
        """The robot home of a stored run's options (``StretchRunOptions.to_json``), if any."""
        home = options.get("home")
        return home if isinstance(home, str) and home.startswith("robot-") and HOME_KEY.match(home) else None

    # --- BackendProvider ------------------------------------------------------------------

    def available(self) -> tuple[bool, str]:
        return True, ""

    def describe(self) -> Mapping[str, Any]:
        return {"host": self.host, "memory_home": self.memory_home()}

    def resolve(self, form: RunForm, goal_dhash: int, goal_sha256: str) -> ResolvedRun:
        unknown = form.given() - {"max_steps", "memory"}
        if unknown:
            raise OptionsError(f"options {sorted(unknown)} do not apply to the Stretch")
        max_steps = MAX_STEPS if form.max_steps is None else form.max_steps
        if not 1 <= max_steps <= MAX_STEPS:
            raise OptionsError(f"max_steps must be between 1 and {MAX_STEPS}")
        memory = check_memory_option(form.memory)
        return ResolvedRun("stretch", StretchRunOptions(self.host, max_steps, self.memory_home(), memory), None)

    def open(self, resolved: ResolvedRun, goal_rgb: np.ndarray) -> RunSession:
        from robot.backend import StretchBackend

        key = self.run_memory_key(resolved.spec)
        if key is None:
            agent, agent_config = build_agent(self.agent_deployment)
            return StretchSession(StretchBackend(goal_rgb, self.config()), agent, agent_config)
        from console.robot_memory import RobotInHome

        memories = self.memories()
        slot = memories.acquire(key, resolved.run_id)
        try:
            agent, agent_config = build_agent(self.agent_deployment, home_memory=slot.memory)
            agent_config = {**agent_config, "memory_home": key}
            robot = RobotInHome(
                StretchBackend(goal_rgb, self.config()), memories, slot, resolved.run_id, agent_config, resolved.notify
            )
        except BaseException:
            memories.release(slot, save=False)
            raise
        return StretchSession(robot, agent, agent_config, on_close=robot.finish)
