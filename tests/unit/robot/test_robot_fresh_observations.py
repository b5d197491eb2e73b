"""Every observation belongs to its step (issue 12, part 1), against the fake robot in its
faithful mode: images grabbed, then the pose read, then compression, then the step stamped
at send time, while the base keeps moving (stretch_ai's bridge order).

An observation is *wrong for its step* when its depth disagrees with a render at the pose
it reports (stale images), or when the pose it reports is not where the robot stands after
the step (images and pose both from before the motion ended). The renders are exact here
(``BoxWorld`` is analytic), so no tolerance beyond the depth codec's is needed.

Issue 30 (the last section): the same against the fake's non-blocking mode, which echoes a
move's step at once and reports ``at_goal`` only when the base has arrived (stretch_ai's
MuJoCo server), with a motion that never arrives, and the blocking mode unchanged.
"""

from __future__ import annotations

import logging
import math
import re
import time

import numpy as np
import pytest

from agent.types import Action, BackendError, Observation, Pose2D
from robot.fake_server import FakeKnobs, FakeStretch
from robot.fake_world import BoxWorld
from robot.protocol import RobotState, parse_state

FWD, LEFT, RIGHT = Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT
# a room with a pillar, so turns change the depth image (a level camera's floor does not)
WORLD = BoxWorld(start_world=Pose2D(-1.0, 0.3, 0.4), pillars=((1.5, -0.5, 0.3),))
ACTIONS = [FWD, LEFT, FWD, RIGHT, RIGHT, LEFT, FWD, LEFT]


def wrong_for_its_step(fake: FakeStretch, start_world: Pose2D, obs: Observation) -> str | None:
    """Why ``obs`` is not the robot's view after the step it answers (None when it is)."""
    reported_world = start_world.compose(obs.pose)
    truth = fake.pose_world  # the robot stands still after the acknowledgement
    yaw_err_deg = math.degrees(abs(math.remainder(reported_world.yaw_rad - truth.yaw_rad, 2 * math.pi)))
    if reported_world.distance_to(truth) > 1e-3 or yaw_err_deg > 0.1:
        return f"reported pose {reported_world} but the robot is at {truth}"
    _, depth = fake.world.render(reported_world, obs.camera_tilt_rad)
    valid = (depth > 0) & (obs.depth_m > 0)
    off = float(np.mean(np.abs(depth - obs.depth_m)[valid] > 0.05))
    if off > 0.01:  # the JPEG2000 millimetre codec stays far below 5 cm
        return f"{100 * off:.0f}% of depth pixels more than 5 cm from a render at the reported pose"
    return None


def run_moves(fake: FakeStretch, backend) -> list[str | None]:
    backend.reset()
    start = fake.pose_world
    verdicts = []
    for action in ACTIONS:
        backend.apply(action)
        verdicts.append(wrong_for_its_step(fake, start, backend.observe()))
    return verdicts


@pytest.mark.slow
def test_the_old_rule_takes_observations_from_before_the_move_ended(make_fake, make_backend) -> None:
    """The defect, reproduced: the first observation that echoes a step is taken."""
    fake = make_fake(WORLD)
    assert fake.knobs.faithful  # the default, as in `imgnav fake-stretch`
    verdicts = run_moves(fake, make_backend(fake, observations_after_echo=0))
    assert any(v is not None for v in verdicts), verdicts


@pytest.mark.slow
def test_observations_are_captured_after_the_acknowledgement(make_fake, make_backend) -> None:
    fake = make_fake(WORLD)
    backend = make_backend(fake)
    assert backend.config.observations_after_echo == 1
    verdicts = run_moves(fake, backend)
    assert verdicts == [None] * len(ACTIONS)


def test_observation_numbers_prove_the_order(make_fake, make_backend) -> None:
    """The observation taken for a step arrived after the first one that echoed it."""
    fake = make_fake(WORLD)
    backend = make_backend(fake)
    backend.reset()
    for action in (FWD, LEFT):
        backend.apply(action)
        step = backend.moves[-1].step
        backend.observe()
        first = backend._link.first_observation_echoing(step)
        assert first is not None and backend.last_observation_seq > first


def test_no_observation_after_the_acknowledgement_fails_clearly(make_fake, make_backend) -> None:
    fake = make_fake(WORLD)
    backend = make_backend(fake, observation_timeout_s=1.0)
    backend.reset()
    fake.knobs.observations_paused = True  # the camera stream stalls; state keeps coming
    backend.apply(FWD)  # arrival is judged from the state stream
    with pytest.raises(BackendError) as info:
        backend.observe()
    assert info.value.reason == "no_observation"
    assert "after the acknowledgement of step" in str(info.value) and "no observation has echoed it" in str(info.value)


@pytest.mark.slow
def test_the_idealised_fake_still_serves(make_fake, make_backend) -> None:
    fake = make_fake(WORLD, knobs=FakeKnobs(faithful=False))
    assert run_moves(fake, make_backend(fake)) == [None] * len(ACTIONS)


# --- RobotState: the bridge's state messages carry the step ---------------------------


def test_state_messages_carry_the_step(make_fake, make_backend) -> None:
    doc = " ".join((RobotState.__doc__ or "").split())
    assert "sends it in state messages as well as in observations" in doc
    state = parse_state({"base_pose": [0.0, 0.0, 0.0], "step": 7, "is_homed": True, "is_runstopped": False}, 0.0)
    assert state.step == 7
    fake = make_fake(WORLD, start_step=11)
    backend = make_backend(fake)
    backend.reset()  # posture 12, head 13
    backend.apply(FWD)  # 14
    assert backend.moves[-1].step == 14
    deadline = time.monotonic() + 10.0  # a state message sent after the echo carries it
    while backend._link.state.step != 14:
        assert time.monotonic() < deadline, backend._link.state
        time.sleep(0.01)


