"""The second look when exploration is exhausted (policy.exhausted_recheck_frames, agent/shortlist.py)."""

import math

import numpy as np
import pytest

from agent.events import Context
from agent.modes import Mode
from agent.shortlist import FrameShortlist
from agent.types import Pose2D
from tests.helpers.agent_runs import painted_agent
from tests.helpers.agent_scenes import SMALL_INTRINSICS, PaintedWorld, observation, two_rooms


def _obs(x, y, yaw_deg, step, value=0):
    rgb = np.full((SMALL_INTRINSICS.height_px, SMALL_INTRINSICS.width_px, 3), value, np.uint8)
    return observation([], Pose2D(x, y, math.radians(yaw_deg)), rgb=rgb, step=step)


def test_the_shortlist_keeps_the_best_frames_one_per_pose_best_first():
    s = FrameShortlist(3)
    assert s.offer(_obs(0, 0, 0, 0), 5.0)
    assert s.offer(_obs(1, 0, 0, 1), 9.0)
    assert s.offer(_obs(2, 0, 0, 2), 1.0)
    assert not s.offer(_obs(3, 0, 0, 3), 0.5)  # below the worst of a full list
    assert s.offer(_obs(4, 0, 0, 4), 7.0)  # pushes out the 1.0
    # the same pose again (a rescan turning on the spot): the better frame stays
    assert not s.offer(_obs(1.01, 0, 1, 5), 8.0)
    assert s.offer(_obs(0, 0, 0, 6), 6.0)  # replaces step 0 (5.0) at its pose
    assert len(s) == 3
    taken = s.take()
    assert [(r, o.step) for r, o in taken] == [(9.0, 1), (7.0, 4), (6.0, 6)]
    assert len(s) == 0 and s.take() == []


def test_the_shortlist_copies_the_frames_and_can_be_off():
    o = _obs(0, 0, 0, 0, value=7)
    s = FrameShortlist(2)
    s.offer(o, 1.0)
    o.rgb[:] = 99  # a backend reusing its buffer
    o.depth_m[:] = 0.0
    ((_, kept),) = s.take()
    assert int(kept.rgb.max()) == 7 and float(kept.depth_m.max()) > 0.0
    off = FrameShortlist(0)
    assert not off.offer(o, 100.0) and len(off) == 0
    with pytest.raises(ValueError):
        FrameShortlist(-1)


def run_exhausted(frames, **policy):
    """The two-room world of the tests below: (decisions with records, world, ungated scores).
    The fresh map is off: the second look is what these tests are about."""
    policy.setdefault("fresh_map_min_steps_left", 0)
    boxes, goal, decoy = two_rooms()
    world = PaintedWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal, decoy=decoy)
    second_look = {"taken": False}
    # 20 wherever it is seen while exploring; after the second look, 60 from within 2.6 m
    agent, ungated = painted_agent(
        world,
        lambda: 60.0 if second_look["taken"] and world.distance_to_goal() <= 2.6 else 20.0,
        exhausted_recheck_frames=frames,
        **policy,
    )
    steps = []
    obs = world.observe()
    agent.reset(obs.goal_image)
    for _ in range(900):
        action = agent.act(obs)
        d, rec = agent.last_decision, agent.last_record
        steps.append((d, rec))
        second_look["taken"] |= d.has(Context.SECOND_LOOK)
        world.apply(action)
        if d.mode in (Mode.STOPPED, Mode.EXHAUSTED):
            break
        obs = world.observe()
    return steps, world, ungated


def test_exhausted_with_nothing_found_the_second_look_finds_the_goal_and_stops_there():
    """The goal scores 20 wherever the robot sees it while exploring (never tau/2): exploration
    ends with no candidate. Without the switch the robot stops where it stands; with it, the kept
    frames are scored again with the full matcher, their matches form candidates (the goal's
    first: it scores best), and the verify ring confirms the goal (60 from within 2.6 m)."""
    steps, world, ungated = run_exhausted(0)
    last, rec = steps[-1]
    assert last.mode == Mode.EXHAUSTED and not rec.candidates
    assert world.distance_to_goal() > 1.0
    assert not any(d.has(Context.SECOND_LOOK) for d, _ in steps)

    ungated.clear()
    steps, world, ungated = run_exhausted(8)
    second = [d for d, _ in steps if d.has(Context.SECOND_LOOK)]
    assert len(second) == 1
    # the kept frames were scored once more, without the gate, and the goal's formed a candidate
    (note,) = [n for n in second[0].context if n.context == Context.SECOND_LOOK]
    assert note.facts["kept"] == 8 and note.facts["added"] >= 1 and note.facts["best"] == 20.0
    assert 20.0 in ungated[:8]
    i = next(k for k, (d, _) in enumerate(steps) if d is second[0])
    assert not any(s == "potential" for _, r in steps[:i] for s in (c.state for c in r.candidates))
    assert any(c.state == "potential" for c in steps[i][1].candidates)
    assert second[0].candidate is not None
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert any(d.has(Context.RING_CONFIRMED) for d, _ in steps[i:])


def test_with_a_fresh_map_due_the_second_look_comes_first():
    """Exploration ends with budget left and no candidate: the fresh map is due (nothing worth going
    to), but the kept frames are looked at again first, and here they hold the goal: the robot
    stops at it and the map is never started again."""
    steps, world, _ = run_exhausted(8, fresh_map_min_steps_left=250)
    i = next(k for k, (d, _) in enumerate(steps) if d.has(Context.SECOND_LOOK))
    assert steps[i - 1][0].mode == Mode.RESCAN
    assert not any(d.has(Context.FRESH_MAP) for d, _ in steps)
    last, _ = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
