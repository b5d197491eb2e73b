"""The console API with the real PyBullet simulator and the real Mod-IIN agent."""

from __future__ import annotations

import io
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from console.api import create_app
from console.store import FINAL_STATUSES as FINAL
from tests.helpers.console_live import ARTIFACTS, HOME_SEED, poll, sim_console


@pytest.fixture
def client(data_dir: Path) -> Iterator[TestClient]:
    console = sim_console(data_dir)
    with TestClient(create_app(console)) as client:
        yield client


def home(client: TestClient) -> dict:
    desc = client.get("/api/backends/sim").json()
    assert desc["available"], desc
    return desc["homes"][0]


def gallery_png(client: TestClient, item: dict) -> bytes:
    resp = client.get(item["url"])
    assert resp.status_code == 200 and resp.headers["content-type"] == "image/png"
    return resp.content


def pick_target(h: dict) -> tuple[dict, dict]:
    """A large, easy instance (couch or bed) and the start near it."""
    by_cat = sorted(
        h["gallery"], key=lambda g: ["couch", "bed", "tv", "chair", "potted plant", "toilet"].index(g["category"])
    )
    for g in by_cat:
        start = next((s for s in h["starts"] if s["id"] == f"n{g['instance']}"), None)
        if start is not None:
            return g, start
    raise AssertionError("no gallery instance with a near start")


def wait_final(client: TestClient, run_id: str, timeout_s: float = 900) -> dict:
    return poll(lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] in FINAL, timeout_s, "run end")


def test_whole_run_to_completion_is_scored(client: TestClient) -> None:
    h = home(client)
    g, start = pick_target(h)
    resp = client.post(
        "/api/runs",
        files={"goal_image": ("goal.png", gallery_png(client, g), "image/png")},
        # A start near the target and a small budget: the run ends by the agent's STOP or by the
        # budget, and is scored either way (the simulator's episode is over in both cases).
        data={"home": h["id"], "start": start["id"], "gallery_item": g["item"], "max_steps": "15"},
    )
    assert resp.status_code == 201, resp.text
    run = resp.json()
    assert run["target"]["instance_id"] == g["instance"] and run["target"]["identified_by"] == "gallery_item"
    done = wait_final(client, run["id"])
    assert done["status"] == "finished", done
    assert done["outcome"] in ("success", "failure"), done  # scored either way
    assert done["n_steps"] <= 15
    for key in ("success", "spl", "ne_m"):
        assert key in done["metrics"], done["metrics"]
    assert done["agent_config"]["reid"]["matcher"]
    assert done["timings"]["upload_to_first_action_s"] > 0
    full = client.get(f"/api/runs/{run['id']}", params={"steps": True}).json()
    assert len(full["steps"]) == done["n_steps"] > 0
    assert any(s["reid_score"] is not None for s in full["steps"])
    for name in ("goal.png", "goal_upload.png", "trajectory.json", "map.png", "run.webp"):
        assert name in done["artifacts"], done["artifacts"]
        assert client.get(done["artifacts"][name]).status_code == 200
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / "whole_run_map.png").write_bytes(client.get(done["artifacts"]["map.png"]).content)


def test_reencoded_gallery_photo_is_identified_and_unknown_photo_is_unscored(client: TestClient) -> None:
    h = home(client)
    g = h["gallery"][0]
    as_jpeg = io.BytesIO()
    Image.open(io.BytesIO(gallery_png(client, g))).convert("RGB").resize((400, 400)).save(as_jpeg, "JPEG", quality=80)
    run = client.post(
        "/api/runs", files={"goal_image": ("g.jpg", as_jpeg.getvalue(), "image/jpeg")}, data={"max_steps": "2"}
    ).json()
    assert run["target"]["instance_id"] == g["instance"] and run["target"]["identified_by"].startswith(
        "perceptual hash"
    )
    done = wait_final(client, run["id"])
    assert done["status"] == "finished" and done["outcome"] in ("success", "failure") and done["n_steps"] == 2

    rng = np.random.default_rng(7)
    other = (np.kron(rng.integers(0, 255, (12, 16, 3)), np.ones((20, 20, 1)))).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(other).save(buf, "PNG")
    run = client.post(
        "/api/runs", files={"goal_image": ("x.png", buf.getvalue(), "image/png")}, data={"max_steps": "2"}
    ).json()
    assert run["target"] is None
    done = wait_final(client, run["id"])
    assert done["outcome"] == "unscored" and "not scored" in done["outcome_detail"]


