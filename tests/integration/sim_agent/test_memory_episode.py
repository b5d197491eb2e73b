"""The memory of a home across two goals in the real simulator, with the real matcher (XFeat and
LighterGlue on stored float16 descriptors): a goal seen during the first goal's search is found
from memory at the second goal's start and reached without looking around or exploring."""

import math
from dataclasses import replace

import numpy as np

from agent.config import load_agent_config
from agent.memory import HomeMemory, InHomeFrame
from agent.policy import ModIINAgent
from agent.types import Action, Pose2D
from sim.backend import SimBackend
from sim.goals import sample_goal_images
from sim.simple_homes import box_object, room_home
from sim.world import SimWorld


def test_a_goal_seen_during_the_last_search_is_found_from_memory_and_reached():
    home = room_home(
        6.0,
        4.0,
        objects=[
            box_object(0, "couch", (5.0, 2.0), (0.8, 1.6, 0.8), material="fabric"),
            box_object(1, "chair", (1.0, 2.0), (0.6, 0.6, 0.9), material="wood"),
        ],
    )
    world = SimWorld(home)
    try:
        cfg = load_agent_config("sim")
        cfg = replace(cfg, reid=replace(cfg.reid, num_threads=1))
        couch, chair = sample_goal_images(world, 0, 1, 1)[0], sample_goal_images(world, 1, 1, 2)[0]
        memory = HomeMemory(cfg.memory)
        # goal A, the couch behind the robot: its look-around (12 turns) sees the chair
        start = Pose2D(3.0, 2.0, math.pi)
        a = SimBackend(world, couch.rgb, start, goal_instance_id=0, max_steps=12)
        agent = ModIINAgent(cfg, home_memory=memory)
        obs = a.reset()
        agent.reset(obs.goal_image)
        while not a.done:
            a.apply(agent.act(obs))
            if not a.done:
                obs = a.observe()
        assert len(memory) >= 3 and memory.goals[0].steps == 12

        # goal B, the chair, from where A ended; its backend's poses start again, put back in A's frame
        b = SimBackend(world, chair.rgb, a.pose_world, goal_instance_id=1, max_steps=40)
        framed = InHomeFrame(b, a.pose_world.relative_to(start))
        agent = ModIINAgent(cfg, matcher=agent.reid.matcher if agent.reid else None, home_memory=memory)
        obs = framed.reset()
        agent.reset(obs.goal_image)
        # before any new frame: a candidate from remembered views at the chair (2 m ahead of A's start)
        cands = agent._evaluate(agent.localiser.candidates(agent.grid, agent.tau))
        assert cands and all(v.step < 0 for v in cands[0].views)
        assert math.dist(cands[0].cluster.centroid_xy_m, (2.0, 0.0)) < 0.8
        assert memory.goals[1].recalled_views >= 1
        modes = []
        while not b.done:
            action = agent.act(obs)
            assert agent.last_record is not None
            modes.append(agent.last_record.mode)
            framed.apply(action)
            if not b.done:
                obs = framed.observe()
        m = b.result()
        assert modes[0] in ("approach", "verify") and not {"look_around", "explore"} & set(modes), modes
        assert action == Action.STOP and m is not None and m.success, (modes, m)
        assert np.isfinite(memory.size_bytes) and memory.summary()["goals"][1]["final_event"] == "stop_at_goal"
    finally:
        world.close()
