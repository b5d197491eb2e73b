"""The console's memory of each home (console/home_memory.py, console/routes/memory.py, issue 31):
the file format, one memory per home, a corrupt file, forgetting, and the endpoints' checks."""

from __future__ import annotations

import io
import json
import logging
import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from fastapi.testclient import TestClient
from PIL import Image

from agent.config import AgentConfig
from agent.memory import HomeMemory
from agent.reid import Features
from agent.types import CandidateInfo, Pose2D
from console import sim_adapter
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.home_memory import HomeMemories, MemoryInUse, memory_bytes, memory_from_bytes
from console.options import SimRunOptions
from console.session import ResolvedRun
from console.sim_provider import SimProvider
from tests.helpers.agent_scenes import observation

CONFIG = AgentConfig()


def filled_memory() -> HomeMemory:
    """Two goals' worth: keyframes with torch descriptors and a nested matcher payload, map cells,
    a goal summary with candidates."""
    mem = HomeMemory(CONFIG.memory)
    for goal in range(2):
        grid = mem.begin_goal(CONFIG.mapping, "xfeat")
        grid.layers.obstacle[10 + goal, 20:30] = True
        grid.layers.visited[40, 40 + goal] = True
        for k in range(3):
            n = 12 + k
            feats = Features(
                np.random.default_rng(k).random((n, 2), np.float32) * 100,
                torch.randn(n, 64, generator=torch.Generator().manual_seed(k)),
                (640, 480),
                {"kpts_resized": torch.arange(2 * n, dtype=torch.float32).reshape(n, 2), "scale": (1.5, 2), "n": n},
            )
            pts = np.random.default_rng(10 + k).random((n, 3)).astype(np.float32)
            pts[0] = np.nan
            obs = observation([], Pose2D(1.5 * k, -0.5 * goal, math.radians(45 * k)), step=k)
            assert mem.offer(obs, feats, pts, "xfeat") is not None
        mem.goals[-1] = replace(
            mem.goals[-1],
            steps=7,
            final_mode="stopped",
            candidates=(
                CandidateInfo(0, "confirmed", (1.25, -2.5), 3, 31.5, 0.8),
                CandidateInfo(1, "rejected", (0.0, 1.0), 1, 9.0, 2.0, "lost"),
            ),
        )
    mem.last_pose = Pose2D(0.5, 0.25, 1.0)
    return mem


def test_a_memory_file_gives_back_the_memory_it_was_written_from() -> None:
    mem = filled_memory()
    data = memory_bytes(mem, Pose2D(3.0, 4.0, 0.5))
    back, anchor = memory_from_bytes(data, CONFIG.memory, CONFIG.mapping, "xfeat")
    assert anchor == Pose2D(3.0, 4.0, 0.5)
    assert back.summary() == mem.summary()
    assert back.goal_index == 1 and back.matcher == "xfeat" and back.last_pose == mem.last_pose
    assert back.grid is not None and mem.grid is not None and back.grid.origin_ij == mem.grid.origin_ij
    for name in mem.grid.layers.names():
        assert np.array_equal(getattr(back.grid.layers, name), getattr(mem.grid.layers, name)), name
    assert len(back) == len(mem) > 0
    for a, b in zip(mem.keyframes, back.keyframes, strict=True):
        assert (a.id, a.goal_index, a.step, a.pose, a.image_size_wh) == (
            b.id,
            b.goal_index,
            b.step,
            b.pose,
            b.image_size_wh,
        )
        assert np.array_equal(a.keypoints_xy, b.keypoints_xy)
        assert np.array_equal(a.points_xyz, b.points_xyz, equal_nan=True)
        fa, fb = a.features(), b.features()
        assert isinstance(fb.descriptors, torch.Tensor) and fb.descriptors.dtype == fa.descriptors.dtype
        assert torch.equal(fa.descriptors, fb.descriptors)
        assert torch.equal(fa.extra["kpts_resized"], fb.extra["kpts_resized"])
        assert fb.extra["scale"] == (1.5, 2) and fb.extra["n"] == fa.extra["n"]
    # the restored memory goes on as the original would: the next goal and the next keyframe id
    back.begin_goal(CONFIG.mapping, "xfeat")
    mem.begin_goal(CONFIG.mapping, "xfeat")
    assert back.summary() == mem.summary()
    obs = observation([], Pose2D(9.0, 9.0, 0.0), step=0)
    f = Features(np.zeros((3, 2), np.float32), torch.zeros(3, 64), (640, 480))
    kb = back.offer(obs, f, np.ones((3, 3), np.float32), "xfeat")
    km = mem.offer(obs, f, np.ones((3, 3), np.float32), "xfeat")
    assert kb is not None and km is not None and kb.id == km.id


