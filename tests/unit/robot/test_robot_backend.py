"""The Stretch client against the fake robot (analytic box room) on loopback.

No sleeps as synchronisation: the client's own waits poll with deadlines; where a test
has to wait for the fake to reach a state it polls with a deadline too.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from agent.types import Action, BackendError, Pose2D
from robot.fake_server import NAV_POSTURE_TILT_RAD, FakeKnobs
from robot.fake_world import BoxWorld
from tests.helpers.polling import poll

FWD, LEFT, RIGHT, STOP = Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT, Action.STOP


def run_loop(
    backend, actions, at_step: int | None = None, do: Callable[[], None] | None = None
) -> tuple[str | None, int]:
    """The project's loop with a scripted agent, calling ``do()`` just before action ``at_step``
    is applied; returns (failure reason or None, actions applied)."""
    applied = 0
    try:
        backend.reset()
        for i, action in enumerate(actions):
            if i == at_step and do is not None:
                do()
            backend.apply(action)
            applied += 1
            if action == STOP:
                break
            backend.observe()
        return None, applied
    except BackendError as exc:
        return exc.reason, applied
    finally:
        backend.close()


def test_reset_posture_head_and_first_observation(make_fake, make_backend) -> None:
    fake = make_fake(start_step=41)
    backend = make_backend(fake)
    obs = backend.reset()
    # step counter seeded from the robot's echo: posture 42, head 43
    assert [a.get("step") for a in fake.actions] == [42, 43]
    assert fake.actions[0] == {"posture": "navigation", "step": 42}
    assert fake.actions[1] == {"head_to": [0.0, -0.0], "step": 43}
    assert obs.pose == Pose2D(0.0, 0.0, 0.0) or obs.pose.distance_to(Pose2D()) < 1e-9
    assert obs.step == 0
    assert obs.rgb.shape == (640, 360, 3) and obs.depth_m.shape == (640, 360) and obs.depth_m.dtype == np.float32
    assert (obs.intrinsics.width_px, obs.intrinsics.height_px) == (360, 640)
    assert obs.intrinsics.hfov_deg == pytest.approx(42.0, abs=0.01)
    assert obs.camera_height_m == pytest.approx(1.31)
    assert obs.camera_tilt_rad == pytest.approx(0.0, abs=math.radians(1))  # levelled after the posture
    assert obs.goal_image is backend.goal_image
    # the first observation matches what the fake renders at its pose, level
    rgb, depth = fake.world.render(fake.pose_world, 0.0)
    assert np.abs(obs.depth_m - depth).max() < 0.02
    assert np.abs(obs.rgb.astype(int) - rgb).mean() < 10


@pytest.mark.slow
def test_actions_move_the_robot_and_poses_are_relative_to_the_start(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake)
    backend.reset()
    start = fake.pose_world
    for action in (FWD, LEFT, FWD, RIGHT, RIGHT, FWD):
        backend.apply(action)
        obs = backend.observe()
        expected = fake.pose_world.relative_to(start)
        assert obs.pose.distance_to(expected) < 1e-6
        assert abs(math.remainder(obs.pose.yaw_rad - expected.yaw_rad, 2 * math.pi)) < 1e-6
    assert obs.step == 6
    xyt = [a for a in fake.actions if "xyt" in a]
    assert len(xyt) == 6 and all(a["nav_relative"] is False and a["nav_blocking"] is True for a in xyt)
    steps = [a["step"] for a in fake.actions]
    assert steps == sorted(steps) and len(set(steps)) == len(steps)
    # the path: forward 0.25, left 30, forward 0.25, right 60, forward 0.25 (start frame)
    p = obs.pose
    x = 0.25 + 0.25 * math.cos(math.radians(30)) + 0.25 * math.cos(math.radians(-30))
    y = 0.25 * math.sin(math.radians(30)) + 0.25 * math.sin(math.radians(-30))
    assert (p.x_m, p.y_m) == (pytest.approx(x, abs=1e-6), pytest.approx(y, abs=1e-6))
    assert all(not m.blocked for m in backend.moves) and all(m.resends == 0 for m in backend.moves)
    backend.apply(STOP)
    assert len([a for a in fake.actions if "xyt" in a]) == 6  # STOP sends nothing


def test_a_move_into_a_wall_stops_short_and_is_reported_blocked(make_fake, make_backend) -> None:
    world = BoxWorld(start_world=Pose2D(2.7, 0.0, 0.0))  # wall at x = 3.0, robot radius 0.17
    fake = make_fake(world)
    backend = make_backend(fake)
    backend.reset()
    backend.apply(FWD)
    obs = backend.observe()
    report = backend.moves[-1]
    assert report.blocked
    assert 0.0 < obs.pose.x_m < 0.25 and fake.pose_world.x_m <= 3.0 - 0.17
    backend.apply(FWD)  # pressed against the wall: no motion at all, still not a failure
    assert backend.observe().pose.distance_to(obs.pose) < 1e-6
    assert backend.moves[-1].blocked


def test_the_echo_may_come_only_from_observations(make_fake, make_backend) -> None:
    """Older bridge versions sent ``step`` only in observations (today's send it in state too)."""
    fake = make_fake(knobs=FakeKnobs(state_has_step=False), start_step=5)
    backend = make_backend(fake)
    reason, applied = run_loop(backend, [FWD, LEFT, STOP])
    assert reason is None and applied == 3
    assert [a["step"] for a in fake.actions] == [6, 7, 8, 9]


@pytest.mark.slow
def test_slow_moves_within_the_ack_timeout_succeed(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(linear_speed_m_s=0.15, angular_speed_rad_s=0.4))  # ~1.7 s and ~1.3 s
    backend = make_backend(fake, ack_timeout_s=6.0)
    reason, applied = run_loop(backend, [FWD, LEFT, STOP])
    assert reason is None and applied == 3
    assert fake.pose_world.distance_to(Pose2D(0.5, 0.3, 0.4)) == pytest.approx(0.25, abs=1e-6)


# --- faults: each ends the run with its reason -----------------------------------------


def test_runstopped_robot_is_refused_before_anything_is_sent(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(runstopped=True))
    reason, applied = run_loop(make_backend(fake), [FWD])
    assert (reason, applied) == ("runstopped", 0)
    assert fake.actions == []


def test_unhomed_robot_is_refused_before_anything_is_sent(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(homed=False))
    reason, applied = run_loop(make_backend(fake), [FWD])
    assert (reason, applied) == ("not_homed", 0)
    assert fake.actions == []


def test_runstop_between_steps_refuses_the_next_move(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake)

    def press_runstop() -> None:
        fake.knobs.runstopped = True
        poll(lambda: backend._link.state.is_runstopped)  # the client has seen it

    reason, applied = run_loop(backend, [FWD, LEFT, FWD, FWD], 2, press_runstop)
    assert (reason, applied) == ("runstopped", 2)
    assert len([a for a in fake.actions if "xyt" in a]) == 2


def test_runstop_during_a_move_ends_the_wait_at_once(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(linear_speed_m_s=0.05))  # a 5 s move
    backend = make_backend(fake, ack_timeout_s=60.0)

    def press_runstop_mid_move() -> None:
        import threading

        def later() -> None:
            poll(lambda: fake.pose_world.distance_to(Pose2D(0.5, 0.3, 0.4)) > 0.02)
            fake.knobs.runstopped = True

        threading.Thread(target=later, daemon=True).start()

    reason, applied = run_loop(backend, [FWD], 0, press_runstop_mid_move)
    assert (reason, applied) == ("runstopped", 0)  # not ack_timeout: the wait noticed the runstop
    assert not any("xyt" in a for a in fake.actions)  # the move is frozen on the robot, never echoed


def test_silence_is_a_disconnect(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake)

    reason, applied = run_loop(backend, [FWD, FWD, FWD], 1, lambda: setattr(fake.knobs, "silent", True))
    assert (reason, applied) == ("disconnected", 1)


def test_silence_during_a_move_is_a_disconnect_not_an_ack_timeout(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(linear_speed_m_s=0.05))
    backend = make_backend(fake, ack_timeout_s=60.0)
    backend.reset()
    fake.knobs.silent = True
    with pytest.raises(BackendError) as info:
        backend.apply(FWD)
    assert info.value.reason == "disconnected" and "no state message" in str(info.value)
    backend.close()


@pytest.mark.slow
def test_dropped_acknowledgements_time_out(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake, ack_timeout_s=1.5, resend_interval_s=0.5)

    reason, applied = run_loop(backend, [FWD, FWD, FWD], 1, lambda: setattr(fake.knobs, "drop_acks", True))
    assert (reason, applied) == ("ack_timeout", 1)
    # re-sends are the same absolute goal with the same step: the robot moved only once
    assert len([a for a in fake.actions if "xyt" in a]) == 2
    assert fake.pose_world.distance_to(Pose2D(0.5, 0.3, 0.4)) == pytest.approx(0.5, abs=1e-6)


def test_a_move_slower_than_the_ack_timeout_times_out(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(linear_speed_m_s=0.05))  # 5 s
    reason, applied = run_loop(make_backend(fake, ack_timeout_s=1.0), [FWD])
    assert (reason, applied) == ("ack_timeout", 0)


def test_no_robot_at_the_address_is_a_disconnect(make_backend, make_fake) -> None:
    fake = make_fake()
    fake.close()  # ports were bound and released: nobody publishes there now
    reason, applied = run_loop(make_backend(fake, connect_timeout_s=1.0), [FWD])
    assert (reason, applied) == ("disconnected", 0)


def test_head_that_never_levels_fails_the_reset(make_fake, make_backend) -> None:
    fake = make_fake(knobs=FakeKnobs(head_speed_rad_s=0.0))  # head stuck where the posture left it
    reason, _ = run_loop(make_backend(fake, head_timeout_s=1.0), [FWD])
    assert reason == "head_failed"
    assert fake.tilt_rad == pytest.approx(math.radians(20.0))
    assert NAV_POSTURE_TILT_RAD > 0


def test_close_is_idempotent_and_ends_the_backend(make_fake, make_backend) -> None:
    fake = make_fake()
    backend = make_backend(fake)
    backend.reset()
    backend.close()
    backend.close()
    with pytest.raises(BackendError) as info:
        backend.apply(FWD)
    assert info.value.reason == "closed"
    with pytest.raises(BackendError):
        backend.reset()


def test_reset_measures_the_head_camera_mount(make_fake, make_backend) -> None:
    backend = make_backend(make_fake())
    backend.reset()
    offset = backend.camera_offset
    assert offset is not None and offset.distance_to(Pose2D()) < 1e-6 and abs(offset.yaw_rad) < 1e-6
