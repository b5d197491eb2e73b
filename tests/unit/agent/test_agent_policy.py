import math

import numpy as np
import pytest

from agent.config import AgentConfig, PolicyConfig, load_agent_config
from agent.configio import ConfigError, from_dict
from agent.policy import ModIINAgent
from agent.reid.identifier import ReIDConfig
from agent.types import Action, Agent, Pose2D
from tests.helpers.agent_runs import NoMatcher, oracle_config
from tests.helpers.agent_scenes import BoxWorld, room_walls, two_rooms


def run(agent, world, max_steps=300):
    obs = world.observe()
    agent.reset(obs.goal_image)
    for _ in range(max_steps):
        action = agent.act(obs)
        rec = agent.last_record
        assert rec is not None and rec.action == action
        world.apply(action)
        if action == Action.STOP:
            return rec
        obs = world.observe()
    return agent.last_record


def test_oracle_agent_finds_the_goal_in_the_other_room():
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
    agent = ModIINAgent(oracle_config(), oracle_reid=world.goal_visible, oracle_ego_mask=world.goal_mask)
    assert isinstance(agent, Agent)
    rec = run(agent, world)
    assert rec.action == Action.STOP and rec.mode == "stopped", (rec.mode, rec.reason)
    assert world.distance_to_goal() < 1.0
    assert len(rec.goal_points_xyz) > 0
    assert set(rec.timings_ms) >= {"mapping", "reid", "localisation", "planning", "total"}
    assert rec.map is not None and rec.map.goal.any()


def test_a_detection_is_trusted_so_a_false_positive_detection_wins():
    # a detection (score >= tau) confirms its candidate from any distance: only sub-tau evidence is
    # verified from the ring (test_agent_modes), so a re-ID false positive is stopped at
    boxes, goal, decoy = two_rooms()
    world = BoxWorld(boxes, Pose2D(0.0, -1.0, math.pi * 0.75), goal)
    agent = ModIINAgent(
        oracle_config(),
        oracle_reid=lambda obs: np.count_nonzero(world._ids == decoy) >= 20,
        oracle_ego_mask=lambda obs: world._ids == decoy,
    )
    rec = run(agent, world)
    assert rec.action == Action.STOP and world.distance_to_goal() > 2.0


def test_exhausted_exploration_is_a_reported_stop():
    world = BoxWorld(room_walls(-1.0, -1.0, 1.0, 1.0) + [(5, 5, 5.5, 5.5, 0.5)], Pose2D(), goal_box=4)
    agent = ModIINAgent(oracle_config(), oracle_reid=world.goal_visible, oracle_ego_mask=world.goal_mask)
    rec = run(agent, world, max_steps=100)
    assert rec.action == Action.STOP and rec.mode == "exhausted" and rec.planner_error


def test_matcher_agent_needs_tau_and_uses_injected_matcher():
    cfg = AgentConfig(reid=ReIDConfig(tau=5.0, gate=False), policy=PolicyConfig(look_around_turns=2))
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(), goal)
    agent = ModIINAgent(cfg, matcher=NoMatcher())
    obs = world.observe()
    agent.reset(obs.goal_image)
    assert agent.act(obs) == Action.TURN_LEFT
    rec = agent.last_record
    assert rec.reid_score == 0.0 and rec.reid_tau == 5.0 and not rec.goal_detected


def test_oracle_modes_need_their_callables():
    with pytest.raises(ValueError):
        ModIINAgent(oracle_config())


def test_deployment_configs_load_strictly():
    for name in ("sim", "stretch"):
        assert isinstance(load_agent_config(name), AgentConfig)
    with pytest.raises(ConfigError):
        from_dict(AgentConfig, {"policy": {"stop_radius": 1.0}})


def test_a_failed_forward_move_is_marked_and_not_repeated():
    """A curb too low for the obstacle layer (5 cm) but high enough to block the robot: the
    failed move leaves a collision mark, is never retried from the same pose, and the agent
    gets round the curb to the goal."""
    boxes, goal, _ = two_rooms()
    curb = (-1.2, -2.0, -1.1, -0.5, 0.05)
    world = BoxWorld(boxes + [curb], Pose2D(-1.5, -1.0, 0.0), goal)
    agent = ModIINAgent(
        oracle_config(look_around_turns=0), oracle_reid=world.goal_visible, oracle_ego_mask=world.goal_mask
    )
    obs = world.observe()
    agent.reset(obs.goal_image)
    forwards, failed, marked = [], 0, False
    rec = None
    for _ in range(400):
        action = agent.act(obs)
        rec = agent.last_record
        marked |= bool(rec.map is not None and rec.map.collision.any())
        before = world.pose
        world.apply(action)
        if action == Action.STOP:
            break
        if action == Action.MOVE_FORWARD:
            key = (round(rec.pose.x_m, 3), round(rec.pose.y_m, 3), round(rec.pose.yaw_rad, 3))
            assert key not in forwards, f"forward move repeated from {key}"
            forwards.append(key)
            failed += world.pose == before
        obs = world.observe()
    assert failed >= 1 and marked
    assert rec.action == Action.STOP and rec.mode == "stopped" and world.distance_to_goal() < 1.0


def test_given_up_frontiers_are_forgiven_before_exhaustion_but_rejected_candidates_are_not():
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
    # re-ID fires within 3 m only: the goal must be explored to, through the door
    agent = ModIINAgent(
        oracle_config(),
        oracle_reid=lambda o: world.goal_visible(o) and world.distance_to_goal() < 3.0,
        oracle_ego_mask=world.goal_mask,
    )
    obs = world.observe()
    agent.reset(obs.goal_image)
    world.apply(agent.act(obs))
    # every frontier given up (as if each had been reached or had stalled), and one rejected
    # goal candidate in room A's corner
    agent.grid.layers.frontier_blacklist[:] = True
    rejected = agent.grid.cell_of(Pose2D(-2.5, -1.5))
    agent.grid.layers.blacklist[rejected] = True
    modes = []
    for _ in range(400):
        obs = world.observe()
        action = agent.act(obs)
        modes.append(agent.last_record.mode)
        world.apply(action)
        if action == Action.STOP:
            break
    assert "rescan" in modes and modes[-1] == "stopped", modes[-1]
    assert world.distance_to_goal() < 1.0
    assert agent.grid.layers.blacklist[agent.grid.cell_of(Pose2D(-2.5, -1.5))]
