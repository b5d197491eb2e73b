"""Arrival, not acknowledgement (issue 30): ``ArrivalWatch`` on hand-built messages, and the
two small items (the README's timeouts, no negative zero in the reset log).

The client against the fake robot's non-blocking mode is in ``test_robot_fresh_observations``.
"""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import numpy as np
import pytest

from agent.types import Pose2D
from robot.arrival import ArrivalLimits, ArrivalWatch
from robot.config import StretchConfig
from robot.fake_world import BoxWorld
from robot.protocol import RawObservation, RobotState
from robot.reports import rounded

WORLD = BoxWorld(start_world=Pose2D(-1.0, 0.3, 0.4))
README = Path(__file__).resolve().parents[3] / "robot" / "README.md"

# --- ArrivalWatch on hand-built messages --------------------------------------------------

LIMITS = ArrivalLimits(
    arrival_timeout_s=5.0,
    settle_timeout_s=1.0,
    goal_tolerance_m=0.1,
    goal_tolerance_rad=0.2,
    still_window_s=0.3,
    still_tolerance_m=0.005,
    still_tolerance_rad=0.01,
)
GOAL = Pose2D(1.0, 0.0, 0.0)
START = Pose2D(0.75, 0.0, 0.0)
STEP = 7


def state(t: float, pose: Pose2D, at_goal: bool | None, step: int | None = STEP) -> RobotState:
    return RobotState(pose, at_goal, True, False, step, "navigation", t)


def obs(seq: int, at_goal: bool | None, failed: bool = False, step: int = STEP) -> RawObservation:
    empty = np.zeros(0, np.uint8)
    return RawObservation(empty, empty, np.eye(3), np.eye(4), START, step, failed, at_goal, 0.0, seq)


def watch() -> ArrivalWatch:
    return ArrivalWatch(STEP, GOAL, 10.0, LIMITS)


def test_a_blocking_robot_has_arrived_with_its_first_message_after_the_echo() -> None:
    w = watch()
    verdict = w.update(state(10.01, GOAL, True), obs(1, True), 10.01)
    assert verdict is not None and (verdict.kind, verdict.how, verdict.pose) == ("arrived", "at_goal", GOAL)
    assert not w.reported_not_arrived and w.observations_before_arrival == 0


def test_messages_from_before_the_step_are_not_evidence() -> None:
    w = watch()
    # an older step's at_goal, and a state received before the echo, say nothing about this move
    assert w.update(state(10.01, GOAL, True, step=STEP - 1), obs(1, True, step=STEP - 1), 10.01) is None
    assert w.update(state(9.99, GOAL, True, step=None), None, 10.02) is None
    verdict = w.update(state(10.03, GOAL, True, step=None), None, 10.03)
    assert verdict is not None and verdict.kind == "arrived"


def test_an_early_echo_is_waited_out_until_at_goal() -> None:
    w = watch()
    mid = Pose2D(0.9, 0.0, 0.0)  # within the goal tolerance, still moving: not arrival
    assert w.update(state(10.01, START, False), obs(1, False), 10.01) is None
    assert w.update(state(10.2, mid, False), obs(2, False), 10.2) is None
    assert w.update(state(10.3, mid, False), obs(2, False), 10.3) is None  # the same observation counts once
    # the state stream says so first; observation 3 was stamped before
    verdict = w.update(state(10.5, GOAL, True), obs(3, False), 10.5)
    assert verdict is not None and (verdict.kind, verdict.how) == ("arrived", "at_goal")
    assert verdict.after_s == pytest.approx(0.5)
    assert w.reported_not_arrived and w.observations_before_arrival == 3


