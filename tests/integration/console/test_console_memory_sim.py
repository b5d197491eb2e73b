"""Runs in one simulator home share the agent's memory of it, in one frame, and the memory
survives a console restart (issue 31; console/home_memory.py), with the real simulator and agent;
a known object asked for again (``goal_from_run``) is the first request's photo, recalled."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from agent.types import Pose2D
from console.api import create_app
from console.store import FINAL_STATUSES as FINAL
from tests.helpers.console_live import poll, sim_console


def run(client: TestClient, home: dict, start: str, max_steps: int, **options: str) -> dict:
    """A run in ``home`` with its first gallery photo, or (``goal_from_run``) an earlier run's."""
    data = {"home": home["id"], "start": start, "max_steps": str(max_steps), **options}
    if "goal_from_run" in options:
        resp = client.post("/api/runs", data=data)
    else:
        g = home["gallery"][0]
        files = {"goal_image": ("g.png", client.get(g["url"]).content, "image/png")}
        resp = client.post("/api/runs", files=files, data={**data, "gallery_item": g["item"]})
    assert resp.status_code == 201, resp.text
    run_id = resp.json()["id"]
    done = poll(lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] in FINAL, 900, "run end")
    assert done["status"] == "finished", done
    return client.get(f"/api/runs/{run_id}", params={"steps": True}).json()


def test_runs_in_a_home_share_its_memory_in_one_frame_and_a_restart_keeps_it(data_dir: Path) -> None:
    console = sim_console(data_dir)
    with TestClient(create_app(console)) as client:
        home = client.get("/api/backends/sim").json()["homes"][0]
        key = home["id"]  # home-<seed>: the memory's key
        a, b = home["starts"][0]["id"], home["starts"][1]["id"]
        assert client.get(f"/api/memory/{key}").json()["goals"] == []

        first = run(client, home, a, 6)
        assert first["agent_config"]["memory_home"] == key
        assert first["agent_config"]["memory_origin"] == [0.0, 0.0, 0.0]  # its start is the memory's frame
        mem1 = client.get(f"/api/memory/{key}").json()
        assert len(mem1["goals"]) == 1 and mem1["goals"][0]["steps"] == first["n_steps"]
        assert mem1["keyframes"] > 0 and mem1["map_bytes"] > 0 and not mem1["in_use"] and mem1["saved"]
        assert mem1["goals"][0]["run_id"] == first["id"]
        (known,) = mem1["objects"]  # the first request found its object (the couch is in view from a)
        assert (known["request"], known["run_id"]) == (1, first["id"])
        assert known["goal_url"] == f"/api/runs/{first['id']}/artifacts/goal.png"

        # asked for again, from memory: the first request's photo, recalled before the first step
        second = run(client, home, b, 4, goal_from_run=first["id"])
        assert second["goal"]["from_run"] == first["id"] and "memory" not in second["options"]
        photos = [client.get(f"/api/runs/{r['id']}/artifacts/goal.png").content for r in (first, second)]
        assert np.array_equal(*(np.asarray(Image.open(io.BytesIO(p))) for p in photos))
        assert photos[0] == client.get(known["goal_url"]).content
        assert second["target"]["instance_id"] == first["target"]["instance_id"]  # scored as the first was
        start_a = Pose2D(*first["options"]["start_pose_world"])
        start_b = Pose2D(*second["options"]["start_pose_world"])
        origin = start_b.relative_to(start_a)  # b's start in the frame of a's start
        assert second["agent_config"]["memory_origin"] == pytest.approx([origin.x_m, origin.y_m, origin.yaw_rad])
        s0 = second["steps"][0]  # the run's poses are in the memory's frame
        assert [s0["x_m"], s0["y_m"], s0["yaw_rad"]] == pytest.approx([origin.x_m, origin.y_m, origin.yaw_rad])
        mem2 = client.get(f"/api/memory/{key}").json()
        assert [g["goal_index"] for g in mem2["goals"]] == [0, 1]
        assert mem2["goals"][1]["keyframes_at_start"] == mem1["keyframes"]  # the second goal began with the first's
        assert mem2["goals"][1]["recalled_views"] > 0  # the object recalled from the first request's views
        assert [g["run_id"] for g in mem2["goals"]] == [first["id"], second["id"]]
        assert mem2["goals"][0] == mem1["goals"][0]
    # a new console on the same data directory
    console2 = sim_console(data_dir)
    with TestClient(create_app(console2)) as client:
        back = client.get(f"/api/memory/{key}").json()
        kept = ("keyframes", "keyframe_bytes", "map_bytes", "goals", "objects")  # the goals with their runs
        assert {k: back[k] for k in kept} == {k: mem2[k] for k in kept}
        png = client.get(back["map_url"])
        assert png.status_code == 200 and Image.open(io.BytesIO(png.content)).format == "PNG"
        third = run(client, home, b, 2)  # the restored memory, in the same frame as before the restart
        assert third["agent_config"]["memory_origin"] == pytest.approx([origin.x_m, origin.y_m, origin.yaw_rad])
        mem3 = client.get(f"/api/memory/{key}").json()
        assert [g["goal_index"] for g in mem3["goals"]] == [0, 1, 2]
        assert mem3["goals"][2]["keyframes_at_start"] == mem2["keyframes"]
        # forgetting the home: the next run starts from nothing, in its own start's frame
        assert client.delete(f"/api/memory/{key}").json() == {"home": key, "forgotten": True}
        gone = client.post("/api/runs", data={"home": key, "goal_from_run": first["id"]})
        assert (gone.status_code, gone.json()["detail"]["code"]) == (422, "not_remembered")
        fourth = run(client, home, b, 2)
        assert fourth["agent_config"]["memory_origin"] == [0.0, 0.0, 0.0]
        assert [g["goal_index"] for g in client.get(f"/api/memory/{key}").json()["goals"]] == [0]
        # a run with memory off: from nothing, and the home's memory stays as it was
        kept = client.get(f"/api/memory/{key}").json()
        fifth = run(client, home, a, 2, memory="off")
        assert fifth["options"]["memory"] == "off" and "memory_home" not in fifth["agent_config"]
        assert fifth["steps"][0]["x_m"] == 0.0 and fifth["steps"][0]["y_m"] == 0.0  # its own start's frame
        after = client.get(f"/api/memory/{key}").json()
        assert (after["goals"], after["keyframes"]) == (kept["goals"], kept["keyframes"])
        g = home["gallery"][0]
        bad = client.post(
            "/api/runs",
            files={"goal_image": ("g.png", client.get(g["url"]).content, "image/png")},
            data={"home": home["id"], "memory": "sometimes"},
        )
        assert bad.status_code == 422 and "memory must be" in bad.json()["detail"]["message"]
