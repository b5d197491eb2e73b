"""A real PyBullet episode end to end: SimBackend + the shortest-path oracle agent."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agent.types import MAX_STEPS, Action, Backend, BackendError, Observation, Pose2D
from sim.backend import SimBackend
from sim.episodes import load_episode_set
from sim.oracle_agent import OracleAgent
from sim.world import SimWorld


def test_oracle_solves_an_episode(small_episode_set: Path) -> None:
    es = load_episode_set(small_episode_set)
    episode = es.episodes[0]
    world = SimWorld.from_seed(episode.scene_seed)
    try:
        backend = SimBackend.for_episode(world, episode, es.goal_image_path(episode))
        assert isinstance(backend, Backend)
        agent = OracleAgent(backend.oracle)
        obs = backend.reset()
        assert isinstance(obs, Observation) and obs.pose == Pose2D(0.0, 0.0, 0.0) and obs.step == 0
        assert obs.rgb.shape == (640, 360, 3) and obs.depth_m.shape == (640, 360)
        assert obs.goal_image.shape == (512, 512, 3)
        agent.reset(obs.goal_image)
        start = backend.pose_world
        while True:
            action = agent.act(obs)
            assert agent.last_record is not None and agent.last_record.action == action
            backend.apply(action)
            if backend.done:
                break
            obs = backend.observe()
            # the observed pose is the world pose seen from the start
            expected = backend.pose_world.relative_to(start)
            assert math.isclose(obs.pose.x_m, expected.x_m, abs_tol=1e-9)
        m = backend.result()
        assert m is not None and m.success and m.called_stop and m.steps < MAX_STEPS
        assert m.spl >= 0.8 and m.ne_m < 0.15
        assert m.path_length_m == pytest.approx(
            0.25
            * sum(
                1
                for a, p, q in zip(backend.actions, backend.trajectory_world, backend.trajectory_world[1:])
                if a == Action.MOVE_FORWARD and p != q
            )
        )
        with pytest.raises(BackendError) as exc:
            backend.apply(Action.MOVE_FORWARD)
        assert exc.value.reason == "episode_over"
        # the oracle sees the goal in the last frame's segmentation or at least knows where it is
        assert backend.oracle.goal_mask().shape == (640, 360)
        assert backend.oracle.goal_position_world is not None
    finally:
        world.close()


def test_free_start_with_a_known_target_is_scored_and_budget_ends_it() -> None:
    world = SimWorld.from_seed(100000000)
    try:
        inst = world.home.instances[0]
        grid = world.navigable_grid(0.05)
        i, j = np.argwhere(grid.navigable)[len(np.argwhere(grid.navigable)) // 2]
        x, y = grid.ij_to_xy([[i, j]])[0]
        goal = np.zeros((100, 80, 3), np.uint8)
        backend = SimBackend(world, goal, Pose2D(float(x), float(y), 0.0), goal_instance_id=inst.object_id, max_steps=5)
        backend.reset()
        for _ in range(5):
            backend.apply(Action.TURN_LEFT)
        assert backend.done and backend.stop_reason == "max_steps"
        m = backend.result()
        assert m is not None and not m.success and m.max_steps_reached and m.path_length_m == 0.0
        unscored = SimBackend(world, goal, Pose2D(float(x), float(y), 0.0))
        unscored.reset()
        unscored.apply(Action.STOP)
        assert unscored.result() is None and not unscored.oracle.goal_mask().any()
    finally:
        world.close()
