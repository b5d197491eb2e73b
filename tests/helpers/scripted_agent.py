"""A scripted agent (forward, left, forward, ... then STOP) that writes a full AgentRecord:
map, matches, plan, a candidate that appears and is rejected. For the loop's and the
console's tests, which need an agent without the policy."""

from __future__ import annotations

import numpy as np

from agent.types import Action, AgentRecord, CandidateInfo, MapSnapshot, Observation


class ScriptedAgent:
    """Forward, left, forward, ... and STOP after ``stop_after`` actions."""

    def __init__(self, stop_after: int) -> None:
        self.stop_after = stop_after
        self.n = 0
        self._record: AgentRecord | None = None

    def reset(self, goal_image: np.ndarray) -> None:
        self.n = 0

    def act(self, obs: Observation) -> Action:
        action = (
            Action.STOP if self.n >= self.stop_after else (Action.MOVE_FORWARD if self.n % 2 == 0 else Action.TURN_LEFT)
        )
        shape = (40, 40)
        explored = np.zeros(shape, bool)
        explored[10:30, 10:30] = True
        obstacle = np.zeros(shape, bool)
        obstacle[10, 10:30] = True
        frontier = np.zeros(shape, bool)
        frontier[29, 12:28] = True
        snap = MapSnapshot(
            0.05,
            (-1.0, -1.0),
            obstacle,
            explored,
            np.zeros(shape, bool),
            np.zeros(shape, bool),
            np.zeros(shape, bool),
            frontier,
        )
        self._record = AgentRecord(
            step=obs.step,
            action=action,
            pose=obs.pose,
            mode="explore",
            reason=f"scripted step {self.n}",
            event="stop_at_goal" if action == Action.STOP else "frontier",  # agent.events.Event values
            reid_score=float(self.n),
            reid_tau=10.0,
            map=snap,
            matches_goal_xy=np.array([[5, 5], [20, 20]], np.float32),
            matches_obs_xy=np.array([[50, 60], [100, 200]], np.float32),
            goal_points_xyz=np.array([[0.3, 0.2, 0.5]], np.float32),
            target_xy_m=(0.2, 0.2),
            target_kind="frontier",
            plan_xy_m=np.array([[0, 0], [0.1, 0.1], [0.2, 0.2]], np.float32),
            timings_ms={"total": 1.0},
            # a candidate appears (detected) at action 3 and is rejected at action 6
            goal_detected=self.n >= 3,
            candidates=()
            if self.n < 3
            else (
                CandidateInfo(
                    1,
                    "rejected" if self.n >= 6 else "confirmed",
                    (0.3, 0.2),
                    self.n - 2,
                    12.5,
                    0.4,
                    "unreachable for 10 steps" if self.n >= 6 else None,
                ),
            ),
        )
        self.n += 1
        return action

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record