def test_a_file_for_another_matcher_or_mapping_is_refused() -> None:
    from console.home_memory import MemoryFileError

    data = memory_bytes(filled_memory(), None)
    with pytest.raises(MemoryFileError, match="descriptors"):
        memory_from_bytes(data, CONFIG.memory, CONFIG.mapping, "aliked")
    with pytest.raises(MemoryFileError, match="mapping"):
        memory_from_bytes(data, CONFIG.memory, replace(CONFIG.mapping, resolution_m=0.1), "xfeat")


def memories(tmp_path: Path) -> HomeMemories:
    return HomeMemories(tmp_path / "memory", CONFIG.memory, CONFIG.mapping, "xfeat")


def test_each_home_has_its_own_memory_kept_across_a_restart(tmp_path: Path) -> None:
    store = memories(tmp_path)
    a = store.acquire("home-0")
    assert store.slot("home-0") is a and store.slot("home-1") is not a
    assert store.slot("home-1").memory is not a.memory
    with pytest.raises(MemoryInUse):
        store.acquire("home-0")  # one run at a time uses a home's memory
    a.memory = filled_memory()
    a.anchor_world = Pose2D(1.0, 2.0, 0.0)
    store.release(a)
    assert (tmp_path / "memory" / "home-0.npz").is_file() and not (tmp_path / "memory" / "home-1.npz").exists()
    again = memories(tmp_path)  # a new console on the same data directory
    assert again.summary("home-0")["goals"] == a.memory.summary()["goals"]
    assert again.summary("home-0")["keyframes"] == len(a.memory) > 0
    assert again.slot("home-0").anchor_world == Pose2D(1.0, 2.0, 0.0)
    assert again.summary("home-1")["keyframes"] == 0 and again.summary("home-1")["goals"] == []
    with pytest.raises(ValueError):
        again.slot("../home-0")


