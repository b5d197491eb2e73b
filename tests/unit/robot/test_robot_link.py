"""The link refuses code-running pickles from the network, and the fake robot behaves like the bridge."""

from __future__ import annotations

import pickle
import threading
import time

import numpy as np
import pytest
import zmq

from agent.types import BackendError, Pose2D
from robot.backend import StretchBackend
from robot.config import StretchConfig
from robot.link import BridgeLink
from robot.protocol import move_message
from tests.helpers.pickles import RunsShell


class RoguePublisher:
    """Binds an observation and a state port and publishes the same evil pickle on both."""

    def __init__(self, payload: bytes) -> None:
        self.ctx = zmq.Context()
        self.socks = []
        self.ports = []
        for _ in range(2):
            sock = self.ctx.socket(zmq.PUB)
            sock.setsockopt(zmq.LINGER, 0)
            sock.bind("tcp://127.0.0.1:*")
            self.ports.append(int(sock.getsockopt(zmq.LAST_ENDPOINT).decode().rsplit(":", 1)[1]))
            self.socks.append(sock)
        self.payload = payload
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.wait(0.02):
            for sock in self.socks:
                sock.send(self.payload)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        for sock in self.socks:
            sock.close(linger=0)
        self.ctx.term()


def test_a_robot_sending_a_code_running_pickle_is_refused_and_the_run_fails_cleanly(tmp_path) -> None:
    marker = tmp_path / "pwned"
    payload = pickle.dumps({"base_pose": np.zeros(3), "evil": RunsShell(str(marker))}, protocol=4)
    rogue = RoguePublisher(payload)
    try:
        obs_port, state_port = rogue.ports
        config = StretchConfig(obs_port=obs_port, state_port=state_port, action_port=1, connect_timeout_s=1.5)
        backend = StretchBackend(np.zeros((8, 8, 3), np.uint8), config)
        with pytest.raises(BackendError) as info:
            backend.reset()
        assert info.value.reason == "disconnected"
        assert "refused" in str(info.value) and "posix.system" in str(info.value)
        assert backend._link.counts["refused"] > 0 and backend._link.counts["state"] == 0
        backend.close()
    finally:
        rogue.close()
    assert not marker.exists()


def _send_raw(port: int, message: dict, until) -> None:
    """Publish ``message`` to the fake's action port until ``until()`` (PUB/SUB joins late)."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(f"tcp://127.0.0.1:{port}")
    deadline = time.monotonic() + 10
    try:
        while not until():
            assert time.monotonic() < deadline, "the fake did not react"
            sock.send(pickle.dumps(message, protocol=4))
            time.sleep(0.05)
    finally:
        sock.close(linger=0)
        ctx.term()


def test_fake_drops_actions_without_a_newer_step(make_fake) -> None:
    fake = make_fake(start_step=10)
    goal = Pose2D(0.75, 0.3, 0.4)
    msg = move_message(goal, step=10)
    msg_unstamped = {k: v for k, v in move_message(goal, step=0).items() if k != "step"}
    for m in (msg, msg_unstamped):
        deadline = time.monotonic() + 0.5
        _send_raw(fake.ports[1], m, lambda: time.monotonic() > deadline)  # noqa: B023 (used in this iteration)
    assert fake.actions == [] and fake.pose_world.distance_to(Pose2D(0.5, 0.3, 0.4)) == 0.0
    _send_raw(fake.ports[1], move_message(goal, step=11), lambda: fake.handled_step == 11)
    assert fake.pose_world.distance_to(goal) < 1e-9


def test_fake_receive_loop_dies_on_an_xyt_without_nav_relative_like_the_bridge(make_fake) -> None:
    fake = make_fake()
    bad = {"xyt": [0.0, 0.0, 0.0], "nav_blocking": True, "step": 1}
    _send_raw(fake.ports[1], bad, lambda: not fake.receiver_alive)
    assert fake.handled_step == -1  # never acknowledged


def test_link_reports_the_latest_messages_and_echo(make_fake) -> None:
    fake = make_fake(start_step=3)
    obs, action, state = fake.ports
    link = BridgeLink(StretchConfig(obs_port=obs, action_port=action, state_port=state))
    try:
        assert link.wait(lambda: link.state is not None and link.observation is not None, 10.0)
        assert link.echoed_step == 3
        assert link.state.is_homed is True and link.state.is_runstopped is False
        seen = link.observation.base_world
        assert seen.distance_to(Pose2D(0.5, 0.3, 0.4)) < 1e-9 and seen.yaw_rad == pytest.approx(0.4)
    finally:
        link.close()
        link.close()
