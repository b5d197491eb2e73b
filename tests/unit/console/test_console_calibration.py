"""Calibrating a deployment's tau from the operator's photos: the API with a stand-in
matcher (fast, exact expectations) and every bad input. The real matcher on simulator
goal images is in tests/integration/console/test_console_calibration_sim.py."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from agent.reid.base import Features, Matches
from agent.reid.identifier import ReIDConfig
from console.api import create_app
from console.calibration import Calibrator
from console.context import Console, ConsoleConfig
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb


class ColourMatcher:
    """Photos of one object share a base texture (seed): many confident matches; others few."""

    name = "colour"

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        return Features(
            np.zeros((1, 2), np.float32), rgb.reshape(-1, 3)[:64].astype(np.float32), (rgb.shape[1], rgb.shape[0])
        )

    def match(self, goal: Features, obs: Features) -> Matches:
        same = float(np.abs(goal.descriptors - obs.descriptors).mean()) < 30
        n = 40 if same else 4
        return Matches(np.arange(n), np.arange(n), np.full(n, 0.9 if same else 0.3, np.float32))


def view_rgb(obj: int, view: int) -> np.ndarray:
    """The object is the top band (what ColourMatcher compares); the rest of the picture changes
    with the view, so that two views are distinct pictures, as two real views are."""
    rgb = textured_rgb(96, 128, seed=1000 + 100 * obj + view)
    rgb[:16] = textured_rgb(16, 128, seed=obj)
    return rgb


def photo_of(obj: int, view: int) -> bytes:
    return encode(view_rgb(obj, view), "JPEG", quality=92)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[tuple[Console, TestClient]]:
    console = Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("testserver",)), {"scripted": ScriptedProvider()}
    )
    console.calibrator = Calibrator(
        console.data_dir, matcher_for=lambda d: (ColourMatcher(), ReIDConfig(matcher="xfeat_lighterglue"))
    )
    with TestClient(create_app(console)) as c:
        yield console, c
    console.close()


def upload(objects: list[tuple[str, int, int]]) -> tuple[list[tuple[str, Any]], dict[str, list[str]]]:
    files = [("photos", (f"{label}-{view}.jpg", photo_of(obj, view), "image/jpeg")) for label, obj, view in objects]
    return files, {"objects": [label for label, _, _ in objects]}


def test_calibrate_from_photos_and_save(client) -> None:
    console, c = client
    before = c.get("/api/calibration").json()
    assert before["stretch"]["file"] is None and "packaged" in before["stretch"]["source"]
    files, data = upload([(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(3)])
    resp = c.post("/api/calibration/stretch", files=files, data=data)
    assert resp.status_code == 202, resp.text
    job = resp.json()
    assert job["objects"] == {"mug": 3, "chair": 3, "plant": 3} and job["photos"] == 9
    done = poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json(), lambda j: j["state"] in ("done", "failed"))
    assert done["state"] == "done", done
    result = done["result"]
    assert result["same_pairs"] == 9 and result["different_pairs"] == 27
    p = result["proposal"]
    # conf: same pairs 40 * 0.9 = 36, different 4 * 0.3 = 1.2 -> separable: F = 1 at tau 36
    assert p["score"] == "conf" and p["tau"] == pytest.approx(36.0) and p["max_f"] == pytest.approx(1.0)
    assert p["same_pairs_accepted"] == 9 and p["different_pairs_accepted"] == 0
    assert len(result["curves"]["conf"]["f_curve"]) == len(result["curves"]["conf"]["threshold"]) >= 2
    assert result["checks"]["savable"] and result["checks"]["problems"] == []
    assert result["checks"]["tau_band"]["packaged_tau"] == pytest.approx(75.303, abs=1e-3)
    assert sum(p["accepted"] for p in result["pair_scores"]) == 9  # the pairs behind it
    listed = c.get("/api/calibration/jobs").json()["jobs"]
    assert [(j["id"], j["state"], j["savable"]) for j in listed] == [(job["id"], "done", True)]
    assert "result" not in listed[0]
    saved = c.post(f"/api/calibration/jobs/{job['id']}/save")
    assert saved.status_code == 200, saved.text
    change = saved.json()
    # what changed: the old tau and where it came from, the new one and the pairs behind it
    assert change["previous"]["tau"] == pytest.approx(75.303, abs=1e-3) and "packaged" in change["previous"]["source"]
    assert change["saved"]["tau"] == pytest.approx(36.0)
    assert (change["saved"]["same_pairs_accepted"], change["saved"]["different_pairs_accepted"]) == (9, 0)
    assert change["in_force"]["undo"]["tau"] == pytest.approx(75.303, abs=1e-3)
    doc = json.loads((console.data_dir / "calibration" / "stretch.json").read_text())
    assert doc["tau"] == pytest.approx(36.0) and doc["matcher"] == "xfeat_lighterglue" and doc["score"] == "conf"
    assert (
        (doc["same_pairs"], doc["different_pairs"]) == (9, 27) and doc["created"] and "operator photos" in doc["source"]
    )
    after = c.get("/api/calibration").json()
    assert after["stretch"]["tau"] == pytest.approx(36.0) and "your photos" in after["stretch"]["source"]
    assert after["sim"]["file"] is None  # only the chosen deployment changed


@pytest.mark.parametrize(
    "objects, code, fragment",
    [
        ([("mug", 0, 0), ("mug", 0, 1), ("mug", 0, 2)], "too_few_photos", "at least 2 different objects"),
        (
            [("mug", 0, 0), ("mug", 0, 1), ("mug", 0, 2), ("chair", 1, 0), ("chair", 1, 1)],
            "too_few_photos",
            "fewer than 3 photos: chair (2)",
        ),
        # 2 x 3 photos: 6 same-object pairs, an F from a handful of pairs
        (
            [(name, obj, v) for obj, name in enumerate(["mug", "chair"]) for v in range(3)],
            "too_few_pairs",
            "6 same-object and 9 different-object pairs",
        ),
    ],
)
def test_too_few_objects_photos_or_pairs(client, objects, code: str, fragment: str) -> None:
    console, c = client
    files, data = upload(objects)
    resp = c.post("/api/calibration/sim", files=files, data=data)
    assert resp.status_code == 422 and resp.json()["detail"]["code"] == code, resp.text
    assert fragment in resp.json()["detail"]["message"], resp.text
    assert console.calibrator.jobs() == []


def test_duplicate_photos_are_refused_before_scoring(client) -> None:
    """Issue 33: the same file uploaded twice for each object proposed tau 936 at "F 1.0"."""
    console, c = client
    objects = [("mug", 0, 0), ("mug", 0, 1), ("mug", 0, 2), ("chair", 1, 0), ("chair", 1, 1), ("chair", 1, 2)]
    files, data = upload(objects)
    same_file = [*files, ("photos", ("mug-again.jpg", files[0][1][1], "image/jpeg"))]
    resp = c.post("/api/calibration/stretch", files=same_file, data={"objects": [*data["objects"], "mug"]})
    assert resp.status_code == 422 and resp.json()["detail"]["code"] == "duplicate_photos", resp.text
    message = resp.json()["detail"]["message"]
    assert "mug-0.jpg and mug-again.jpg" in message and "the same file" in message, message
    # the same picture re-encoded smaller (another file, the same view), even under another object
    rgb = view_rgb(1, 0)
    small = np.asarray(Image.fromarray(rgb).resize((96, 72), Image.Resampling.LANCZOS))
    near = [*files, ("photos", ("chair-copy.png", encode(small, "PNG"), "image/png"))]
    resp = c.post("/api/calibration/stretch", files=near, data={"objects": [*data["objects"], "mug"]})
    assert resp.status_code == 422 and resp.json()["detail"]["code"] == "duplicate_photos", resp.text
    message = resp.json()["detail"]["message"]
    assert "chair-0.jpg and chair-copy.png" in message and "near-identical" in message, message
    assert "one labelled chair, the other mug" in message
    assert console.calibrator.jobs() == [] and not (console.data_dir / "calibration").exists()


def test_unreadable_photo_names_the_file(client) -> None:
    _, c = client
    files, data = upload([("mug", 0, 0), ("mug", 0, 1), ("chair", 1, 0), ("chair", 1, 1)])
    files[2] = ("photos", ("broken.jpg", b"not a picture at all" * 10, "image/jpeg"))
    resp = c.post("/api/calibration/sim", files=files, data=data)
    assert resp.status_code == 415 and "broken.jpg (chair)" in resp.json()["detail"]["message"], resp.text


def test_labels_must_match_photos_and_deployment_must_exist(client) -> None:
    _, c = client
    files, data = upload([("mug", 0, 0), ("mug", 0, 1), ("chair", 1, 0), ("chair", 1, 1)])
    resp = c.post("/api/calibration/sim", files=files, data={"objects": data["objects"][:3]})
    assert resp.status_code == 422 and resp.json()["detail"]["code"] == "bad_labels"
    assert c.post("/api/calibration/warp", files=files, data=data).status_code == 422
    assert c.post("/api/calibration/sim", data=data).status_code == 422  # no photos
    assert c.get("/api/calibration/jobs/0123456789ab").status_code == 404
    assert c.post("/api/calibration/jobs/0123456789ab/save").status_code == 404
    assert c.get("/api/calibration/jobs/..%2F..").status_code in (404, 422)


def test_calibration_needs_the_token_off_loopback(tmp_path: Path) -> None:
    console = Console(ConsoleConfig(data_dir=tmp_path, viewer=None, host="0.0.0.0", allowed_hosts=("testserver",)), {})
    try:
        with TestClient(create_app(console)) as c:
            files, data = upload([("mug", 0, 0), ("mug", 0, 1), ("chair", 1, 0), ("chair", 1, 1)])
            assert c.post("/api/calibration/sim", files=files, data=data).status_code == 401
            assert c.post("/api/calibration/jobs/0123456789ab/save").status_code == 401
    finally:
        console.close()


def test_saved_file_is_what_the_deployment_reads(client) -> None:
    """The agent side (console.agents.read_deployment_calibration) accepts the saved file."""
    from agent.config import load_agent_config
    from console.agents import read_deployment_calibration

    console, c = client
    files, data = upload([(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(3)])
    job = c.post("/api/calibration/stretch", files=files, data=data).json()
    poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json()["state"], lambda s: s == "done")
    assert c.post(f"/api/calibration/jobs/{job['id']}/save").status_code == 200
    reid = load_agent_config("stretch").reid
    doc = read_deployment_calibration(console.data_dir / "calibration" / "stretch.json", reid.matcher, reid.score)
    assert doc["tau"] > 0


class LoudMatcher(ColourMatcher):
    """Same-object pairs match every one of 1000 keypoints: what one file matched with itself gives."""

    def match(self, goal: Features, obs: Features) -> Matches:
        same = float(np.abs(goal.descriptors - obs.descriptors).mean()) < 30
        n = 1000 if same else 4
        return Matches(np.arange(n), np.arange(n), np.full(n, 0.95 if same else 0.3, np.float32))


def test_a_tau_far_outside_the_matchers_range_is_flagged_and_not_saved(client) -> None:
    console, c = client
    console.calibrator = Calibrator(
        console.data_dir, matcher_for=lambda d: (LoudMatcher(), ReIDConfig(matcher="xfeat_lighterglue"))
    )
    files, data = upload([(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(3)])
    job = c.post("/api/calibration/stretch", files=files, data=data).json()
    done = poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json(), lambda j: j["state"] in ("done", "failed"))
    result = done["result"]
    assert result["proposal"]["tau"] == pytest.approx(950.0) and result["proposal"]["max_f"] == pytest.approx(1.0)
    checks = result["checks"]
    assert not checks["savable"] and [p["code"] for p in checks["problems"]] == ["implausible_tau"]
    assert checks["tau_band"]["low"] == pytest.approx(75.3034 / 8, abs=1e-3)
    assert checks["tau_band"]["high"] == pytest.approx(75.3034 * 4, abs=1e-3)
    assert "far above" in checks["problems"][0]["message"]
    saved = c.post(f"/api/calibration/jobs/{job['id']}/save")
    assert saved.status_code == 409 and saved.json()["detail"]["code"] == "implausible_tau", saved.text
    assert not (console.data_dir / "calibration" / "stretch.json").exists()
    assert c.get("/api/calibration").json()["stretch"]["undo"] is None


def test_saving_can_be_undone(client) -> None:
    console, c = client
    path = console.data_dir / "calibration" / "stretch.json"
    assert c.post("/api/calibration/stretch/undo").status_code == 409  # nothing saved yet

    def calibrate_and_save(views: int) -> dict[str, Any]:
        objs = [(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(views)]
        files, data = upload(objs)
        job = c.post("/api/calibration/stretch", files=files, data=data).json()
        poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json()["state"], lambda s: s == "done")
        saved = c.post(f"/api/calibration/jobs/{job['id']}/save")
        assert saved.status_code == 200, saved.text
        return saved.json()

    first = calibrate_and_save(3)
    second = calibrate_and_save(4)
    assert second["previous"]["tau"] == first["saved"]["tau"] and "your photos" in second["previous"]["source"]
    assert json.loads(path.read_text())["same_pairs"] == 18
    status = c.get("/api/calibration").json()["stretch"]
    assert status["undo"]["tau"] == first["saved"]["tau"] and "your photos" in status["undo"]["source"]
    undone = c.post("/api/calibration/stretch/undo")
    assert undone.status_code == 200, undone.text
    assert undone.json()["undone"]["same_pairs"] == 18
    assert json.loads(path.read_text()) == first["saved"]  # the first save is back in force
    assert "packaged" in undone.json()["in_force"]["undo"]["source"]
    again = c.post("/api/calibration/stretch/undo").json()
    assert not path.exists() and "packaged" in again["in_force"]["source"] and again["in_force"]["undo"] is None
    assert c.post("/api/calibration/stretch/undo").status_code == 409
    assert c.get("/api/calibration").json()["sim"]["undo"] is None  # only the chosen deployment
