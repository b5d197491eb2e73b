"""Replay of a finished run: what is stored per step, the timeline and its marks, the
pictures per step, the viewer's replay, and the words a run is told in."""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from agent.types import MapSnapshot
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.replay import decode_map, encode_map
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb


def scripted_console(tmp_path: Path, stop_after: int) -> Console:
    return Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("testserver",)),
        {"scripted": ScriptedProvider(stop_after=stop_after)},
    )


def run_to_the_end(client: TestClient) -> str:
    """Start a scripted run and wait until it has finished; its id."""
    run = client.post(
        "/api/runs", files={"goal_image": ("g.jpg", encode(textured_rgb(120, 160), "JPEG"), "image/jpeg")}
    )
    run_id = run.json()["id"]
    poll(lambda: client.get(f"/api/runs/{run_id}").json()["status"], lambda s: s == "finished")
    return run_id


@pytest.fixture
def finished(tmp_path: Path) -> Iterator[tuple[Console, TestClient, str]]:
    console = scripted_console(tmp_path, 25)
    client = TestClient(create_app(console))
    with client:
        yield console, client, run_to_the_end(client)
    console.close()


def test_map_codec_round_trip() -> None:
    rng = np.random.default_rng(0)
    layers = [rng.random((37, 53)) > 0.7 for _ in range(7)]
    snap = MapSnapshot(0.05, (-1.25, 2.5), *layers)
    back = decode_map(encode_map(snap))
    assert back.resolution_m == 0.05 and back.origin_xy_m == (-1.25, 2.5)
    for name in ("obstacle", "explored", "visited", "collision", "goal", "frontier", "blacklist"):
        assert np.array_equal(getattr(back, name), getattr(snap, name)), name
    no_blacklist = MapSnapshot(0.05, (0.0, 0.0), *layers[:6])
    assert decode_map(encode_map(no_blacklist)).blacklist is None


def test_timeline_marks_and_pictures(finished) -> None:
    console, client, run_id = finished
    replay = client.get(f"/api/runs/{run_id}/replay").json()
    assert replay["n_steps"] == 26 and len(replay["steps"]) == 26
    # maps every 10 steps, at the first detection (step 3), and at the last step
    assert replay["map_steps"] == [0, 3, 10, 20, 25]
    marks = replay["marks"]
    assert marks["first_detection"] == 3 and marks["stop"] == 25
    assert marks["candidate_rejected"] == [{"step": 6, "candidate": 1}]
    first = replay["steps"][0]
    # plain words for the operator; the agent's reason is the technical line behind them
    assert first["words"].startswith("Step 1: exploring, forward") and "scripted" not in first["words"]
    assert "agent: scripted step 0" in first["detail"] and "event frontier" in first["detail"]
    assert first["mode_words"] == "exploring" and first["action_words"] == "forward"
    step = client.get(f"/api/runs/{run_id}/replay/4").json()
    assert step["candidates"][0]["state"] == "confirmed" and step["candidates"][0]["distance_m"] == 0.4
    assert "why" not in step["candidates"][0]
    # a rejected candidate carries the policy's reason
    rejected = client.get(f"/api/runs/{run_id}/replay/6").json()["candidates"][0]
    assert rejected["state"] == "rejected" and rejected["why"] == "unreachable for 10 steps"
    frame = client.get(step["frame_url"])
    assert frame.status_code == 200 and frame.headers["content-type"] == "image/jpeg"
    assert Image.open(io.BytesIO(frame.content)).size[0] == 180  # thumbnail width
    pic = client.get(step["map_url"])
    assert pic.status_code == 200 and pic.headers["content-type"] == "image/png"
    # the map differs along the run: the trajectory grows
    other = client.get(f"/api/runs/{run_id}/replay/25/map.png").content
    assert other != pic.content


