"""The agent's memory of the robot's home through the console, on the fake Stretch with the real
agent (issue 31; console/robot_memory.py): runs on the robot share it in the robot's map frame
(the second run recalls the first's keyframes, and what both remember lands at the same place in
the map frame), a console restart keeps it, and a runstop, a push by hand or a localisation
restart drop it with a message.

The fake robot's map frame is its world frame (until ``reset_localisation``), so the ground truth
of every remembered point is the box room's geometry: a pillar 2 m ahead of the first start, which
the goal photo shows. Runs take one or two agent steps. The head stays where the fake robot starts
it (``send_posture`` off: no posture, no head move; the agent reads the tilt from each
observation), so that no frame is taken while the head still moves.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from agent.types import Pose2D
from console.context import Console
from console.stretch_provider import StretchProvider
from robot.fake_server import FakeStretch
from robot.fake_world import BoxWorld
from tests.helpers.polling import poll
from tests.helpers.robot_console import client_for, start_run, stretch_console, wait_final

PILLAR = (1.5, 0.5, 0.25)  # x, y, half side (m)
START = Pose2D(-0.5, 0.5, 0.0)  # facing the pillar; away from the map origin (a localisation reset shows)


def box() -> BoxWorld:
    return BoxWorld(pillars=(PILLAR,), start_world=START)


@pytest.fixture
def fake() -> Iterator[FakeStretch]:
    robot = FakeStretch(box(), obs_port=0, action_port=0, state_port=0).start()
    yield robot
    robot.close()


@pytest.fixture
def goal_rgb(fake: FakeStretch) -> np.ndarray:
    """The pillar, photographed from the first start with the head camera as it stands."""
    return box().render(START, fake.tilt_rad)[0]


def robot_console(data_dir: Path, fake: FakeStretch) -> Console:
    """The console driving the fake robot, keeping the robot's home memory in ``data_dir``."""
    return stretch_console(data_dir, fake, memory=True, send_posture=False)


def memory_home(console: Console) -> str:
    provider = console.providers["stretch"]
    assert isinstance(provider, StretchProvider)
    home = provider.memory_home()
    assert home is not None and home.startswith("robot-")
    return home


def run(client: TestClient, goal_rgb: np.ndarray, max_steps: int, status: str = "finished") -> dict[str, Any]:
    return finished(client, start_run(client, goal_rgb, max_steps), status)


def finished(client: TestClient, run_id: str, status: str = "finished") -> dict[str, Any]:
    done = wait_final(client, run_id, timeout_s=240)
    assert done["status"] == status, done
    return client.get(f"/api/runs/{run_id}", params={"steps": True}).json()


def close_to(values: list[float], pose: Pose2D, tol: float = 0.02) -> bool:
    x, y, yaw = values
    return math.hypot(x - pose.x_m, y - pose.y_m) <= tol and abs(math.remainder(yaw - pose.yaw_rad, math.tau)) <= tol


def surface_distance_m(xy: np.ndarray) -> np.ndarray:
    """Distance from each map-frame point to the nearest surface of the box room (walls, pillar)."""
    world = box()
    x, y = xy[:, 0], xy[:, 1]
    walls = np.min(np.abs(np.stack([x - world.x_min, x - world.x_max, y - world.y_min, y - world.y_max])), axis=0)
    px, py, half = PILLAR
    ox, oy = np.abs(x - px) - half, np.abs(y - py) - half
    pillar = np.where((ox < 0) & (oy < 0), -np.maximum(ox, oy), np.hypot(np.maximum(ox, 0), np.maximum(oy, 0)))
    return np.minimum(walls, pillar)


def on_the_surfaces(xy: np.ndarray) -> float:
    """The share of map-frame points within 0.1 m of a surface of the box room (the robot's depth
    comes JPEG2000-coded, so a few points at depth edges fall between the pillar and a wall)."""
    off = surface_distance_m(xy)
    share = float(np.mean(off < 0.1))
    print(
        f"\n{len(off)} remembered obstacle cells, {share:.1%} within 0.1 m of a surface, quartiles "
        f"{np.percentile(off, [25, 50, 75]).round(3)}, max {off.max():.2f} m"
    )
    return share


