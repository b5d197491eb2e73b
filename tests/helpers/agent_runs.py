"""Agents for the policy's unit tests (oracle or scripted re-ID) and a runner that checks each
step's Decision against its AgentRecord. The worlds are in tests.helpers.agent_scenes."""

from __future__ import annotations

import numpy as np

from agent.config import AgentConfig, PolicyConfig
from agent.modes import Decision
from agent.policy import ModIINAgent
from agent.reid import Features, Matches
from agent.reid.identifier import ReIDConfig, ReIDResult
from agent.segmentation import SegmentationConfig
from agent.types import Action
from tests.helpers.agent_scenes import DECOY_RGB, GOAL_RGB


class NoMatcher:
    """A matcher that never matches (re-ID is the oracle in these tests)."""

    name = "none"

    def extract(self, rgb, max_keypoints):
        return Features(np.zeros((0, 2), np.float32), None, (rgb.shape[1], rgb.shape[0]))

    def match(self, goal, obs):
        return Matches.empty()


def oracle_config(**policy):
    pol = dict(reid_source="oracle", localisation_source="oracle")
    pol.update(policy)
    return AgentConfig(policy=PolicyConfig(**pol))


def oracle_agent(world, **policy):
    return ModIINAgent(oracle_config(**policy), oracle_reid=world.goal_visible, oracle_ego_mask=world.goal_mask)


def run_decisions(agent, world, max_steps=300, before_step=None):
    """[(Decision, AgentRecord)] of one run, stopping at STOP. ``before_step(agent)``, if given,
    runs before each step (a test's hand on the agent's state)."""
    obs = world.observe()
    agent.reset(obs.goal_image)
    out = []
    for _ in range(max_steps):
        if before_step is not None:
            before_step(agent)
        action = agent.act(obs)
        d, rec = agent.last_decision, agent.last_record
        assert isinstance(d, Decision) and d.action == action == rec.action
        # the record carries the decision
        assert rec.mode == d.mode.value and rec.reason == d.reason and rec.target_kind == d.target_kind
        assert rec.planner_error == d.planner_error
        assert (rec.target_xy_m is None) == (d.plan is None)
        assert len(rec.goal_points_xyz) == (0 if d.candidate is None else d.candidate.n_points)
        out.append((d, rec))
        world.apply(action)
        if action == Action.STOP:
            break
        obs = world.observe()
    return out


def painted_agent(world, goal_score, **policy):
    """For a PaintedWorld: tau 100, potential at tau/2. The scripted matcher reads the frame: where
    the goal's pixels show it scores ``goal_score()``, where the decoy's show 5. The gate's count
    (the shortlist's rank) is the number of such pixels, the decoy's counting half. Matches sit on
    the painted pixels; localisation lifts them (the goal image's mask is all of it).
    Returns (agent, the scores computed without the gate)."""
    pol = dict(
        reid_source="matcher",
        localisation_source="goal_mask",
        potential_tau_ratio=0.5,
        verify_ring_tau_ratio=0.5,
        last_resort=True,
    )
    pol.update(policy)
    cfg = AgentConfig(
        reid=ReIDConfig(tau=100.0, gate=False),
        policy=PolicyConfig(**pol),
        segmentation=SegmentationConfig(source="oracle"),
    )
    agent = ModIINAgent(cfg, matcher=NoMatcher(), goal_mask_fn=lambda img: np.ones(img.shape[:2], bool))
    ungated = []

    def compare(rgb, use_gate=True):
        goal = np.all(rgb == GOAL_RGB, axis=2)
        decoy = np.all(rgb == DECOY_RGB, axis=2)
        n_goal, n_decoy = int(goal.sum()), int(decoy.sum())
        if n_goal >= 20:
            score, px = goal_score(), np.argwhere(goal)[:, ::-1].astype(np.float32)
        elif n_decoy >= 20:
            score, px = 5.0, np.argwhere(decoy)[:, ::-1].astype(np.float32)
        else:
            score, px = 0.0, np.zeros((0, 2), np.float32)
        if not use_gate:
            ungated.append(score)
        px = px[:: max(1, len(px) // 40)]
        return ReIDResult(score, Matches.empty(), px.copy(), px, 0.0, 0.0, gate_score=float(n_goal + 0.5 * n_decoy))

    agent.reid.compare = compare
    return agent, ungated