def test_arrival_that_never_comes_ends_at_the_bound_and_says_where_the_base_is() -> None:
    w = watch()
    stalled = Pose2D(0.875, 0.0, 0.0)
    t = 10.0
    while (verdict := w.update(state(t, stalled, False), obs(1, False), t)) is None:
        t += 0.05
        assert t < 20.0
    assert verdict.kind == "no_arrival" and verdict.after_s == pytest.approx(LIMITS.arrival_timeout_s, abs=0.06)
    text = w.describe()
    assert "at_goal stayed false" in text and "0.12 m and 0 deg from the goal" in text and "standing still" in text


def test_at_goal_off_the_goal_is_a_failed_move_after_the_settle_time() -> None:
    w = watch()
    assert w.update(state(10.1, START, True), obs(1, True), 10.1) is None
    assert w.update(state(10.6, START, True), obs(2, True), 10.6) is None
    verdict = w.update(state(11.1, START, True), obs(3, True), 11.1)
    assert verdict is not None and (verdict.kind, verdict.how) == ("off_goal", "at_goal")


def test_a_failed_motion_ends_the_wait_where_the_state_says_the_base_stopped() -> None:
    w = watch()
    short = Pose2D(0.8, 0.0, 0.0)
    verdict = w.update(state(10.1, short, False), obs(1, False, failed=True), 10.1)
    assert verdict is not None and (verdict.kind, verdict.pose) == ("blocked", short)


def test_without_at_goal_the_base_must_stand_still_at_the_goal() -> None:
    w = watch()
    # standing still at the start (a controller that has not started yet) is not arrival
    for t in (10.05, 10.2, 10.4, 10.5):
        assert w.update(state(t, START, None), obs(1, None), t) is None
    assert w.update(state(10.6, Pose2D(0.9, 0.0, 0.0), None), obs(2, None), 10.6) is None
    for t in (10.7, 10.8, 10.9):
        assert w.update(state(t, GOAL, None), obs(3, None), t) is None  # still for less than the window
    verdict = w.update(state(11.0, GOAL, None), obs(4, None), 11.0)
    assert verdict is not None and (verdict.kind, verdict.how) == ("arrived", "still")
    assert not w.reports_at_goal


def test_without_at_goal_a_base_standing_still_off_the_goal_is_a_failed_move() -> None:
    w = watch()
    t = 10.05
    while (verdict := w.update(state(t, START, None), None, t)) is None:
        t += 0.05
        assert t < 13.0
    assert (verdict.kind, verdict.how) == ("off_goal", "still")
    assert t == pytest.approx(10.05 + LIMITS.still_window_s + LIMITS.settle_timeout_s, abs=0.06)


# --- the two small items -------------------------------------------------------------------


def test_readme_states_the_timeouts_of_the_code() -> None:
    text = " ".join(README.read_text().split())
    cfg = StretchConfig()
    for field in ("posture_timeout_s", "ack_timeout_s", "arrival_timeout_s"):
        match = re.search(rf"within (\d+) s \(`{field}`", text)
        assert match is not None, field
        assert float(match.group(1)) == getattr(cfg, field), field
    assert cfg.posture_timeout_s == 60.0


def test_no_negative_zero_in_the_reset_log(make_fake, make_backend, caplog) -> None:
    assert f"{rounded(-0.04, 1):.1f}" == "0.0" and f"{rounded(-0.0004, 3):+.3f}" == "+0.000"
    assert rounded(-0.06, 1) == -0.1
    fake = make_fake(WORLD)
    with caplog.at_level(logging.INFO, logger="robot.backend"):
        make_backend(fake).reset()
    (line,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("head camera")]
    assert "tilt 0.0 deg down" in line and "-0.0" not in line, line


def test_the_config_checks_the_new_bounds() -> None:
    for field in ("arrival_timeout_s", "still_window_s", "still_tolerance_m", "still_tolerance_rad"):
        with pytest.raises(ValueError, match=field):
            StretchConfig(**{field: 0.0})  # type: ignore[arg-type]
    assert math.isclose(StretchConfig().arrival_timeout_s, StretchConfig().ack_timeout_s)
