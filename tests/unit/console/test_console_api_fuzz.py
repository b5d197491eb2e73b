"""API fuzzing with schemathesis against the app's own /openapi.json: generated requests
(valid and invalid) to every operation, no server error (5xx) allowed. A new route that can
be made to crash is caught here. Bounded: a few examples per operation, so it stays fast.

Random ids only reach the 404 branch of a route (issue 33: 13 of 19 operations mostly answered
404), so the console is given a real finished run (with its replay steps and artifacts) and a
real calibration job first, and the schema's id parameters are narrowed to those ids (and one
unknown id): generated requests then read, replay, stop, save and undo real records.

The two server-sent-event streams are left out: a valid request to them never ends (their
behaviour is tested in test_console_events.py and the API tests).

``goal_from_run`` (asking for a known object again, issue 31) is fuzzed on its own against a
console whose home remembers real runs (the schema only knows it as a string, and the scripted
backend keeps no memory, so schemathesis reaches only its first refusal): hostile ids (random
text, path traversal, very long, unicode, ids of the right shape that name no run, runs of
another home or not remembered), alone or with a goal photo, ``memory=off`` or a gallery item.
Each is a 4xx with the API's JSON error, starts no run and writes no file."""

from __future__ import annotations

import copy
import re
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error

from agent.config import AgentConfig
from agent.memory import HomeMemory
from agent.reid.base import Features, Matches
from agent.reid.identifier import ReIDConfig
from console import sim_adapter
from console.api import create_app
from console.artifacts import run_dir
from console.calibration import Calibrator
from console.context import Console, ConsoleConfig
from console.options import SimRunOptions
from console.sim_catalog import HomeEntry, Start
from console.sim_provider import SimProvider
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb

UNKNOWN_ID = "0123456789ab"


class _TopBandMatcher:
    """Stand-in for the matcher: photos whose top band is the same object match strongly."""

    name = "stand-in"

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        top = rgb[:8].reshape(-1, 3)[:64].astype(np.float32)
        return Features(np.zeros((1, 2), np.float32), top, (rgb.shape[1], rgb.shape[0]))

    def match(self, goal: Features, obs: Features) -> Matches:
        n = 40 if float(np.abs(goal.descriptors - obs.descriptors).mean()) < 30 else 4
        return Matches(np.arange(n), np.arange(n), np.full(n, 0.9 if n == 40 else 0.3, np.float32))


def _photo(obj: int, view: int) -> bytes:
    rgb = textured_rgb(96, 128, seed=1000 + 100 * obj + view)
    rgb[:16] = textured_rgb(16, 128, seed=obj)  # the object; the rest of the picture is the view
    return encode(rgb, "JPEG", quality=92)


@pytest.fixture(scope="module")
def fuzz_console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Console, dict[str, Any]]]:
    """A console holding one finished run and one done calibration job; their ids."""
    console = Console(
        ConsoleConfig(data_dir=tmp_path_factory.mktemp("fuzz"), viewer=None, allowed_hosts=("testserver", "localhost")),
        {"scripted": ScriptedProvider(stop_after=3)},
    )
    console.calibrator = Calibrator(
        console.data_dir, matcher_for=lambda d: (_TopBandMatcher(), ReIDConfig(matcher="xfeat_lighterglue"))
    )
    with TestClient(create_app(console, close_on_shutdown=False)) as c:
        photo = {"goal_image": ("g.jpg", _photo(0, 0), "image/jpeg")}
        run_id = c.post("/api/runs", files=photo).json()["id"]
        poll(lambda: c.get(f"/api/runs/{run_id}").json()["status"], lambda s: s in ("finished", "stopped"))
        objects = [(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(3)]
        files = [("photos", (f"{n}-{v}.jpg", _photo(o, v), "image/jpeg")) for n, o, v in objects]
        job = c.post("/api/calibration/sim", files=files, data={"objects": [n for n, _, _ in objects]}).json()
        poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json()["state"], lambda s: s == "done")
        steps = len(c.get(f"/api/runs/{run_id}/replay").json()["steps"])
        artifacts = sorted(c.get(f"/api/runs/{run_id}").json()["artifacts"])
    assert steps >= 2 and artifacts
    yield console, {"run_id": run_id, "job_id": job["id"], "steps": steps, "artifacts": artifacts}
    console.close()


def _narrowed(raw: dict[str, Any], known: dict[str, Any]) -> dict[str, Any]:
    """The schema with its id parameters drawn from the real records (and one unknown id)."""
    choices: dict[str, list[Any]] = {
        "run_id": [known["run_id"], UNKNOWN_ID],
        "job_id": [known["job_id"], UNKNOWN_ID],
        "name": [*known["artifacts"], "console.sqlite3"],
        "step": [*range(known["steps"]), known["steps"] + 1000],
    }
    out = copy.deepcopy(raw)
    for ops in out["paths"].values():
        for op in ops.values():
            for param in op.get("parameters", []):
                if param["in"] == "path" and param["name"] in choices:
                    param["schema"] = {"enum": choices[param["name"]]}
    return out