def remembered_obstacles_map(console: Console, home: str) -> np.ndarray:
    """The remembered map's obstacle cells, in the robot's map frame (through the memory's anchor)."""
    provider = console.providers["stretch"]
    assert isinstance(provider, StretchProvider)
    slot = provider.memories().slot(home)
    grid = slot.memory.grid
    assert grid is not None and slot.anchor_world is not None
    cells = np.argwhere(grid.layers.obstacle)
    assert len(cells) > 10
    return slot.anchor_world.transform_xy(grid.ij_to_xy(cells))


def candidate_map_xy(memory: dict[str, Any], goal: int, anchor: Pose2D) -> np.ndarray:
    """The best candidate of a remembered goal, in the robot's map frame."""
    best = max(memory["goals"][goal]["candidates"], key=lambda c: c["best_score"])
    return anchor.transform_xy(np.asarray([best["xy_m"]]))[0]


def test_robot_runs_share_the_memory_in_the_robots_map_frame_and_a_restart_keeps_it(
    fake: FakeStretch, goal_rgb: np.ndarray, tmp_path: Path
) -> None:
    data = tmp_path / "data"
    console = robot_console(data, fake)
    try:
        home = memory_home(console)
        with client_for(console) as client:
            assert client.get("/api/memory").json() == {"homes": [home], "backends": {"stretch": [home]}}
            assert client.get("/api/backends/stretch").json()["memory_home"] == home
            empty = client.get(f"/api/memory/{home}").json()
            assert (empty["goals"], empty["keyframes"], empty["dropped"]) == ([], 0, None)

            first = run(client, goal_rgb, max_steps=2)
            assert first["options"]["home"] == home and first["agent_config"]["memory_home"] == home
            assert first["agent_config"]["memory_origin"] == [0.0, 0.0, 0.0]  # the first start is the frame
            mem1 = client.get(f"/api/memory/{home}").json()
            assert len(mem1["goals"]) == 1 and mem1["keyframes"] > 0 and mem1["saved"]
            assert mem1["goals"][0]["run_id"] == first["id"]
            (known,) = mem1["objects"]  # the pillar, with the photo it was asked with
            assert known["run_id"] == first["id"] and known["goal_url"] == f"/api/runs/{first['id']}/artifacts/goal.png"

            start2 = fake.pose_world  # where the first run left the robot: the second run's start
            assert start2.distance_to(START) > 0.2  # the robot moved: the two runs' own frames differ
            refused = client.post(
                "/api/runs", data={"backend": "stretch", "goal_from_run": first["id"], "memory": "off"}
            )
            assert (refused.status_code, refused.json()["detail"]["code"]) == (422, "memory_off")
            # the known object asked for again, from memory: the first request's photo
            form = {"backend": "stretch", "goal_from_run": first["id"], "max_steps": "1"}
            asked = client.post("/api/runs", data=form)
            assert asked.status_code == 201, asked.text
            second = finished(client, asked.json()["id"])
            assert second["goal"]["from_run"] == first["id"] and second["options"]["home"] == home
            assert "memory_dropped" not in second["agent_config"] and "dropped" not in second["outcome_detail"]
            origin = start2.relative_to(START)  # this start in the first start's frame
            assert close_to(second["agent_config"]["memory_origin"], origin)
            s0 = second["steps"][0]  # the run's poses are in the memory's frame
            assert close_to([s0["x_m"], s0["y_m"], s0["yaw_rad"]], origin)
            mem2 = client.get(f"/api/memory/{home}").json()
            assert [g["run_id"] for g in mem2["goals"]] == [first["id"], second["id"]]
            assert mem2["goals"][1]["keyframes_at_start"] == mem1["keyframes"]  # began with the first's views
            assert mem2["goals"][1]["recalled_views"] > 0  # and recalled the pillar from them

            # what both runs remember lands at the same map-frame place: the pillar's face, and the
            # remembered map's obstacles on the room's surfaces
            face = np.array([PILLAR[0] - PILLAR[2], PILLAR[1]])
            c1, c2 = candidate_map_xy(mem2, 0, START), candidate_map_xy(mem2, 1, START)
            assert np.linalg.norm(c1 - face) < 0.25 and np.linalg.norm(c2 - face) < 0.25, (c1, c2)
            assert np.linalg.norm(c1 - c2) < 0.1, (c1, c2)
            assert on_the_surfaces(remembered_obstacles_map(console, home)) > 0.9
    finally:
        console.close()

    # a new console on the same data directory, the robot where the second run left it
    console = robot_console(data, fake)
    try:
        with client_for(console) as client:
            back = client.get(f"/api/memory/{home}").json()
            kept = ("keyframes", "keyframe_bytes", "map_bytes", "goals", "objects")
            assert {k: back[k] for k in kept} == {k: mem2[k] for k in kept}
            start3 = fake.pose_world
            third = run(client, goal_rgb, max_steps=1)
            assert close_to(third["agent_config"]["memory_origin"], start3.relative_to(START))
            mem3 = client.get(f"/api/memory/{home}").json()
            assert [g["goal_index"] for g in mem3["goals"]] == [0, 1, 2]
            assert mem3["goals"][2]["keyframes_at_start"] == mem2["keyframes"]
            assert mem3["goals"][2]["recalled_views"] > 0

            # the operator forgets the home: the next run starts from nothing, in its own start's frame
            assert client.delete(f"/api/memory/{home}").json() == {"home": home, "forgotten": True}
            assert client.get(f"/api/memory/{home}").json()["goals"] == []
            assert not (data / "memory" / f"{home}.npz").exists()
    finally:
        console.close()