@pytest.mark.parametrize(
    "path, status",
    [
        ("/api/runs/{run}/replay/26", 404),
        ("/api/runs/{run}/replay/26/frame.jpg", 404),
        ("/api/runs/{run}/replay/26/map.png", 404),
        ("/api/runs/{run}/replay/-1", 422),
        ("/api/runs/{run}/replay/x/map.png", 422),
        ("/api/runs/0123456789ab/replay", 404),
        ("/api/runs/0123456789ab/replay/0/frame.jpg", 404),
    ],
)
def test_replay_bad_requests(finished, path: str, status: int) -> None:
    _, client, run_id = finished
    assert client.get(path.format(run=run_id)).status_code == status


def test_replay_storage_is_compact(finished) -> None:
    console, _, run_id = finished
    sizes = console.store.replay_bytes(run_id)
    assert sizes["steps"] == 26 and sizes["n_maps"] == 5
    per_step = (sizes["frames"] + sizes["extras"] + sizes["maps"]) / 26
    assert per_step < 20_000, sizes  # a 1000-step run stays well under 20 MB


def test_run_in_words(finished) -> None:
    _, client, run_id = finished
    run = client.get(f"/api/runs/{run_id}").json()
    summary = run["summary"]
    assert summary["headline"] == "Stopped at what it took for the object"
    assert "after 26 steps" in summary["sentence"] and "m driven" in summary["sentence"]
    assert any(label == "upload to first move" for label, _ in run["timings_words"])


def test_viewer_shows_a_replayed_step(finished) -> None:
    from console.viewer import Viewer, ViewerConfig

    console, client, run_id = finished
    viewer = Viewer(ViewerConfig(port=0))
    try:
        steps_json = client.get(f"/api/runs/{run_id}", params={"steps": True}).json()["steps"]
        from agent.types import Action

        for s in steps_json:
            s["action_name"] = Action(s["action"]).name
        row = console.store.get_run(run_id)
        viewer.show_replay(console.store, row, steps_json, console.store.replay_extras(run_id), 12)
        assert viewer.replay_step == 12
        assert "Replay of run" in viewer.scene.status.content and "Step 13" in viewer.scene.status.content
        assert viewer.scene.occupancy is not None and viewer.scene.trajectory is not None
        # the slider moves through the run
        viewer.replay.state.slider.value = 20
        assert viewer.replay_step == 19
        # a live run ends the replay
        viewer.run_started("fedcbafedcba", np.zeros((8, 8, 3), np.uint8), {})
        assert viewer.replay.state is None
    finally:
        viewer.close()


def test_latest_step_for_the_live_view(finished) -> None:
    _, client, run_id = finished
    latest = client.get(f"/api/runs/{run_id}/replay/latest").json()
    assert latest["step"] == 25 and latest["frame_url"].endswith("/replay/25/frame.jpg")


def test_a_step_is_announced_only_once_its_pictures_can_be_loaded(tmp_path: Path) -> None:
    """The live view asks for the latest step when it hears of one: at that moment the step's
    row and pictures are both stored (the step event used to come first, a 404 in the browser)."""
    console = scripted_console(tmp_path, 8)
    seen: list[tuple[int, int | None]] = []
    publish = console.hub.publish

    def spy(kind, run_id, data):
        if kind == "step":
            seen.append((int(data["step"]), console.store.replay_latest_step(run_id)))
        return publish(kind, run_id, data)

    console.hub.publish = spy  # type: ignore[method-assign]
    client = TestClient(create_app(console))
    with client:
        run_to_the_end(client)
    console.close()
    assert [s for s, _ in seen] == list(range(9))
    assert all(latest == step for step, latest in seen), seen


def test_the_latest_step_needs_both_its_row_and_its_pictures(finished) -> None:
    console, _, run_id = finished
    console.store.add_replay_step(run_id, 26, b"\xff\xd8", "{}")  # pictures of a step whose row is not written yet
    assert console.store.replay_latest_step(run_id) == 25
