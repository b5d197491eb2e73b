"""``imgnav calibrate --realism`` (sim/evaluation/calibration_realism.py, issue 30): each image is
processed the same way in every run, the goal's and the frame's roles differ, the clean profile
scores the pairs exactly as the plain calibration does, and a profile changes the images, never
the pairs or their weights. A recording stand-in for the matcher keeps it fast (no weights)."""

from __future__ import annotations

import argparse
import json
import zlib
from pathlib import Path

import numpy as np
import pytest

from agent.reid.base import Features, Matches
from sim.episodes import write_rgb
from sim.evaluation import calibrate
from sim.evaluation.calibration_core import make_pairs, operating_point, pr_curves, score_pairs
from sim.evaluation.calibration_realism import (
    frame_version,
    goal_version,
    role_features,
    score_calibration_pairs,
)
from sim.realism import PROFILES, Realism, get_profile

STRETCH = Realism(PROFILES["stretch"])
N_INST, PER_INST = 3, 3


class RecordingMatcher:
    """Features are the image itself; a match's score is a fixed function of both images' bytes."""

    name = "recording"

    def __init__(self) -> None:
        self.extracted: list[tuple[np.ndarray, int]] = []
        self.matched: list[tuple[np.ndarray, np.ndarray]] = []

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        self.extracted.append((rgb, max_keypoints))
        h, w = rgb.shape[:2]
        return Features(np.zeros((0, 2), np.float32), np.array(rgb, copy=True), (w, h), {"k": max_keypoints})

    def match(self, goal: Features, obs: Features) -> Matches:
        self.matched.append((goal.descriptors, obs.descriptors))
        n = 1 + (zlib.crc32(goal.descriptors.tobytes()) ^ zlib.crc32(obs.descriptors.tobytes())) % 9
        conf = np.full(n, float(goal.descriptors.mean()) / 255.0, np.float32)
        return Matches(np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64), conf)


def _images() -> tuple[list[np.ndarray], list[str], list[str]]:
    rng = np.random.default_rng(3)
    images = [(rng.random((48, 64, 3)) * 200 + 20).astype(np.uint8) for _ in range(N_INST * PER_INST)]
    names = [f"7_{i // PER_INST}_{i % PER_INST:02d}.png" for i in range(len(images))]
    instances = [f"7_{i // PER_INST}" for i in range(len(images))]
    return images, names, instances


# --- the processing ------------------------------------------------------------------------


def test_each_image_is_processed_the_same_in_every_run_and_by_its_own_name() -> None:
    img = _images()[0][0]
    for version in (goal_version, frame_version):
        a = version(img, STRETCH, "1_2_00.png")
        assert np.array_equal(a, version(img.copy(), Realism(PROFILES["stretch"]), "1_2_00.png"))
        assert not np.array_equal(a, version(img, STRETCH, "1_2_01.png"))  # same pixels, another image
        assert not np.array_equal(a, version(img, Realism(PROFILES["stretch"], seed=1), "1_2_00.png"))
    assert np.array_equal(img, _images()[0][0])  # the input is left as it was


def test_the_goal_is_a_phone_photo_and_the_frame_the_bridges_colour() -> None:
    img = _images()[0][0]
    goal = goal_version(img, STRETCH, "a.png")
    frame = frame_version(img, STRETCH, "a.png")
    # the phone photo is a 4:3 crop (portrait or landscape) of the view; the frame keeps its geometry
    assert goal.shape in {(48, 36, 3), (48, 64, 3)} and frame.shape == img.shape
    assert frame.dtype == np.uint8 and not np.array_equal(frame, img)
    assert not np.array_equal(goal, frame[: goal.shape[0], : goal.shape[1]])
    # each role only from its own component
    only_photo = Realism(get_profile("stretch", ["goal_photo"]))
    only_rgb = Realism(get_profile("stretch", ["rgb"]))
    assert np.array_equal(goal_version(img, only_photo, "a.png"), goal)
    assert frame_version(img, only_photo, "a.png") is img
    assert goal_version(img, only_rgb, "a.png") is img
    assert np.array_equal(frame_version(img, only_rgb, "a.png"), frame)
    for clean in (None, Realism(PROFILES["clean"]), Realism(get_profile("stretch", ["depth", "pose"]))):
        assert goal_version(img, clean, "a.png") is img and frame_version(img, clean, "a.png") is img


# --- the scoring ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "realism", [None, Realism(PROFILES["clean"]), Realism(get_profile("stretch", ["depth", "actuation"]))]
)
def test_without_colour_the_pairs_are_scored_as_the_plain_calibration_scores_them(realism: Realism | None) -> None:
    images, names, instances = _images()
    pairs = make_pairs(instances, max_negatives=0).pairs
    today = RecordingMatcher()
    want = score_pairs(today, [today.extract(im, 11) for im in images], pairs)
    m = RecordingMatcher()
    goal, frame = role_features(m, images, names, realism, 11, 5)
    got = score_calibration_pairs(m, goal, frame, pairs)
    assert frame is None and [k for _, k in m.extracted] == [11] * len(images)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_under_the_profile_a_pair_is_the_goal_photo_of_one_against_the_frame_of_the_other() -> None:
    images, names, instances = _images()
    pairs = make_pairs(instances, max_negatives=10, seed=2).pairs
    m = RecordingMatcher()
    goal, frame = role_features(m, images, names, STRETCH, 11, 5)
    assert frame is not None
    # one extraction per processed version, with the agent's keypoint budget for the role
    assert [k for _, k in m.extracted] == [11, 5] * len(images)
    conf, _ = score_calibration_pairs(m, goal, frame, pairs)
    assert len(m.matched) == len(pairs)
    for (a, b), (g, f) in zip(pairs, m.matched, strict=True):
        assert np.array_equal(g, goal_version(images[a], STRETCH, names[a]))
        assert np.array_equal(f, frame_version(images[b], STRETCH, names[b]))
    clean = RecordingMatcher()
    plain, _ = score_pairs(clean, [clean.extract(im, 11) for im in images], pairs)
    assert not np.array_equal(conf, plain)