# --- arrival, not acknowledgement (issue 30): a server that echoes before the base arrives ----------------------------------------------------


@pytest.mark.slow
def test_non_blocking_server_no_stale_observations(make_fake, make_backend, caplog) -> None:
    """(a) The server echoes every move before the base arrives; no observation is stale."""
    # a quarter of the fake's default speeds: several observations per motion, as on a robot
    fake = make_fake(WORLD, knobs=FakeKnobs(nonblocking_nav=True, linear_speed_m_s=0.5, angular_speed_rad_s=1.5))
    backend = make_backend(fake)
    with caplog.at_level(logging.WARNING, logger="robot.backend"):
        verdicts = run_moves(fake, backend)
    stale = [v for v in verdicts if v is not None]
    assert stale == [], f"{len(stale)} of {len(verdicts)} stale: {stale}"
    # the server really did acknowledge early: observations echoing each step came while the
    # base moved (the old rule, the one after the first echo, would have taken one of them)
    assert all(m.acked_before_arrival for m in backend.moves)
    assert sum(m.observations_before_arrival >= 2 for m in backend.moves) >= len(ACTIONS) // 2, [
        m.observations_before_arrival for m in backend.moves
    ]
    warnings = [r.getMessage() for r in caplog.records if "before its base arrived" in r.getMessage()]
    assert len(warnings) == 1, warnings  # said once per run, not every step


def test_non_blocking_server_two_moves(make_fake, make_backend) -> None:
    """(a), fast: the observation after a move is the view where the base stopped."""
    fake = make_fake(WORLD, knobs=FakeKnobs(nonblocking_nav=True, linear_speed_m_s=1.0, angular_speed_rad_s=3.0))
    backend = make_backend(fake)
    backend.reset()
    start = fake.pose_world
    for action in (FWD, LEFT):
        backend.apply(action)
        report = backend.moves[-1]
        assert report.acked_before_arrival and not report.blocked
        # the client returned only after arrival: the base is where the goal says
        assert fake.pose_world.distance_to(report.goal_world) < 1e-6
        assert wrong_for_its_step(fake, start, backend.observe()) is None
        link = backend._link
        assert link.first_observation_arrived(report.step) > link.first_observation_echoing(report.step)
        assert backend.last_observation_seq > link.first_observation_arrived(report.step)


def test_non_blocking_server_without_at_goal_waits_for_the_base_to_stand_still(make_fake, make_backend) -> None:
    fake = make_fake(
        WORLD,
        knobs=FakeKnobs(nonblocking_nav=True, reports_at_goal=False, linear_speed_m_s=1.0, angular_speed_rad_s=3.0),
    )
    backend = make_backend(fake)
    backend.reset()
    start = fake.pose_world
    for action in (FWD, LEFT):
        backend.apply(action)
        assert fake.pose_world.distance_to(backend.moves[-1].goal_world) < 1e-6
        assert wrong_for_its_step(fake, start, backend.observe()) is None


def test_non_blocking_move_into_a_wall_is_reported_blocked(make_fake, make_backend) -> None:
    fake = make_fake(BoxWorld(start_world=Pose2D(2.7, 0.0, 0.0)), knobs=FakeKnobs(nonblocking_nav=True))
    backend = make_backend(fake)
    backend.reset()
    backend.apply(FWD)
    assert backend.moves[-1].blocked and not backend.moves[-1].acked_before_arrival
    assert 0.0 < backend.observe().pose.x_m < 0.25


def test_arrival_that_never_comes_ends_the_run_clearly(make_fake, make_backend, caplog) -> None:
    """(b) The base stalls halfway, at_goal stays false: the client gives up after its bound."""
    fake = make_fake(WORLD, knobs=FakeKnobs(nonblocking_nav=True, never_arrive=True))
    backend = make_backend(fake, arrival_timeout_s=0.8)
    backend.reset()
    with caplog.at_level(logging.ERROR, logger="robot.backend"), pytest.raises(BackendError) as info:
        backend.apply(FWD)
    assert info.value.reason == "no_arrival"
    text = str(info.value)
    assert "did not report that its base arrived within 0.8 s" in text and "arrival_timeout_s" in text
    assert "at_goal stayed false" in text and re.search(r"0\.1[23] m and 0 deg from the goal, standing still", text)
    assert any(r.getMessage() == text for r in caplog.records)  # in the log as well as to the caller
    assert backend.moves == []


def test_blocking_server_is_unchanged(make_fake, make_backend) -> None:
    """(c) The bridge's behaviour: arrival is reported with the echo, so the client waits for
    no more than before: the observation counted from is the first one echoing the step."""
    fake = make_fake(WORLD)
    assert not fake.knobs.nonblocking_nav  # the default, as the bridge
    backend = make_backend(fake)
    backend.reset()
    start = fake.pose_world
    for action in (FWD, LEFT):
        backend.apply(action)
        report = backend.moves[-1]
        assert not report.acked_before_arrival and report.observations_before_arrival == 0
        assert wrong_for_its_step(fake, start, backend.observe()) is None
        link = backend._link
        assert link.first_observation_arrived(report.step) == link.first_observation_echoing(report.step)
        assert backend.last_observation_seq - link.first_observation_echoing(report.step) == 1