def test_a_search_under_the_stretch_profile(data_dir: Path) -> None:
    """``imgnav console --realism stretch``: the simulated robot has the profile's senses and motion."""
    import argparse
    import json
    import math

    from console.providers import console_realism

    realism = console_realism(argparse.Namespace(realism="stretch", realism_only=None, realism_seed=0))
    assert realism is not None and "goal_photo" not in realism.profile.components  # the operator's photo is real
    with TestClient(create_app(sim_console(data_dir, realism=realism))) as client:
        desc = client.get("/api/backends/sim").json()
        assert "stretch" in desc["label"], desc["label"]
        h = desc["homes"][0]
        g, start = pick_target(h)
        run = client.post(
            "/api/runs",
            files={"goal_image": ("goal.png", gallery_png(client, g), "image/png")},
            data={"home": h["id"], "start": start["id"], "gallery_item": g["item"], "max_steps": "5"},
        ).json()
        done = wait_final(client, run["id"])
        assert done["status"] == "finished" and done["outcome"] in ("success", "failure"), done
        traj = json.loads(client.get(done["artifacts"]["trajectory.json"]).content)
        poses = [(s["x_m"], s["y_m"], s["yaw_rad"]) for s in traj["steps"]]
        moves = [math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(poses, poses[1:])]
        turns = [abs(math.degrees(math.remainder(b[2] - a[2], math.tau))) for a, b in zip(poses, poses[1:])]
        # the robot's believed moves and turns land off the exact 0.25 m / 30 deg lattice (actuation, pose)
        off = [m for m in moves if m > 0.01 and abs(m - 0.25) > 0.003] + [
            t for t in turns if t > 1 and abs(t - 30) > 0.2
        ]
        assert off, (moves, turns)


def test_second_run_409_and_stop_mid_run(client: TestClient) -> None:
    h = home(client)
    g = h["gallery"][0]
    png = gallery_png(client, g)
    first = client.post("/api/runs", files={"goal_image": ("g.png", png, "image/png")}, data={"home": h["id"]}).json()
    second = client.post("/api/runs", files={"goal_image": ("g.png", png, "image/png")})
    assert second.status_code == 409 and second.json()["detail"]["code"] == "run_active"
    poll(lambda: client.get(f"/api/runs/{first['id']}").json()["n_steps"], lambda n: n >= 2, 300, "two steps")
    assert client.post(f"/api/runs/{first['id']}/stop").json()["stopping"] is True
    at_stop = client.get(f"/api/runs/{first['id']}").json()["n_steps"]
    done = wait_final(client, first["id"])
    assert done["status"] == "stopped" and done["outcome"] == "stopped"
    assert 2 <= done["n_steps"] <= at_stop + 1  # the step under way when the stop came, no more
    assert "run.webp" in done["artifacts"]


def test_restart_recovery(data_dir: Path) -> None:
    console = sim_console(data_dir)
    client = TestClient(create_app(console, close_on_shutdown=False))
    h = home(client)
    g = h["gallery"][0]
    run = client.post("/api/runs", files={"goal_image": ("g.png", gallery_png(client, g), "image/png")}).json()
    poll(lambda: client.get(f"/api/runs/{run['id']}").json()["status"], lambda s: s == "running", 60, "running")
    # A second process opening the same data dir finds the run active: the first "died"
    # (the kernel drops a dead process's flock; releasing it here stands in for that).
    console.lock.release()
    console2 = sim_console(data_dir)
    with TestClient(create_app(console2)) as client2:
        row = client2.get(f"/api/runs/{run['id']}").json()
        assert row["status"] == "interrupted" and row["outcome"] == "interrupted"
        assert client2.get("/api/runs").json()["runs"][0]["id"] == run["id"]
    console.close()  # clean shutdown of the first: stops its robot