@pytest.fixture(scope="module")
def api_schema(fuzz_console: tuple[Console, dict[str, Any]]):
    console, known = fuzz_console
    app = create_app(console, close_on_shutdown=False)
    with TestClient(app) as c:
        raw = c.get("/openapi.json").json()
    schema = schemathesis.openapi.from_dict(_narrowed(raw, known))
    schema.app = app
    return schema.exclude(path_regex=r"events$")


# operations that must answer 2xx to at least one generated request: the deep paths
DEEP = {
    "GET /api/runs/{run_id}",
    "GET /api/runs/{run_id}/artifacts/{name}",
    "GET /api/runs/{run_id}/replay",
    "GET /api/runs/{run_id}/replay/latest",
    "GET /api/runs/{run_id}/replay/{step}",
    "GET /api/runs/{run_id}/replay/{step}/frame.jpg",
    "GET /api/runs/{run_id}/replay/{step}/map.png",
    "GET /api/calibration/jobs/{job_id}",
    "POST /api/calibration/jobs/{job_id}/save",
    "GET /api/calibration/jobs",
}


def test_no_server_error(api_schema) -> None:
    # Hypothesis over each operation's case strategy (schemathesis's pytest plugin does not load
    # under this pytest); every failing operation is reported, not just the first.
    failures: list[str] = []
    calls: dict[str, int] = {}
    statuses: dict[str, set[int]] = {}
    for result in api_schema.get_all_operations():
        operation = result.ok()
        label = f"{operation.method.upper()} {operation.path}"

        @given(case=operation.as_strategy())
        @settings(
            max_examples=12, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck)
        )
        def fuzz(case) -> None:
            # fuzz() runs within this iteration, so the loop variable is the one it was built for
            calls[label] = calls.get(label, 0) + 1  # noqa: B023
            response = case.call_and_validate(checks=[not_a_server_error])
            statuses.setdefault(label, set()).add(response.status_code)  # noqa: B023

        try:
            fuzz()
        except Exception as exc:  # collect and report all operations' failures together
            failures.append(f"{label}: {exc}")
    assert not failures, "\n\n".join(failures)
    assert len(calls) >= 8 and min(calls.values()) >= 1, calls  # every path was exercised
    shallow = sorted(op for op in DEEP if not any(200 <= s < 300 for s in statuses.get(op, ())))
    assert not shallow, {op: sorted(statuses.get(op, ())) for op in shallow}  # reached real records


def test_fuzzing_covers_the_state_changing_routes(api_schema) -> None:
    paths = {op.path for op in (result.ok() for result in api_schema.get_all_operations())}
    assert {"/api/runs", "/api/runs/{run_id}/stop", "/api/runs/{run_id}/artifacts/{name}"} <= paths, paths
    assert {"/api/calibration/jobs/{job_id}/save", "/api/calibration/{deployment}/undo"} <= paths, paths
    assert not any(p.endswith("events") for p in paths)


# --- goal_from_run (issue 31) ----------------------------------------------------------------

# the stored runs of the memory console: "asked" is a request home-0 remembers (the one id that
# would start a run on its own), "other" one of home-1, "unremembered" a run in home-0 its memory
# does not hold, "gone" a request home-0 remembers whose run is no longer stored
MEMORY_RUNS = {"asked": "00000000000b", "other": "00000000000c", "unremembered": "00000000000d", "gone": "00000000000a"}
RUN_ID_SHAPE = re.compile(r"[0-9a-f]{12}")


@pytest.fixture(scope="module")
def memory_console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, Console, Path]]:
    """A console on the simulator backend (catalogue given, no simulator: a run that starts fails
    at once) whose home-0 remembers two requests and home-1 one; the client, the console and the
    folder its data directory is in (three levels up: where ``../`` ids would land)."""
    root = tmp_path_factory.mktemp("fuzz-memory")
    data = root / "a" / "b" / "data"
    provider = SimProvider(data)
    starts = (Start("r0", "middle", (1.0, 1.0, 0.0)),)
    provider._homes = {f"home-{s}": HomeEntry(f"home-{s}", s, f"home {s}", 3, starts, ()) for s in (0, 1)}
    provider._ready = True
    config = AgentConfig()
    memories = provider.memories()
    for key, run_ids in (("home-0", ["gone", "asked"]), ("home-1", ["other"])):
        slot = memories.acquire(key)
        memory = HomeMemory(config.memory)
        for _ in run_ids:
            memory.begin_goal(config.mapping, memories.matcher)
        memory.goals = [replace(g, run_id=MEMORY_RUNS[r]) for g, r in zip(memory.goals, run_ids, strict=True)]
        slot.memory = memory
        memories.release(slot)
    console = Console(ConsoleConfig(data_dir=data, viewer=None, allowed_hosts=("testserver",)), {"sim": provider})
    photo = encode(textured_rgb(64, 80, seed=3), "PNG")
    with TestClient(create_app(console, close_on_shutdown=False)) as client:
        for name, seed in (("asked", 0), ("other", 1), ("unremembered", 0)):
            run_id = MEMORY_RUNS[name]
            options = SimRunOptions(seed, (1.0, 1.0, 0.0), 5, home=f"home-{seed}", start="r0").to_json()
            console.store.create_run(
                run_id, backend="sim", options=options, goal={"path": "goal.png"}, target=None, created_s=1.0
            )
            console.store.update_run(run_id, status="finished")
            run_dir(data, run_id).mkdir(parents=True)
            (run_dir(data, run_id) / "goal.png").write_bytes(photo)
        yield client, console, root
    console.close()


