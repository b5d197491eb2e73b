"""The viser viewer: camera pose math, publishing a record, throttled offers."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from console.scene_geometry import camera_rotation, rotation_to_wxyz
from console.session import Outcome, StepRecord
from console.viewer import Viewer, ViewerConfig
from tests.helpers.console_testkit import ScriptedAgent, ScriptedBackend, poll, textured_rgb


def test_camera_rotation_opencv_axes() -> None:
    R = camera_rotation(0.0, 0.0)
    assert np.allclose(R[:, 2], [1, 0, 0])  # optical axis along the heading
    assert np.allclose(R[:, 0], [0, -1, 0])  # image x to the robot's right
    assert np.allclose(R[:, 1], [0, 0, -1])  # image y down
    R = camera_rotation(math.pi / 2, 0.3)
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert R[2, 2] < 0  # tilted down


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, math.pi])
def test_quaternion_round_trip(yaw: float) -> None:
    R = camera_rotation(yaw, 0.2)
    w, x, y, z = rotation_to_wxyz(R)
    Rq = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    assert np.allclose(Rq, R, atol=1e-9)


def records(n: int) -> list[StepRecord]:
    goal = textured_rgb(64, 64)
    backend, agent = ScriptedBackend(goal), ScriptedAgent(stop_after=n)
    obs = backend.reset()
    out, traj = [], []
    for step in range(n):
        action = agent.act(obs)
        traj.append((obs.pose.x_m, obs.pose.y_m))
        out.append(
            StepRecord(
                "abcdefabcdef",
                step,
                time.time(),
                action,
                obs.pose,
                obs.rgb,
                obs.depth_m,
                obs.intrinsics,
                obs.camera_height_m,
                obs.camera_tilt_rad,
                goal,
                agent.last_record,
                np.array(traj),
                tuple((i, float(i), 10.0) for i in range(step + 1)),
            )
        )
        backend.apply(action)
        obs = backend.observe()
    return out


def test_viewer_publishes_and_throttles() -> None:
    """Twelve offers inside one pose period publish once, the newest; nothing is lost at the end."""
    viewer = Viewer(ViewerConfig(port=0, pose_hz=0.5, map_hz=1.0))  # a 2 s pose period
    try:
        assert viewer.port > 0
        recs = records(12)
        viewer.run_started("abcdefabcdef", recs[0].goal_rgb, {"backend": "scripted"})
        viewer.publish(recs[0], with_map=True)  # direct publish: the full path, map included
        assert viewer.n_published == 1
        for rec in recs:  # offers return at once; the viewer thread keeps only the newest
            viewer.offer(rec)
        poll(lambda: viewer.n_published, lambda n: n >= 2, 10, "the throttled publish")
        assert viewer.n_published == 2 and viewer.last_published_step == 11
        viewer.run_ended("abcdefabcdef", "finished", Outcome("unscored", "test", {"spl": 0.5}))
        assert viewer.n_published == 2  # the newest was already shown: nothing republished
        viewer.offer(recs[5])
        viewer.run_ended("abcdefabcdef", "finished", Outcome("unscored", "test", {"spl": 0.5}))
        assert viewer.n_published == 3 and viewer.last_published_step == 5  # a pending one is shown at the end
    finally:
        viewer.close()


def test_occupancy_plane_is_not_mirrored() -> None:
    """viser shows image row 0 at the plane's -y side; grid row 0 is the lowest y, so the
    texture must go out unflipped: a goal cell at high y stays at the top rows."""
    recs = records(3)
    viewer = Viewer(ViewerConfig(port=0))
    try:
        viewer.run_started(recs[0].run_id, recs[0].goal_rgb, {})
        viewer.publish(recs[-1], with_map=True)
        snap = recs[-1].record.map
        image = viewer.scene.occupancy.image
        known = snap.explored | snap.obstacle
        ii, _ = np.nonzero(known)
        # the scripted map's obstacle row is its lowest known row (i = 10): first texture row
        assert (image[0, :, :3] == np.array([70, 78, 110])).all(axis=1).any()
        assert ii.min() == 10
    finally:
        viewer.close()


# --- the viewer's port: the same Host/Origin rules as the API ------------------------------


def _ws_connect(port: int, host_header: str, origin: str | None):
    import socket

    import viser
    from websockets.sync.client import connect

    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    return connect(
        f"ws://{host_header}/",
        sock=sock,
        origin=origin,
        subprotocols=[f"viser-v{viser.__version__}"],
        open_timeout=10,
        close_timeout=2,
    )


def _first_message_or_close(ws) -> tuple[str, object]:
    from websockets.exceptions import ConnectionClosed

    try:
        return "message", ws.recv(timeout=10)
    except ConnectionClosed as exc:
        return "closed", exc.rcvd.code if exc.rcvd is not None else None


@pytest.mark.parametrize(
    "host_header, origin",
    [
        ("evil.example:{port}", "http://evil.example:{port}"),  # DNS rebinding: Host and Origin agree
        ("evil.example:{port}", None),
        ("127.0.0.1:{port}", "http://evil.example"),  # a page elsewhere opening ws://127.0.0.1
        ("127.0.0.1:{port}", "null"),
    ],
)
def test_viewer_refuses_foreign_host_or_origin(host_header: str, origin: str | None) -> None:
    stops: list[int] = []
    viewer = Viewer(ViewerConfig(port=0), on_stop=lambda: stops.append(1) or "stopping")
    try:
        port = viewer.port
        with _ws_connect(
            port, host_header.format(port=port), None if origin is None else origin.format(port=port)
        ) as ws:
            kind, value = _first_message_or_close(ws)
        assert (kind, value) == ("closed", 1008)
        assert viewer.n_rejected == 1 and stops == []
    finally:
        viewer.close()


def test_viewer_accepts_its_own_names() -> None:
    viewer = Viewer(ViewerConfig(port=0))
    try:
        port = viewer.port
        for host_header, origin in [(f"127.0.0.1:{port}", f"http://127.0.0.1:{port}"), (f"localhost:{port}", None)]:
            with _ws_connect(port, host_header, origin) as ws:
                kind, _ = _first_message_or_close(ws)
            assert kind == "message", host_header
        assert viewer.n_rejected == 0
    finally:
        viewer.close()
