"""``StretchBackend.map_frame`` against the fake robot (analytic box room): the run's start and the
last pose in the robot's map frame, a move under way, the runstops seen and the bridge's steps,
while the agent's observations stay relative to the run's start; and the fake's hand push and
localisation restart that the console's memory checks (console/robot_memory.py) must notice."""

from __future__ import annotations

import math
import threading

import pytest

from agent.types import Action, BackendError, Pose2D
from robot.fake_world import BoxWorld
from tests.helpers.polling import poll

START = Pose2D(0.5, 0.3, 0.4)


def close_to(a: Pose2D, b: Pose2D, tol_m: float = 1e-6, tol_rad: float = 1e-6) -> bool:
    return a.distance_to(b) <= tol_m and abs(math.remainder(a.yaw_rad - b.yaw_rad, 2 * math.pi)) <= tol_rad


def test_the_map_frame_report_follows_the_run_without_changing_what_the_agent_gets(make_fake, make_backend) -> None:
    fake = make_fake(start_step=41)
    backend = make_backend(fake)
    before = backend.map_frame
    assert (before.start_map, before.last_map, before.first_step, before.last_step) == (None, None, None, None)
    obs = backend.reset()
    report = backend.map_frame
    assert close_to(report.start_map, START)  # the robot's own map-frame pose
    assert report.first_step == 41 and report.last_step == 43  # the echo at connect; posture and head since
    assert not report.runstop_seen and report.moving_to is None
    assert close_to(obs.pose, Pose2D())  # the agent's poses start at its own start, as before

    backend.apply(Action.MOVE_FORWARD)
    obs = backend.observe()
    backend.apply(Action.TURN_LEFT)
    obs = backend.observe()
    end = START.compose(Pose2D(0.25, 0.0, 0.0)).compose(Pose2D(0.0, 0.0, math.radians(30)))
    report = backend.map_frame
    assert close_to(report.last_map, end, 0.02, 0.02) and close_to(fake.pose_world, end, 0.02, 0.02)
    assert close_to(obs.pose, report.last_map.relative_to(START), 0.02, 0.02)  # start-relative
    assert close_to(report.start_map, START) and report.moving_to is None and report.last_step == 45

    backend.close()
    closed = backend.map_frame  # kept after the link is gone
    assert closed.start_map == report.start_map and closed.last_step == 45
    assert closed.last_map is not None and close_to(closed.last_map, report.last_map, 1e-3, 1e-3)  # standing still


def test_a_runstop_pressed_and_released_between_steps_is_seen(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake)
    backend.reset()
    backend.apply(Action.TURN_LEFT)
    backend.observe()
    assert backend.map_frame.runstopped_states == 0
    fake.knobs.runstopped = True  # between two of the backend's own checks: only the link sees it
    poll(lambda: backend.map_frame.runstopped_states, lambda n: n > 0, 10, "a runstopped state message")
    fake.knobs.runstopped = False
    poll(lambda: backend._link.state, lambda st: st is not None and not st.is_runstopped, 10, "released")
    seen = backend.map_frame.runstopped_states
    backend.apply(Action.TURN_RIGHT)  # the run goes on: the runstop was released
    assert backend.map_frame.runstop_seen and backend.map_frame.runstopped_states >= seen


def test_a_move_the_run_ends_during_is_reported_with_its_goal(make_fake, make_backend) -> None:
    fake = make_fake()
    fake.knobs.linear_speed_m_s = 0.05  # 5 s for the 0.25 m move: it is still under way when cancelled
    backend = make_backend(fake, ack_timeout_s=60.0)
    backend.reset()

    def cancel_once_moving() -> None:
        poll(lambda: fake.pose_world.distance_to(START), lambda d: d > 0.005, 20, "the base moving")
        backend.cancel()

    t = threading.Thread(target=cancel_once_moving, daemon=True)
    t.start()
    with pytest.raises(BackendError) as err:
        backend.apply(Action.MOVE_FORWARD)
    t.join()
    assert err.value.reason == "cancelled"
    goal = START.compose(Pose2D(0.25, 0.0, 0.0))
    report = backend.map_frame
    assert report.moving_to is not None and close_to(report.moving_to, goal)
    assert report.last_map is not None and report.last_map.distance_to(goal) > 0.01  # still on its way


def test_the_fakes_hand_push_and_localisation_restart(make_fake, make_backend) -> None:
    fake = make_fake(world=BoxWorld(start_world=START))
    backend = make_backend(fake)
    backend.reset()
    backend.close()
    pushed = Pose2D(-0.5, -0.5, 2.0)
    fake.push_base(pushed)
    with pytest.raises(ValueError):
        fake.push_base(Pose2D(10.0, 0.0, 0.0))  # outside the room
    second = make_backend(fake)
    second.reset()
    assert close_to(second.map_frame.start_map, pushed)  # the localisation followed the push
    second.close()

    fake.reset_localisation()  # a new map frame at the base: the reported pose is the origin
    third = make_backend(fake)
    third.reset()
    assert close_to(third.map_frame.start_map, Pose2D())
    third.apply(Action.MOVE_FORWARD)  # absolute goals are read in the new frame
    assert close_to(third.map_frame.last_map, Pose2D(0.25, 0.0, 0.0), 0.02, 0.02)
    assert close_to(fake.pose_world, pushed.compose(Pose2D(0.25, 0.0, 0.0)), 0.02, 0.02)
