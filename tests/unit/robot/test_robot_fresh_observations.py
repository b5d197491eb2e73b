"""Every observation belongs to its step (issue 12, part 1), against the fake robot in its
faithful mode: images grabbed, then the pose read, then compression, then the step stamped
at send time, while the base keeps moving (stretch_ai's bridge order).

An observation is *wrong for its step* when its depth disagrees with a render at the pose
it reports (stale images), or when the pose it reports is not where the robot stands after
the step (images and pose both from before the motion ended). The renders are exact here
(``BoxWorld`` is analytic), so no tolerance beyond the depth codec's is needed.
"""

from __future__ import annotations

import math
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
