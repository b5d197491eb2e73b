"""``imgnav fake-stretch`` as a process: a PyBullet home behind the bridge protocol, driven by
the Stretch client over loopback, stopped with Ctrl-C (SIGINT)."""

from __future__ import annotations

import math
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from agent.types import Action, BackendError, Pose2D
from robot.backend import StretchBackend
from robot.config import StretchConfig

READY = re.compile(
    r"observations (\d+), actions (\d+), state (\d+); start Pose2D\(x_m=([-\d.e]+), y_m=([-\d.e]+), yaw_rad=([-\d.e]+)\)"
)


def _start(*extra: str) -> tuple[subprocess.Popen, tuple[int, int, int]]:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "console.cli",
            "fake-stretch",
            "--obs-port",
            "0",
            "--action-port",
            "0",
            "--state-port",
            "0",
            *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 120
    lines = []
    assert proc.stdout is not None
    for line in proc.stdout:  # the ready line comes after the home is built
        lines.append(line)
        m = READY.search(line)
        if m:
            return proc, (int(m.group(1)), int(m.group(2)), int(m.group(3)))
        if time.monotonic() > deadline:
            break
    proc.kill()
    raise AssertionError("fake-stretch did not start:\n" + "".join(lines))


def _stop(proc: subprocess.Popen) -> tuple[int, str]:
    """Ctrl-C; the exit code and the rest of the output."""
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=30)
        return proc.returncode, out
    finally:
        if proc.poll() is None:
            proc.kill()


def test_fake_stretch_cli_serves_a_simulated_home_until_ctrl_c() -> None:
    proc, (obs, act, state) = _start("--world", "sim", "--scene-seed", "0")
    try:
        config = StretchConfig(obs_port=obs, action_port=act, state_port=state, connect_timeout_s=20)
        with StretchBackend(np.zeros((30, 40, 3), np.uint8), config) as backend:
            first = backend.reset()
            assert first.rgb.shape == (640, 360, 3) and first.depth_m.max() > 0.5
            assert first.camera_height_m == pytest.approx(1.31) and first.camera_tilt_rad == pytest.approx(
                0.0, abs=0.02
            )
            for action in (Action.TURN_LEFT, Action.TURN_LEFT, Action.TURN_RIGHT):
                backend.apply(action)
            obs_after = backend.observe()
            assert obs_after.step == 3
            assert obs_after.pose.distance_to(Pose2D()) < 1e-6
            assert obs_after.pose.yaw_rad == pytest.approx(math.radians(30), abs=1e-6)
            assert not np.array_equal(obs_after.rgb, first.rgb)  # the view turned
    finally:
        assert _stop(proc)[0] == 0


def test_fake_stretch_cli_runstopped_is_refused() -> None:
    proc, (obs, act, state) = _start("--world", "box", "--runstopped")
    try:
        config = StretchConfig(obs_port=obs, action_port=act, state_port=state, connect_timeout_s=20)
        with StretchBackend(np.zeros((30, 40, 3), np.uint8), config) as backend:
            with pytest.raises(BackendError) as info:
                backend.reset()
            assert info.value.reason == "runstopped"
    finally:
        assert _stop(proc)[0] == 0


def test_fake_stretch_cli_starts_at_an_episode_start_and_reports_the_distance_to_its_goal(tmp_path) -> None:
    from sim.episodes import load_episode_set

    out = tmp_path / "episodes"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "console.cli",
            "episodes",
            "--split",
            "val",
            "--count",
            "1",
            "--out",
            str(out),
            "--workers",
            "1",
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    episode = load_episode_set(out).episodes[0]
    proc, (obs, act, state) = _start("--episodes", str(out), "--episode", episode.episode_id)
    try:
        config = StretchConfig(obs_port=obs, action_port=act, state_port=state, connect_timeout_s=20)
        with StretchBackend(np.zeros((30, 40, 3), np.uint8), config) as backend:
            assert backend.reset().pose.distance_to(Pose2D()) < 1e-9
            backend.apply(Action.STOP)
    finally:
        code, rest = _stop(proc)
    assert code == 0
    assert "m from the nearest goal viewpoint" in rest, rest
    expected = min(
        math.hypot(x - episode.start_pose_world.x_m, y - episode.start_pose_world.y_m)
        for x, y in episode.viewpoints_xy_m
    )
    assert f"{expected:.2f} m from the nearest goal viewpoint" in rest