def published_logs(console: Console, monkeypatch: pytest.MonkeyPatch) -> list[tuple[str | None, str]]:
    """The ``log`` events the console publishes from now on: (run id, message)."""
    logs: list[tuple[str | None, str]] = []
    publish = console.hub.publish

    def recording(kind: str, run_id: str | None, data: Any) -> Any:
        if kind == "log":
            logs.append((run_id, str(data.get("message"))))
        return publish(kind, run_id, data)

    monkeypatch.setattr(console.hub, "publish", recording)
    return logs


def test_a_runstop_drops_the_robots_memory_with_a_message(
    fake: FakeStretch, goal_rgb: np.ndarray, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    console = robot_console(tmp_path / "data", fake)
    logs = published_logs(console, monkeypatch)
    try:
        home = memory_home(console)
        path = tmp_path / "data" / "memory" / f"{home}.npz"
        with client_for(console) as client:
            first = run(client, goal_rgb, max_steps=1)
            assert client.get(f"/api/memory/{home}").json()["keyframes"] > 0 and path.is_file()

            fake.knobs.runstopped = True  # pressed between runs: the base can be pushed now
            refused = run(client, goal_rgb, max_steps=1, status="failed")
            detail = refused["outcome_detail"]
            assert "backend error (runstopped)" in detail, detail
            said = f"the memory of {home} is dropped: the robot is runstopped at the start of this run"
            assert said in detail and "pushed by hand" in detail, detail
            note = detail[detail.index(said) :]  # told at once too, as a log event of the run
            assert [m for r, m in logs if r == refused["id"]] == [f"run {refused['id']}: {note}"]
            assert "runstopped" in refused["agent_config"]["memory_dropped"]
            mem = client.get(f"/api/memory/{home}").json()
            assert (mem["goals"], mem["keyframes"], mem["map_bytes"]) == ([], 0, 0)
            assert mem["dropped"]["run_id"] == refused["id"] and "runstopped" in mem["dropped"]["reason"]

            fake.knobs.runstopped = False
            fresh = run(client, goal_rgb, max_steps=1)  # from nothing, in its own start's frame
            assert (
                fresh["agent_config"]["memory_origin"] == [0.0, 0.0, 0.0] and "dropped" not in fresh["outcome_detail"]
            )
            mem = client.get(f"/api/memory/{home}").json()
            assert [(g["goal_index"], g["run_id"], g["keyframes_at_start"]) for g in mem["goals"]] == [
                (0, fresh["id"], 0)
            ]
            assert first["id"] not in {g["run_id"] for g in mem["goals"]}

            # pressed during a run (after its first move), and released: dropped when that run ends
            moves = len([a for a in fake.actions if "xyt" in a])

            def press_after_first_move() -> None:
                poll(lambda: len([a for a in fake.actions if "xyt" in a]), lambda n: n > moves, 120, "a move")
                fake.knobs.runstopped = True

            presser = threading.Thread(target=press_after_first_move, daemon=True)
            presser.start()
            stopped = run(client, goal_rgb, max_steps=5, status="failed")
            presser.join()
            fake.knobs.runstopped = False
            assert "backend error (runstopped)" in stopped["outcome_detail"]
            assert (
                f"the memory of {home} is dropped: the robot was runstopped during this run"
                in stopped["outcome_detail"]
            )
            mem = client.get(f"/api/memory/{home}").json()
            assert mem["goals"] == [] and mem["dropped"]["run_id"] == stopped["id"]
    finally:
        console.close()


@pytest.mark.parametrize("how", ["pushed by hand", "localisation restarted"])
def test_a_robot_moved_between_runs_drops_the_memory_and_the_run_goes_on_from_nothing(
    how: str, fake: FakeStretch, goal_rgb: np.ndarray, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    console = robot_console(tmp_path / "data", fake)
    logs = published_logs(console, monkeypatch)
    try:
        home = memory_home(console)
        with client_for(console) as client:
            first = run(client, goal_rgb, max_steps=1)
            assert client.get(f"/api/memory/{home}").json()["keyframes"] > 0
            left = fake.pose_world
            if how == "pushed by hand":
                fake.push_base(Pose2D(left.x_m, left.y_m - 1.0, left.yaw_rad + 0.2))
            else:  # a SLAM restart: the base stays, its reported pose becomes the origin
                fake.reset_localisation()
            second = run(client, goal_rgb, max_steps=1)
            detail = second["outcome_detail"]
            said = f"the memory of {home} is dropped: the robot starts "
            assert said in detail and f"from where run {first['id']} left it" in detail, detail
            assert "moved by hand, or its localisation was reset" in detail and "this run starts from nothing" in detail
            note = detail[detail.index(said) :]  # told at once too, as a log event of the run
            assert [m for r, m in logs if r == second["id"]] == [f"run {second['id']}: {note}"]
            assert second["agent_config"]["memory_origin"] == [0.0, 0.0, 0.0]
            mem = client.get(f"/api/memory/{home}").json()
            assert [(g["goal_index"], g["run_id"], g["keyframes_at_start"]) for g in mem["goals"]] == [
                (0, second["id"], 0)
            ]
            assert not mem["goals"][0]["recalled_views"]
            assert mem["dropped"]["run_id"] == second["id"] and mem["saved"]  # the new memory, from this run
            # and the new memory is in the new start's frame: its map lies on the room's surfaces
            provider = console.providers["stretch"]
            assert isinstance(provider, StretchProvider)
            slot = provider.memories().slot(home)
            assert slot.anchor_world is not None
            seen = remembered_obstacles_map(console, home)
            if how == "localisation restarted":  # the map frame is now the base's pose at the restart
                seen = left.transform_xy(seen)
            assert on_the_surfaces(seen) > 0.9
    finally:
        console.close()