def test_a_corrupt_file_is_reported_kept_aside_and_the_home_starts_empty(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    d = tmp_path / "memory"
    d.mkdir()
    (d / "home-0.npz").write_bytes(b"PK\x03\x04 not really a zip")
    good = memory_bytes(filled_memory(), None)
    (d / "home-1.npz").write_bytes(good[: len(good) // 2])  # cut short
    # a well-formed archive whose JSON is not a memory's (a node of the wrong shape)
    buf = io.BytesIO()
    meta: dict[str, Any] = {
        "format": 1,
        "anchor_world": None,
        "goal_index": 0,
        "matcher": "xfeat",
        "last_pose": None,
        "next_id": 1,
    }
    meta |= {"goals": [], "grid": None, "keyframes": [{"id": 0, "goal_index": 0, "step": 0, "pose": [0, 0, 0]}]}
    meta["keyframes"][0] |= {"matcher": "xfeat", "keypoints_xy": "a0", "points_xyz": "a1", "image_size_wh": [4, 4]}
    meta["keyframes"][0] |= {"descriptors": {"dict": [1, 2]}, "extra": {"dict": {}}}
    np.savez(buf, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), a0=np.zeros((2, 2)), a1=np.zeros((2, 3)))
    (d / "home-2.npz").write_bytes(buf.getvalue())
    store = memories(tmp_path)
    with caplog.at_level(logging.ERROR, logger="console.home_memory"):
        assert store.summary("home-0")["keyframes"] == 0
        assert store.summary("home-1")["goals"] == []
        assert store.summary("home-2")["keyframes"] == 0
    errors = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 3 and all("cannot be used" in m and "moved to" in m for m in errors), errors
    aside = sorted(p.name for p in d.glob("*.unreadable-*.npz"))
    assert len(aside) == 3 and [a.split(".")[0] for a in aside] == ["home-0", "home-1", "home-2"]
    assert (d / aside[1]).read_bytes() == good[: len(good) // 2]  # kept as it was
    assert not (d / "home-0.npz").exists()


def test_forget_empties_the_home_and_removes_its_file_but_not_while_a_run_uses_it(tmp_path: Path) -> None:
    store = memories(tmp_path)
    slot = store.acquire("home-0")
    slot.memory = filled_memory()
    with pytest.raises(MemoryInUse):
        store.forget("home-0")
    store.release(slot)
    other = store.acquire("home-1")
    other.memory = filled_memory()
    store.release(other)
    assert store.forget("home-0") is True
    assert not (tmp_path / "memory" / "home-0.npz").exists()
    assert store.summary("home-0")["goals"] == [] and len(store.slot("home-0").memory) == 0
    assert memories(tmp_path).summary("home-0")["goals"] == []  # and after a restart
    assert memories(tmp_path).summary("home-1")["goals"] != []  # the other home is untouched
    assert store.forget("home-0") is False


def test_an_empty_memory_takes_the_runs_start_as_its_frame(tmp_path: Path) -> None:
    slot = memories(tmp_path).slot("home-0")
    a, b = Pose2D(1.0, 2.0, math.pi / 2), Pose2D(3.0, 2.0, 0.0)
    assert slot.origin_for(a) == Pose2D(0.0, 0.0, 0.0)
    slot.memory.begin_goal(CONFIG.mapping)
    origin = slot.origin_for(b)  # b in a's frame: 2 m ahead of a is -2 m on a's y axis
    assert origin.x_m == pytest.approx(0.0, abs=1e-9) and origin.y_m == pytest.approx(-2.0)
    assert origin.yaw_rad == pytest.approx(-math.pi / 2)


# --- the provider: which memory a run gets -----------------------------------------------------


def sim_run(seed: int, start: tuple[float, float, float] = (1.0, 1.0, 0.0)) -> ResolvedRun:
    return ResolvedRun("sim", SimRunOptions(seed, start, 5, home=f"home-{seed}", start="custom"), None)


def test_runs_in_one_home_share_its_memory_and_runs_in_another_home_do_not(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    given: list[Any] = []

    def fake_open_session(**kw: Any) -> Any:
        given.append(kw["memory"])

        class Session:
            def close(self) -> None:
                kw["on_close"]()

        return Session()

    monkeypatch.setattr(sim_adapter, "open_session", fake_open_session)
    provider = SimProvider(tmp_path)
    rgb = np.zeros((8, 8, 3), np.uint8)
    s0 = provider.open(sim_run(0), rgb)
    with pytest.raises(MemoryInUse):
        provider.open(sim_run(0), rgb)  # the same home while its memory is in use
    given[0].memory.begin_goal(CONFIG.mapping)  # the run's agent started a goal
    s0.close()
    provider.open(sim_run(0, (2.0, 1.0, 0.0)), rgb).close()
    provider.open(sim_run(1), rgb).close()
    assert given[0] is given[1] and given[0].key == "home-0"
    assert given[2] is not given[0] and given[2].key == "home-1" and given[2].memory is not given[0].memory
    assert (tmp_path / "memory" / "home-0.npz").is_file()  # saved when the run closed
    assert provider.memory_key(SimRunOptions(4, (0, 0, 0), 5, episode="e1")) == "scene-4"


def test_a_run_with_memory_off_starts_from_nothing_and_leaves_the_home_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from console.session import OptionsError
    from console.sim_provider import _check_memory

    given: list[Any] = []

    def fake_open_session(**kw: Any) -> Any:
        given.append(kw)
        return object()

    monkeypatch.setattr(sim_adapter, "open_session", fake_open_session)
    provider = SimProvider(tmp_path)
    off = ResolvedRun("sim", SimRunOptions(0, (1.0, 1.0, 0.0), 5, home="home-0", memory="off"), None)
    provider.open(off, np.zeros((8, 8, 3), np.uint8))
    assert given[0]["memory"] is None and given[0]["on_close"] is None
    assert not provider.memories().slot("home-0").in_use and not (tmp_path / "memory").exists()
    assert [_check_memory(v) for v in (None, "on", "off")] == [None, None, "off"]
    with pytest.raises(OptionsError, match="memory must be"):
        _check_memory("maybe")


def test_a_run_that_fails_to_open_releases_the_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def failing(**kw: Any) -> Any:
        raise RuntimeError("no world")

    monkeypatch.setattr(sim_adapter, "open_session", failing)
    provider = SimProvider(tmp_path)
    with pytest.raises(RuntimeError):
        provider.open(sim_run(0), np.zeros((8, 8, 3), np.uint8))
    assert provider.memories().acquire("home-0").in_use  # free again


# --- the endpoints -------------------------------------------------------------------------------


@pytest.fixture
def token_console(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[TestClient, SimProvider]]:
    provider = SimProvider(tmp_path / "data")
    monkeypatch.setattr(provider, "memory_keys", lambda: ["home-0", "home-1"])
    store = provider.memories()
    slot = store.acquire("home-0")
    slot.memory = filled_memory()
    store.release(slot)
    console = Console(
        ConsoleConfig(data_dir=tmp_path / "data", viewer=None, token="sesame", allowed_hosts=("testserver",)),
        {"sim": provider},
    )
    with TestClient(create_app(console)) as client:
        yield client, provider


def test_the_memory_endpoints_show_a_home_and_forget_it_only_with_the_consoles_checks(token_console) -> None:
    client, provider = token_console
    got = client.get("/api/memory/home-0")
    assert got.status_code == 200, got.text
    body = got.json()
    assert body["keyframes"] == 6 and body["keyframe_bytes"] > 0 and body["map_bytes"] > 0
    assert body["map_url"] == "/api/memory/home-0/map.png"
    cands = body["goals"][1]["candidates"]
    assert cands[0] == {"id": 0, "state": "confirmed", "xy_m": [1.25, -2.5], "best_score": 31.5}
    png = client.get(body["map_url"])
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert Image.open(io.BytesIO(png.content)).size == (480, 480)
    assert client.get("/api/memory/home-7").status_code == 404
    assert client.get("/api/memory/..%2Fx").status_code == 404

    path = provider.memories().path("home-0")
    refused = [
        client.delete("/api/memory/home-0"),  # no token
        client.delete("/api/memory/home-0", headers={"X-Imgnav-Token": "wrong"}),
        client.delete(
            "/api/memory/home-0", headers={"X-Imgnav-Token": "sesame", "Origin": "http://evil.example"}
        ),  # another origin
        client.delete("/api/memory/home-0?token=sesame", headers={"Host": "evil.example"}),  # DNS rebinding
    ]
    assert [r.status_code for r in refused] == [401, 401, 403, 400], [r.text for r in refused]
    assert path.is_file() and client.get("/api/memory/home-0").json()["keyframes"] == 6

    slot = provider.memories().acquire("home-0")  # a run in the home
    busy = client.delete("/api/memory/home-0?token=sesame")
    assert busy.status_code == 409 and busy.json()["detail"]["code"] == "memory_in_use"
    provider.memories().release(slot, save=False)

    ok = client.delete("/api/memory/home-0?token=sesame", headers={"Origin": "http://testserver"})
    assert ok.status_code == 200 and ok.json() == {"home": "home-0", "forgotten": True}
    assert not path.exists()
    after = client.get("/api/memory/home-0").json()
    assert after["keyframes"] == 0 and after["goals"] == []