def test_the_figures_at_a_given_tau_are_the_curves_at_that_threshold() -> None:
    scores = np.array([9, 8, 7, 6, 5, 4, 3, 2], float)
    label = np.array([1, 1, 0, 1, 0, 0, 1, 0], bool)
    weight = np.array([1, 1, 3, 1, 3, 3, 1, 3], float)
    c = pr_curves(scores, label, weight)
    for k, tau in enumerate(c.threshold):
        p = operating_point(scores, label, weight, float(tau))
        assert (p.precision, p.recall, p.f) == pytest.approx((c.precision[k], c.recall[k], c.f[k]))
    # between thresholds: the next one up; above all: nothing detected
    assert operating_point(scores, label, weight, 6.5).recall == pytest.approx(c.recall[2])
    above = operating_point(scores, label, weight, 10.0)
    assert (above.precision, above.recall, above.f) == (0.0, 0.0, 0.0)


# --- imgnav calibrate --realism --------------------------------------------------------------


@pytest.fixture
def agent_calibration(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The agent's calibration files, in a temporary directory (the packaged ones are never touched)."""
    import agent.reid.identifier as identifier

    d = tmp_path / "agent_calibration"
    d.mkdir()
    for kind, tau in (("conf", 2.5), ("count", 4.0)):
        (d / f"xfeat_lighterglue_{kind}.json").write_text(
            json.dumps({"matcher": "xfeat_lighterglue", "score": kind, "tau": tau})
        )
    monkeypatch.setattr(identifier, "calibration_path", lambda matcher, kind: d / f"{matcher}_{kind}.json")
    monkeypatch.setattr(identifier, "make_matcher", lambda cfg: RecordingMatcher())
    return d


def _args(out: Path, argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    calibrate.add_arguments(parser)
    return parser.parse_args(["--out", str(out), "--threads", "1", "--max-negatives", "12", *argv])


def test_calibrate_under_the_profile_keeps_the_pairs_names_its_outputs_and_leaves_the_agent_alone(
    tmp_path: Path, agent_calibration: Path
) -> None:
    images, names, instances = _images()
    cache, out = tmp_path / "images", tmp_path / "out"
    cache.mkdir()
    out.mkdir()
    entries = []
    for im, name, inst in zip(images, names, instances, strict=True):
        write_rgb(cache / name, im)
        entries.append({"path": name, "instance": inst, "category": "chair"})
    before = {p.name: p.read_bytes() for p in agent_calibration.iterdir()}

    stretch = calibrate.calibrate_matcher(
        "xfeat_lighterglue", entries, cache, out, _args(out, ["--realism", "stretch"])
    )
    assert {p.name: p.read_bytes() for p in agent_calibration.iterdir()} == before  # not written
    for kind, tau in (("conf", 2.5), ("count", 4.0)):
        res = json.loads((out / f"xfeat_lighterglue_stretch_{kind}.json").read_text())
        assert res == stretch[kind] and res["realism"]["profile"] == "stretch" and res["agent_tau"] == tau
    assert (out / "xfeat_lighterglue_stretch_pr.png").is_file()

    clean = calibrate.calibrate_matcher("xfeat_lighterglue", entries, cache, out, _args(out, []))
    assert "realism" not in clean["conf"] and "agent_tau" not in clean["conf"]
    assert json.loads((agent_calibration / "xfeat_lighterglue_conf.json").read_text()) == clean["conf"]  # written

    a = np.load(out / "xfeat_lighterglue_scores.npz")
    b = np.load(out / "xfeat_lighterglue_stretch_scores.npz")
    for key in ("pairs", "label", "weight", "same_category"):
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(a["conf"], b["conf"])
    assert stretch["conf"]["same_pairs"] == clean["conf"]["same_pairs"] == N_INST * 3
    assert stretch["conf"]["negative_weight"] == clean["conf"]["negative_weight"]


def test_calibrate_writes_the_agent_under_a_profile_only_when_asked(tmp_path: Path) -> None:
    stretch = Realism(PROFILES["stretch"])
    assert calibrate.writes_agent(_args(tmp_path, []), None)
    assert not calibrate.writes_agent(_args(tmp_path, ["--no-write-agent"]), None)
    assert not calibrate.writes_agent(_args(tmp_path, ["--realism", "stretch"]), stretch)
    assert calibrate.writes_agent(_args(tmp_path, ["--realism", "stretch", "--write-agent"]), stretch)
    with pytest.raises(SystemExit):
        _args(tmp_path, ["--write-agent", "--no-write-agent"])
    assert calibrate.profile_tag(Realism(get_profile("stretch", ["goal_photo", "rgb"]))) == "stretch-rgb+goal_photo"
    # the gate and Ray paths do not take a profile: refused before any image is made
    for extra in (["--gate"], ["--ray", "local"]):
        assert calibrate.run(_args(tmp_path / "out", ["--realism", "stretch", *extra])) == 2
    assert not (tmp_path / "out" / "images").exists()
