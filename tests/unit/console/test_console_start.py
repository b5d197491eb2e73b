"""The path from upload to the first action (issue 14). A run's time to it is kept in
consecutive parts (console.manager; printed by benchmarks/bench_console.py): the parts are
there, none is negative, and together they do not exceed the total (what they leave out is
the few statements between them). goal.png is written after the first action, or at the end
of a run that had none; the photo's blank check and torch's OpenMP wait policy."""

from __future__ import annotations

import io
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from console import agents
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.photos import _max_channel_std, decode_photo
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb

PARTS = ("request_s", "prepare_s", "open_s", "setup_s", "reset_s", "first_step_s")
SUB_PARTS = {
    "request_s": ("decode_s", "resolve_s", "record_s"),
    "reset_s": ("reset_backend_s", "reset_agent_s"),
    "first_step_s": ("first_act_s", "first_apply_s"),
}
CLOCKS_S = 0.002  # the request's part is wall clock, the others perf_counter


def test_first_action_parts_add_up_to_at_most_the_total(tmp_path: Path) -> None:
    console = Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("testserver",)), {"scripted": ScriptedProvider(3)}
    )
    try:
        with TestClient(create_app(console)) as client:
            resp = client.post(
                "/api/runs", files={"goal_image": ("g.jpg", encode(textured_rgb(120, 160), "JPEG"), "image/jpeg")}
            )
            assert resp.status_code == 201, resp.text
            run_id = resp.json()["id"]
            done = poll(lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] == "finished")
    finally:
        console.close()
    t = done["timings"]
    for key in (*PARTS, *(k for ks in SUB_PARTS.values() for k in ks)):
        assert isinstance(t.get(key), float) and t[key] >= 0.0, (key, t)
    assert sum(t[k] for k in PARTS) <= t["upload_to_first_action_s"] + CLOCKS_S, t
    for whole, parts in SUB_PARTS.items():
        assert sum(t[k] for k in parts) <= t[whole] + CLOCKS_S, (whole, t)
    assert t["first_act_s"] > 0.0  # the scripted agent's act is timed apart from the backend's apply


@pytest.mark.parametrize("fail_at", [None, 0])
def test_goal_png_is_written_after_the_first_action_or_at_the_end(tmp_path: Path, fail_at: int | None) -> None:
    upload = encode(textured_rgb(120, 160), "JPEG")
    console = Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("testserver",)),
        {"scripted": ScriptedProvider(3, fail_at)},
    )
    try:
        with TestClient(create_app(console)) as client:
            run_id = client.post("/api/runs", files={"goal_image": ("g.jpg", upload, "image/jpeg")}).json()["id"]
            done = poll(
                lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] in ("finished", "failed")
            )
            assert done["status"] == ("finished" if fail_at is None else "failed"), done
            assert {"goal.png", "goal_upload.jpg"} <= set(done["artifacts"])
            png = client.get(done["artifacts"]["goal.png"]).content
    finally:
        console.close()

    assert np.array_equal(np.asarray(Image.open(io.BytesIO(png)).convert("RGB")), decode_photo(upload).rgb)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_blank_check_spread_is_numpys_standard_deviation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    images = [
        rng.integers(0, 256, (37, 53, 3), dtype=np.uint8),
        np.full((20, 30, 3), (200, 100, 50), np.uint8),
        (np.full((64, 64, 3), 100) + rng.integers(0, 3, (64, 64, 3))).astype(np.uint8),
        textured_rgb(96, 128, seed),
    ]
    for rgb in images:
        assert _max_channel_std(rgb) == pytest.approx(float(rgb.reshape(-1, 3).std(axis=0).max()), rel=1e-9, abs=1e-12)


def test_openmp_waits_passively_unless_the_environment_says_otherwise(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(sys.modules, "torch", raising=False)  # as before the console imports it
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    assert agents.passive_openmp_wait() and os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")  # the operator's choice wins
    assert not agents.passive_openmp_wait() and os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    monkeypatch.setitem(sys.modules, "torch", object())  # too late to change: says so
    monkeypatch.delenv("OMP_WAIT_POLICY")
    assert not agents.passive_openmp_wait() and "OMP_WAIT_POLICY" not in os.environ
