"""The shortest-path oracle agent: ground-truth map and goal, discrete actions.

It plans, with A* on the robot's motion lattice (``sim.lattice``), the shortest
action sequence from its current pose to a pose within the success radius of a
goal viewpoint, using the simulator's exact collision-checked step and the
fast-marching geodesic as the heuristic, follows it and stops there. If the
robot ever is not where the plan says (it should not happen: the plan replays
the simulator's own motion model), it replans.

It validates episodes, collision checking and metrics together: on a sound
episode set it must reach SR >= 0.98 and SPL >= 0.9.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from agent.types import Action, AgentRecord, Observation, Pose2D
from sim.lattice import LatticePlan, ViewpointGoal, plan_to_goal
from sim.navigation import geodesic_at

if TYPE_CHECKING:
    from sim.backend import SimBackend
    from sim.metrics import EpisodeMetrics

log = logging.getLogger(__name__)

# A* heuristic weight: 1.0 is optimal on the lattice; a little more expands far fewer states.
DEFAULT_WEIGHT = 1.2


class OracleAgent:
    """Implements ``agent.types.Agent`` given a ``SimOracle`` (never a default agent)."""

    def __init__(self, oracle, weight: float = DEFAULT_WEIGHT) -> None:
        if not oracle.target_known or len(oracle.viewpoints_world) == 0:
            raise ValueError("the oracle agent needs a known target with viewpoints")
        self.oracle = oracle
        self.weight = weight
        self._steps: list[tuple[Pose2D, Action]] = []  # (pose before the action, action)
        self._record: AgentRecord | None = None
        self._goal = ViewpointGoal(oracle.viewpoints_world)
        self.replans = 0

    def reset(self, goal_image: np.ndarray) -> None:
        self._steps, self._record, self.replans = [], None, 0

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record

    def _replan(self, pose: Pose2D) -> LatticePlan | None:
        field = self.oracle.goal_field()
        grid = self.oracle.navigable
        plan = plan_to_goal(
            self.oracle.move_world,
            pose,
            self._goal,
            lambda x, y: max(geodesic_at(field, grid, x, y) - 0.1, 0.0),
            weight=self.weight,
        )
        self.replans += 1
        if plan is None:
            self._steps = []
        else:
            before = [pose] + list(plan.poses_world[:-1])
            self._steps = list(zip(before, plan.actions))
        return plan

    def act(self, obs: Observation) -> Action:
        t0 = time.perf_counter()
        pose = self.oracle.pose_world
        reason = "following the shortest lattice path"
        if not self._steps or self._steps[0][0] != pose:
            if self._steps:
                log.warning("oracle: robot at %s, plan expected %s; replanning", pose, self._steps[0][0])
            plan = self._replan(pose)
            reason = "planned" if plan is not None else "no path to any viewpoint on the motion lattice"
        action = self._steps.pop(0)[1] if self._steps else Action.STOP
        self._record = AgentRecord(
            step=obs.step,
            action=action,
            pose=obs.pose,
            mode="oracle" if action != Action.STOP else "stopped",
            reason=reason,
            timings_ms={"total": (time.perf_counter() - t0) * 1000.0},
        )
        return action


def run_blind(backend: SimBackend) -> EpisodeMetrics | None:
    """Run the oracle agent on ``backend`` to the end and return its metrics. The oracle never
    looks at the images, so one blank observation stands in for the renders (nothing is
    rendered: fast enough to check every generated episode)."""
    from agent.types import Intrinsics

    blank = np.zeros((1, 1, 3), np.uint8)
    agent = OracleAgent(backend.oracle)
    agent.reset(blank)
    intr = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1)
    while not backend.done:
        obs = Observation(
            rgb=blank,
            depth_m=np.zeros((1, 1), np.float32),
            pose=Pose2D(),
            intrinsics=intr,
            goal_image=blank,
            step=backend.steps,
        )
        backend.apply(agent.act(obs))
    return backend.result()
