"""The console's memory of each home (console/home_memory.py, console/routes/memory.py, issue 31):
the file format (with each goal's run, and the format before it), one memory per home, a corrupt
file, forgetting, the endpoints' checks, the known objects with their goal photos, and asking for
one again (``POST /api/runs`` with ``goal_from_run``) only with the console's checks and only in
its own home."""

from __future__ import annotations

import io
import json
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
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
from console.artifacts import run_dir
from console.context import Console, ConsoleConfig
from console.home_memory import HomeMemories, MemoryInUse
from console.memory_file import MemoryFileError, memory_bytes, memory_from_bytes
from console.options import SimRunOptions
from console.pictures import CANDIDATE_MARK_RGB, render_map
from console.session import ResolvedRun
from console.sim_catalog import HomeEntry, Start
from console.sim_provider import SimProvider
from tests.helpers.agent_scenes import observation
from tests.helpers.console_testkit import encode, poll, textured_rgb

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
    from console.memory_file import MemoryFileError

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
    from console.session import check_memory_option as _check_memory  # the simulator's and the Stretch's

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


# --- each goal's run ---------------------------------------------------------------------------


def rewritten(data: bytes, change: Any) -> bytes:
    """A memory file with its JSON member changed by ``change(meta)`` (the arrays kept)."""
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    change(meta)
    buf = io.BytesIO()
    np.savez(buf, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    return buf.getvalue()


def test_each_goals_run_is_saved_and_read_back_and_a_file_from_before_run_ids_still_reads() -> None:
    mem = filled_memory()
    mem.goals[1] = replace(mem.goals[1], run_id="0123456789ab")
    data = memory_bytes(mem, None)
    back, _ = memory_from_bytes(data, CONFIG.memory, CONFIG.mapping, "xfeat")
    assert [g.run_id for g in back.goals] == [None, "0123456789ab"]
    assert back.summary() == mem.summary() and back.summary()["goals"][1]["run_id"] == "0123456789ab"

    def format_1(meta: dict[str, Any]) -> None:  # as the console wrote it before goals had runs
        meta["format"] = 1
        for g in meta["goals"]:
            del g["run_id"]

    old, _ = memory_from_bytes(rewritten(data, format_1), CONFIG.memory, CONFIG.mapping, "xfeat")
    assert [g.run_id for g in old.goals] == [None, None]
    assert [replace(g, run_id=None) for g in back.goals] == old.goals and len(old) == len(back) > 0

    def bad_run(meta: dict[str, Any]) -> None:
        meta["goals"][1]["run_id"] = "../../etc"

    def later(meta: dict[str, Any]) -> None:
        meta["format"] = 3

    with pytest.raises(MemoryFileError, match="not a run id"):
        memory_from_bytes(rewritten(data, bad_run), CONFIG.memory, CONFIG.mapping, "xfeat")
    with pytest.raises(MemoryFileError, match=r"format 3, not one of \(1, 2\)"):
        memory_from_bytes(rewritten(data, later), CONFIG.memory, CONFIG.mapping, "xfeat")


def test_the_goal_a_run_begins_carries_its_id_while_it_runs_and_after_a_restart(tmp_path: Path) -> None:
    store = memories(tmp_path)
    first = store.acquire("home-0", "aaaaaaaaaaaa")
    first.memory.begin_goal(CONFIG.mapping)  # the run's agent starts its goal
    assert [g["run_id"] for g in store.summary("home-0")["goals"]] == ["aaaaaaaaaaaa"]  # while it runs
    assert not store.remembers("home-0", "aaaaaaaaaaaa")  # stamped only when the run ends
    store.release(first)
    assert store.remembers("home-0", "aaaaaaaaaaaa")
    no_goal = store.acquire("home-0", "bbbbbbbbbbbb")  # a run that ends before its agent's reset
    store.release(no_goal)
    third = store.acquire("home-0", "cccccccccccc")
    third.memory.begin_goal(CONFIG.mapping)
    store.release(third)
    again = memories(tmp_path)  # a new console on the same data directory
    assert [g.run_id for g in again.slot("home-0").memory.goals] == ["aaaaaaaaaaaa", "cccccccccccc"]
    assert [g["run_id"] for g in again.summary("home-0")["goals"]] == ["aaaaaaaaaaaa", "cccccccccccc"]
    assert not again.remembers("home-0", "bbbbbbbbbbbb") and not again.remembers("home-1", "aaaaaaaaaaaa")


def test_the_map_numbers_each_known_object_with_its_request(tmp_path: Path) -> None:
    point = np.array([[0.0, 0.0]])
    plain, view = render_map(None, extra_points_xy_m=point, size_px=240)
    labelled, _ = render_map(None, extra_points_xy_m=point, extra_labels=["2"], size_px=240)
    changed = np.argwhere((plain != labelled).any(axis=2))
    assert len(changed) > 20  # the digit's pixels
    u, v = view.to_px(point)[0]
    assert changed[:, 1].min() > u and changed[:, 0].max() < v + 2  # beside the mark, up and to the right
    assert (labelled == CANDIDATE_MARK_RGB).all(axis=2).sum() > (plain == CANDIDATE_MARK_RGB).all(axis=2).sum()
    # the memory's map: both requests found the object at (1.25, -2.5): one mark, numbered with both
    store = memories(tmp_path)
    slot = store.acquire("home-0")
    slot.memory = mem = filled_memory()
    store.release(slot)
    assert mem.grid is not None
    drawn = np.asarray(Image.open(io.BytesIO(store.map_png("home-0"))).convert("RGB"))
    one = np.array([[1.25, -2.5]])
    expected, _ = render_map(mem.grid.snapshot(), pose=mem.last_pose, extra_points_xy_m=one, extra_labels=["1,2"])
    assert np.array_equal(drawn, expected)


HOMES = {
    f"home-{seed}": HomeEntry(f"home-{seed}", seed, f"home {seed}", 3, (Start("r0", "middle", (1.0, 1.0, 0.0)),), ())
    for seed in (0, 1)
}


@dataclass(frozen=True)
class FindConsole:
    client: TestClient
    console: Console
    provider: SimProvider
    runs: dict[str, str]  # what each stored run is: its run id


def stored_run(console: Console, run_id: str, seed: int, photo: bytes | None) -> None:
    """A finished simulator run in ``home-<seed>`` as the store and the run's files keep it."""
    options = SimRunOptions(seed, (1.0, 1.0, 0.0), 5, home=f"home-{seed}", start="r0").to_json()
    console.store.create_run(
        run_id, backend="sim", options=options, goal={"path": "goal.png"}, target=None, created_s=1.0
    )
    console.store.update_run(run_id, status="finished")
    if photo is not None:
        run_dir(console.data_dir, run_id).mkdir(parents=True)
        (run_dir(console.data_dir, run_id) / "goal.png").write_bytes(photo)


@pytest.fixture
def find_console(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[FindConsole]:
    """A console with a token and two homes (no simulator: opening a run fails): home-0 remembers
    two requests, of a run that is gone and of a stored run ("asked"); home-1 one ("other");
    "unremembered" is a stored run in home-0 its memory does not hold."""
    provider = SimProvider(tmp_path / "data")
    monkeypatch.setattr(provider, "_homes", HOMES)
    monkeypatch.setattr(provider, "_ready", True)
    runs = {"gone": "00000000000a", "asked": "00000000000b", "other": "00000000000c", "unremembered": "00000000000d"}
    store = provider.memories()
    for key, run_ids in (("home-0", [runs["gone"], runs["asked"]]), ("home-1", [runs["other"]])):
        slot = store.acquire(key)
        slot.memory = filled_memory()
        slot.memory.goals = [replace(g, run_id=r) for g, r in zip(slot.memory.goals, run_ids, strict=False)]
        store.release(slot)
    console = Console(
        ConsoleConfig(data_dir=tmp_path / "data", viewer=None, token="sesame", allowed_hosts=("testserver",)),
        {"sim": provider},
    )
    photo = encode(textured_rgb(64, 80, seed=3), "PNG")
    with TestClient(create_app(console)) as client:
        stored_run(console, runs["asked"], 0, photo)
        stored_run(console, runs["other"], 1, photo)
        stored_run(console, runs["unremembered"], 0, photo)
        yield FindConsole(client, console, provider, runs)


def test_the_known_objects_show_the_goal_photo_of_their_run_and_none_for_a_run_that_is_gone(
    find_console: FindConsole,
) -> None:
    client, runs = find_console.client, find_console.runs
    body = client.get("/api/memory/home-0").json()
    assert [g["run_id"] for g in body["goals"]] == [runs["gone"], runs["asked"]]
    objects = body["objects"]  # both requests ended with a confirmed candidate (and a rejected one)
    assert [(o["request"], o["run_id"], o["state"], o["best_score"], o["candidates"]) for o in objects] == [
        (1, runs["gone"], "confirmed", 31.5, 1),
        (2, runs["asked"], "confirmed", 31.5, 1),
    ]
    assert objects[0]["goal_url"] is None  # its run was deleted: no thumbnail, no error
    assert objects[1]["goal_url"] == f"/api/runs/{runs['asked']}/artifacts/goal.png"
    photo = client.get(objects[1]["goal_url"])
    assert photo.status_code == 200 and Image.open(io.BytesIO(photo.content)).size == (80, 64)
    (run_dir(find_console.console.data_dir, runs["asked"]) / "goal.png").unlink()  # its files removed
    assert [o["goal_url"] for o in client.get("/api/memory/home-0").json()["objects"]] == [None, None]


def test_finding_an_object_again_needs_the_token_and_a_run_this_home_remembers(
    find_console: FindConsole, monkeypatch: pytest.MonkeyPatch
) -> None:
    client, console, runs = find_console.client, find_console.console, find_console.runs
    opened: list[Any] = []

    def no_simulator(**kw: Any) -> Any:
        opened.append((kw["memory"].key, kw["memory"].run_id))
        raise RuntimeError("no simulator in this test")

    monkeypatch.setattr(sim_adapter, "open_session", no_simulator)

    def find(run_id: str, headers: dict[str, str] | None = None, **form: Any) -> Any:
        data = {"home": "home-0", "start": "r0", "goal_from_run": run_id, **form}
        return client.post("/api/runs", data=data, headers={"X-Imgnav-Token": "sesame", **(headers or {})})

    refused = {
        "no token": client.post("/api/runs", data={"home": "home-0", "goal_from_run": runs["asked"]}),
        "wrong token": find(runs["asked"], {"X-Imgnav-Token": "wrong"}),
        "another origin": find(runs["asked"], {"Origin": "http://evil.example"}),
        "another host": find(runs["asked"], {"Host": "evil.example"}),
        "malformed id": find("../../etc/passwd"),
        "unknown run": find("0123456789ff"),
        "deleted run": find(runs["gone"]),  # remembered, but its run is gone
        "another home's": find(runs["other"]),
        "not remembered": find(runs["unremembered"]),
        "memory off": find(runs["asked"], memory="off"),
        "and a gallery item": find(runs["asked"], gallery_item="home-0/i0-v0"),
    }
    photo = {"goal_image": ("g.png", encode(textured_rgb(64, 80, seed=4), "PNG"), "image/png")}
    refused["and a photo"] = client.post(
        "/api/runs", files=photo, data={"goal_from_run": runs["asked"], "token": "sesame"}
    )
    assert refused.pop("another host").status_code == 400  # the Host check (DNS rebinding): a plain text answer
    got = {k: (r.status_code, r.json()["detail"]["code"]) for k, r in refused.items()}
    assert got == {
        "no token": (401, "token_required"),
        "wrong token": (401, "token_required"),
        "another origin": (403, "cross_origin"),
        "malformed id": (422, "unknown_run"),
        "unknown run": (422, "unknown_run"),
        "deleted run": (422, "unknown_run"),
        "another home's": (422, "foreign_run"),
        "not remembered": (422, "not_remembered"),
        "memory off": (422, "memory_off"),
        "and a gallery item": (422, "two_goals"),
        "and a photo": (422, "two_goals"),
    }, {k: r.text for k, r in refused.items()}
    assert "was in home-1, not in home-0" in refused["another home's"].json()["detail"]["message"]
    stored = {runs["asked"], runs["other"], runs["unremembered"]}
    assert {r["id"] for r in client.get("/api/runs").json()["runs"]} == stored and opened == []  # none started
    no_photo = client.post("/api/runs", data={"home": "home-0", "token": "sesame"})
    assert (no_photo.status_code, no_photo.json()["detail"]["code"]) == (422, "no_goal_image")

    # the run the home remembers: started with its goal photo, from memory, in its home
    ok = find(runs["asked"])
    assert ok.status_code == 201, ok.text
    new = ok.json()
    assert new["goal"]["from_run"] == runs["asked"] and new["options"]["home"] == "home-0"
    assert "memory" not in new["options"]  # on
    source_png = (run_dir(console.data_dir, runs["asked"]) / "goal.png").read_bytes()
    assert (run_dir(console.data_dir, new["id"]) / "goal_upload.png").read_bytes() == source_png
    ended = poll(lambda: client.get(f"/api/runs/{new['id']}").json(), lambda r: r["status"] == "failed", 30, "end")
    assert "no simulator in this test" in ended["outcome_detail"]
    assert opened == [("home-0", new["id"])]  # the home's memory, noting the goal as this run's
    assert not find_console.provider.memories().slot("home-0").in_use  # released when its open failed