def test_bad_simulator_options(client: TestClient) -> None:
    h = home(client)
    png = gallery_png(client, h["gallery"][0])
    for data, fragment in [
        ({"home": "home-999"}, "no home"),
        ({"start": "nowhere"}, "no start"),
        ({"start": "1,2"}, "no start"),
        ({"start": "a,b,c"}, "x,y,yaw_deg"),
        ({"gallery_item": "home-999/i1-v0"}, "no gallery image"),
        ({"gallery_item": "../../etc/passwd"}, "no gallery image"),
        ({"max_steps": "0"}, "between 1 and 1000"),
        ({"max_steps": "5000"}, "between 1 and 1000"),
        ({"target_instance": "x"}, "integer"),
        # custom starts that the robot cannot stand on: refused at upload, not in the run's history
        ({"start": "0,0,0"}, "not a free position"),
        ({"start": "1000,1000,0"}, "not a free position"),
        ({"start": "1e308,0,0"}, "start (1e+308, 0.00) is not a free position"),  # not its 309 digits
    ]:
        resp = client.post("/api/runs", files={"goal_image": ("g.png", png, "image/png")}, data=data)
        assert resp.status_code == 422, (data, resp.text)
        assert fragment in resp.json()["detail"]["message"], (data, resp.json())
    assert client.get("/api/runs").json()["runs"] == []  # nothing was started
    assert client.get("/api/sim/gallery/home-0/..%2F..%2Fcatalog.json").status_code == 404
    assert client.get(f"/api/sim/gallery/home-{HOME_SEED}/catalog.json").status_code == 404


def test_episode_choice_sets_home_start_and_target(sim_data_dir: Path, tmp_path: Path) -> None:
    from agent.types import Pose2D
    from console.context import Console, ConsoleConfig
    from console.options import RunForm
    from console.sim_provider import SimProvider, SimProviderConfig
    from sim.episodes import Episode, save_episode_set

    eps = tmp_path / "eps"
    (eps / "goals").mkdir(parents=True)
    shutil.copy(next((sim_data_dir / "sim" / f"home-{HOME_SEED}").glob("*.png")), eps / "goals" / "e0.png")
    episode = Episode("val-test-0", "val", 12345, Pose2D(1.0, 1.0, 0.0), 0, "chair", "goals/e0.png", ((2.0, 2.0),), 1.5)
    save_episode_set(eps, "val", 0, [episode], {})
    data = tmp_path / "data"
    shutil.copytree(sim_data_dir / "sim", data / "sim")
    provider = SimProvider(data, SimProviderConfig(home_seeds=(HOME_SEED,), episodes_dir=eps))
    console = Console(ConsoleConfig(data_dir=data, viewer=None, allowed_hosts=("testserver",)), {"sim": provider})
    with TestClient(create_app(console)) as client:
        desc = client.get("/api/backends/sim").json()
        assert [e["id"] for e in desc["episodes"]] == ["val-test-0"]
        png = client.get(desc["episodes"][0]["goal_image_url"])
        assert png.status_code == 200
        resolved = provider.resolve(RunForm(episode="val-test-0"), 0, "")
        assert resolved.target["instance_id"] == 0 and resolved.target["identified_by"] == "episode"
        assert resolved.options["home_seed"] == 12345 and resolved.options["start_pose_world"] == [1.0, 1.0, 0.0]
        for data_, fragment in [
            ({"episode": "nope"}, "no episode"),
            ({"episode": "val-test-0", "home": "home-0"}, "fixes home"),
        ]:
            resp = client.post("/api/runs", files={"goal_image": ("g.png", png.content, "image/png")}, data=data_)
            assert resp.status_code == 422 and fragment in resp.json()["detail"]["message"]
        assert client.get("/api/sim/episodes/..%2F..%2Fetc/goal.png").status_code == 404


def test_catalog_starts_are_free_positions(data_dir: Path) -> None:
    """The start check refuses colliding poses only: every start the console offers passes it."""
    from console import sim_adapter

    console = sim_console(data_dir)
    try:
        provider = console.providers["sim"]
        for home in provider.homes.values():
            for start in home.starts:
                x, y, _ = start.pose_world
                assert not sim_adapter.start_collides(home.seed, provider.config.n_rooms, x, y), (home.id, start)
    finally:
        console.close()