def _files(root: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder under ``root``: its size and modification time."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*")}


_TEXT = st.characters(exclude_categories=("Cs",))  # any code point a form can carry (no lone surrogates)
HOSTILE_IDS = st.one_of(
    st.text(_TEXT, min_size=1, max_size=40),  # random strings
    st.builds(
        lambda up, tail: up + tail,
        st.sampled_from(["../", "../../", "../../../", "..\\", "/", "./", "%2e%2e/", "runs/../"]),
        st.sampled_from(["x", "etc/passwd", "data/console.sqlite3", MEMORY_RUNS["asked"], "memory/home-0.npz", ""]),
    ).filter(bool),  # path traversal
    st.builds(
        lambda c, n: c * n,
        st.sampled_from(["a", "0", "\u00e9", "\U0001f600"]),
        st.sampled_from([13, 4096, 70_000, 300_000]),
    ),
    st.text(st.characters(min_codepoint=0x80, exclude_categories=("Cs",)), min_size=1, max_size=24),  # unicode
    st.from_regex(RUN_ID_SHAPE, fullmatch=True).filter(lambda r: r not in MEMORY_RUNS.values()),  # no such run
    st.from_regex(RUN_ID_SHAPE, fullmatch=True).map(lambda r: r + "\n"),  # right shape, then a newline
    st.sampled_from([MEMORY_RUNS[k] for k in ("other", "unremembered", "gone")]),  # not this home's request
    st.just(MEMORY_RUNS["asked"]),  # remembered: refused only with a second goal or memory off (below)
)


@pytest.mark.slow  # about a second of fuzzing: make test runs it, make test-fast leaves it out
def test_goal_from_run_refuses_hostile_ids_without_starting_a_run_or_writing(
    memory_console: tuple[TestClient, Console, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    client, console, root = memory_console
    opened: list[Any] = []

    def no_simulator(**kw: Any) -> Any:  # a run that starts by mistake is seen here, then fails
        opened.append(kw)
        raise RuntimeError("no simulator in this test")

    monkeypatch.setattr(sim_adapter, "open_session", no_simulator)
    runs_before = [r["id"] for r in client.get("/api/runs").json()["runs"]]
    files_before = _files(root)
    photo = encode(textured_rgb(48, 64, seed=4), "PNG")
    codes: set[str] = set()

    @given(
        run_id=HOSTILE_IDS,
        with_photo=st.booleans(),
        memory=st.sampled_from([None, "on", "off"]),
        gallery=st.booleans(),
    )
    # a run of another home and one this home does not remember, each alone (the route's last checks)
    @example(run_id=MEMORY_RUNS["other"], with_photo=False, memory=None, gallery=False)
    @example(run_id=MEMORY_RUNS["unremembered"], with_photo=False, memory="on", gallery=False)
    @example(run_id="\U0001f600" * 300_000, with_photo=False, memory=None, gallery=False)  # a 1.2 MB form field
    @settings(max_examples=80, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
    def fuzz(run_id: str, with_photo: bool, memory: str | None, gallery: bool) -> None:
        # the one request that may start a run: the remembered id alone, with memory on
        assume(run_id != MEMORY_RUNS["asked"] or with_photo or memory == "off" or gallery)
        data = {"home": "home-0", "start": "r0", "goal_from_run": run_id, "max_steps": "5"}
        if memory is not None:
            data["memory"] = memory
        if gallery:
            data["gallery_item"] = "home-0/i0-v0"
        files = {"goal_image": ("g.png", photo, "image/png")} if with_photo else None
        response = client.post("/api/runs", data=data, files=files)
        assert 400 <= response.status_code < 500, (run_id[:80], response.status_code, response.text[:300])
        detail = response.json()["detail"]
        assert isinstance(detail["code"], str) and isinstance(detail["message"], str), detail
        codes.add(detail["code"])
        assert console.manager.active_run_id is None and not opened, run_id[:80]

    fuzz()
    assert [r["id"] for r in client.get("/api/runs").json()["runs"]] == runs_before  # no run was stored
    assert _files(root) == files_before  # nothing written, in the data directory or beside it
    # the examples reached the route's own checks, not only the first
    assert {"unknown_run", "two_goals", "memory_off", "foreign_run", "not_remembered"} <= codes, codes
