"""The console driving the fake Stretch (robot integration tests): a console on the fake's
loopback ports, a client that reaches it by its loopback address, starting a run and waiting
for its end."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from agent.types import Pose2D
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.store import FINAL_STATUSES as FINAL
from console.stretch_provider import StretchProvider
from console.viewer import ViewerConfig
from robot.config import StretchConfig
from robot.fake_server import FakeKnobs, FakeStretch
from robot.fake_world import BoxWorld
from tests.helpers.console_testkit import encode
from tests.helpers.polling import poll


def stretch_console(
    data_dir: Path, fake: FakeStretch, viewer: bool = False, memory: bool = False, **robot: Any
) -> Console:
    """``memory``: the robot's home memory in ``<data>/memory``, as ``imgnav console`` keeps it."""
    assert fake.ports is not None
    obs, action, state = fake.ports
    config = StretchConfig(obs_port=obs, action_port=action, state_port=state, connect_timeout_s=10.0, **robot)
    provider = StretchProvider("127.0.0.1", robot_config=config, memory_dir=data_dir / "memory" if memory else None)
    return Console(
        ConsoleConfig(data_dir=data_dir, viewer=ViewerConfig(port=0) if viewer else None), {"stretch": provider}
    )


def client_for(console: Console) -> TestClient:
    """A client that reaches the console by its loopback address (the console checks Host)."""
    return TestClient(create_app(console), base_url="http://127.0.0.1")


def start_run(client: TestClient, goal_rgb: np.ndarray, max_steps: int) -> str:
    resp = client.post(
        "/api/runs",
        files={"goal_image": ("goal.png", encode(goal_rgb, "PNG"), "image/png")},
        data={"backend": "stretch", "max_steps": str(max_steps)},
    )
    assert resp.status_code == 201, resp.text
    return resp.json()["id"]


def wait_final(client: TestClient, run_id: str, timeout_s: float) -> dict:
    return poll(lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] in FINAL, timeout_s, "run end")


def box_fake(**knobs: Any) -> FakeStretch:
    """A started fake Stretch in the analytic box room, on free loopback ports."""
    return FakeStretch(
        BoxWorld(start_world=Pose2D(0.0, 0.0, 0.3)), obs_port=0, action_port=0, state_port=0, knobs=FakeKnobs(**knobs)
    ).start()


def any_photo() -> np.ndarray:
    return np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8)
