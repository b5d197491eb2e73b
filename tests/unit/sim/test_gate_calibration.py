"""`imgnav calibrate --gate` (sim/evaluation/gate_calibration.py): recorded frames are read from
train records only, and the threshold it writes beside tau is the one the agent then uses."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import skimage.data

from agent.reid import ReIDConfig, ReIdentifier
from sim.episodes import write_rgb
from sim.evaluation import gate_calibration as gc


def record(episode_id: str, full, gate) -> str:
    return json.dumps({"episode_id": episode_id, "modiin": {"trace": {"reid_score": full, "gate_score": gate}}})


def test_frames_come_from_train_records_only(tmp_path: Path) -> None:
    p = tmp_path / "episodes.jsonl"
    p.write_text(
        record("train-s0-0000-0", [1.0, 80.0, None], [3.0, 90.0, 4.0])
        + "\n"
        + record("train-s0-0000-1", [2.0], [None])
        + "\n"
    )  # gate not recorded: skipped
    full, gate, episodes = gc.frames_from_records([str(p)])
    assert full.tolist() == [1.0, 80.0] and gate.tolist() == [3.0, 90.0] and episodes == 1
    p.write_text(record("val-s0-0000-0", [1.0], [3.0]) + "\n")
    with pytest.raises(ValueError, match="val split"):
        gc.frames_from_records([str(p)])


@pytest.mark.slow
def test_calibrate_gate_writes_the_threshold_the_agent_reads(tmp_path: Path, monkeypatch) -> None:
    # two "instances", three views each: crops of two natural images (XFeat finds plenty in both)
    cache = tmp_path / "images"
    cache.mkdir()
    entries = []
    for name, img in (("astro", skimage.data.astronaut()), ("coffee", skimage.data.coffee())):
        for k, (x0, y0) in enumerate(((0, 0), (40, 30), (80, 10))):
            view = cv2.resize(img[y0 : y0 + 300, x0 : x0 + 300], (160, 160))
            write_rgb(cache / f"{name}_{k}.png", view)
            entries.append({"path": f"{name}_{k}.png", "instance": name, "category": "tv"})
    cal = tmp_path / "xfeat_lighterglue_{kind}.json"
    for kind, tau in (("conf", 20.0), ("count", 10.0)):
        Path(str(cal).format(kind=kind)).write_text(
            json.dumps({"matcher": "xfeat_lighterglue", "score": kind, "tau": tau})
        )
    monkeypatch.setattr(
        "agent.reid.identifier.calibration_path",
        lambda matcher, kind, early_stop=-1.0: Path(str(cal).format(kind=kind)),
    )
    records = tmp_path / "episodes.jsonl"
    # recorded frames: the gate score is about 1.5 x the full score near and above tau
    full = np.array([0.0, 1.0, 3.0, 6.0, 8.0, 20.0])
    records.write_text(record("train-s0-0000-0", full.tolist(), (1.5 * full + 1).tolist()) + "\n")
    out = tmp_path / "out"
    out.mkdir()
    args = argparse.Namespace(
        matcher=["xfeat_lighterglue"],
        config="sim",
        threads=1,
        gate_negatives=100,
        seed=0,
        gate_records=[str(records)],
        gate_max_drop=0.01,
        no_write_agent=False,
    )
    result = gc.calibrate_gate(entries, cache, out, args)["xfeat_lighterglue"]["conf"]
    written = json.loads(Path(str(cal).format(kind="conf")).read_text())
    assert written["tau"] == 20.0 and written["gate_threshold"] == result["threshold"]
    assert set(written["gate_sources"]) == {"goal-image pairs", "train-episode frames"}
    # the recorded frames' bound: the lowest gate/full ratio among frames >= tau/2 (31/20 at full 20), x tau
    frames = written["gate_sources"]["train-episode frames"]
    assert frames["bound"] == np.floor(31.0 / 20.0 * 20.0) == 31 and frames["positives"] == 1
    assert frames["direct"] == 31.0  # the lowest positive's gate score (1 positive: no drop allowed)
    assert result["threshold"] <= frames["bound"] and (out / "xfeat_lighterglue_conf_gate.png").stat().st_size > 0
    # the exit stage: a threshold on LighterGlue's score after layer 2, from the pairs (the score
    # records carry no exit scores), that keeps every positive pair here (the 6 same-image pairs:
    # too few to drop one) and is above 0 (their first two layers already match much of each other)
    assert written["gate_exit_layer"] == 2 and written["gate_exit_threshold"] == result["exit_threshold"]
    assert written["gate_exit_keypoints"] == ReIDConfig().gate_exit_keypoints == 384  # the setting it holds for
    pairs = written["gate_exit_sources"]["goal-image pairs"]
    assert set(written["gate_exit_sources"]) == {"goal-image pairs"} and pairs["dropped_share_at_threshold"] == 0.0
    assert 0 < result["exit_threshold"] <= pairs["direct"] and (out / "xfeat_lighterglue_conf_gate_exit.png").is_file()
    # what the agent then uses
    reid = ReIdentifier(ReIDConfig(gate=True, calibration_file=str(cal).format(kind="conf"), num_threads=1))
    assert reid.gate_threshold == result["threshold"] and reid.exit_threshold == result["exit_threshold"]
    # a second run reuses the scored pairs
    again = gc.calibrate_gate(entries, cache, out, args)["xfeat_lighterglue"]["conf"]
    assert again["threshold"] == result["threshold"]


def test_gate_report_counts_what_each_stage_would_drop(tmp_path: Path) -> None:
    from sim.evaluation.gate_report import report, shadow_frames

    run = tmp_path / "run"
    run.mkdir()
    trace = {
        "reid_score": [100.0, 80.0, 40.0, 5.0, None],
        "gate_score": [50.0, 15.0, 30.0, 2.0, 9.0],
        "exit_score": [20.0, 9.0, 2.0, 0.5, 1.0],
    }
    (run / "episodes.jsonl").write_text(
        json.dumps({"episode_id": "train-s0-0000-0", "modiin": {"trace": trace}}) + "\n"
    )
    full, gate, exit_, episodes = shadow_frames(str(run))
    assert full.tolist() == [100.0, 80.0, 40.0, 5.0] and episodes == 1  # the frame without a score is left out
    lines = report(full, gate, exit_, tau=75.0, gate_thr=20.0, exit_thr=6.0, ratio=0.5)
    # >= tau: 100 (passes both) and 80 (first stage 15 < 20): one dropped
    assert "frames >= tau: 2; dropped by the first stage 1, by the exit stage 0, by either 1 (50.0%)" in lines[1]
    # >= tau/2 with the halved thresholds (10, 3): 40 has exit 2 < 3, 80 passes (15 >= 10, 9 >= 3)
    assert "frames >= 0.5 tau: 3; dropped by the first stage 0, by the exit stage 1, by either 1 (33.3%)" in lines[2]
    assert "every layer would run on 50.0% of the frames (first stage alone: 75.0%)" in lines[3]
