"""Distance-aware evidence (sim/evaluation/evidence.py): binning, gated frames as censored scores,
the per-bin max-F threshold and its floor, and train-only records."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from agent.config import load_agent_config
from agent.reid.identifier import resolve_gate_threshold
from sim.evaluation import evidence as evd

TAU = 75.3
GATE = 36.0  # the calibrated gate threshold: a run gated at 36 hides scores < tau, at 18 scores < tau/2


def record(episode_id: str, scores, gates, px, dist, variant: str = "reid=conf, loc=mask", **extra) -> str:
    return json.dumps(
        {
            "episode_id": episode_id,
            "scene_seed": 3,
            "variant": variant,
            **extra,
            "modiin": {"trace": {"reid_score": scores, "gate_score": gates, "goal_px": px, "goal_dist_m": dist}},
        }
    )


def frames(tmp_path: Path, lines: list[str], gate: float | None = GATE) -> evd.Evidence:
    p = tmp_path / "episodes.jsonl"
    p.write_text("\n".join(lines) + "\n")
    return evd.frames_evidence([p], TAU, GATE, [gate])


def synthetic(score, positive, censored=None, bound=0.0, dist=None) -> evd.Evidence:
    n = len(score)
    positive = np.asarray(positive, bool)
    return evd.Evidence(
        score=np.asarray(score, float),
        censored=np.zeros(n, bool) if censored is None else np.asarray(censored),
        gate_bound=np.full(n, bound),
        share=np.where(positive, 0.05, 0.0),
        dist_m=np.full(n, 1.5) if dist is None else np.asarray(dist, float),
        positive=positive,
        glimpse=np.zeros(n, bool),
        negative=~positive,
        weight=np.ones(n),
        unit=np.array(["e"] * n, object),
    )


def test_bins_are_left_closed_and_drop_nan() -> None:
    d = evd.DIST_BINS.index(np.array([0.0, 0.99, 1.0, 4.99, 5.0, 40.0, math.nan, -0.1]))
    assert d.tolist() == [0, 0, 1, 3, 4, 4, -1, -1]
    px = np.array([100, 2299, 2300, 0.03 * evd.FRAME_PX, 0.3 * evd.FRAME_PX, evd.FRAME_PX])
    assert evd.SIZE_BINS.index(px / evd.FRAME_PX).tolist() == [0, 0, 1, 2, 4, 4]


def test_a_gated_zero_is_censored_below_the_runs_gate_bound(tmp_path: Path) -> None:
    ev = frames(
        tmp_path,
        [
            record(
                "train-s0-0000-0",
                [0.0, 0.0, 0.0, 0.12, None, 50.0],
                [10.0, 40.0, None, 24.0, 3.0, 90.0],
                [3000, 0, 0, 0, 0, 5000],
                [1.0, 2.0, 3.0, 4.0, 5.0, 0.5],
            )
        ],
    )
    # gate 10 < 36 and score 0: hidden; gate 40 or no gate score: a measured 0; 0.12: the matcher ran
    assert ev.censored.tolist() == [True, False, False, False, False]
    assert np.allclose(ev.gate_bound, TAU) and ev.positive.tolist() == [True, False, False, False, True]
    pos = ev.select(ev.positive)
    # >= tau: the hidden frame is below tau (gate bound = tau), the measured 50 too
    assert evd.share_at_least(pos, TAU) == (0.0, 0.0)
    # >= tau/2: 50 is above; the hidden frame may or may not be
    assert evd.share_at_least(pos, 0.5 * TAU) == (0.5, 1.0)
    assert evd.quantile(pos, 0.0) == (0.0, 50.0)
    # the same frames from a run gated at 18: hidden frames are below tau/2, so the share is exact
    low = frames(tmp_path, [record("train-s0-0000-0", [0.0, 50.0], [10.0, 90.0], [3000, 5000], [1.0, 0.5])], gate=18.0)
    assert low.censored.tolist() == [True, False]
    assert evd.share_at_least(low, 0.5 * TAU) == (0.5, 0.5)
    # gate off: a 0 is a measured 0
    off = frames(tmp_path, [record("train-s0-0000-0", [0.0], [10.0], [3000], [1.0])], gate=None)
    assert off.censored.tolist() == [False] and evd.share_at_least(off, 1.0) == (0.0, 0.0)


def test_gate_threshold_is_rebuilt_from_the_runs_variant() -> None:
    base = resolve_gate_threshold(load_agent_config("sim").reid)
    assert evd.gate_threshold_of({"variant": "reid=conf, loc=mask"}) == base
    half = {"variant": "reid=conf, loc=mask, policy.stop_radius_m=0.6, policy.potential_tau_ratio=0.5"}
    assert evd.gate_threshold_of(half) == pytest.approx(0.5 * base)
    assert evd.gate_threshold_of({"variant": "reid=conf, loc=mask, reid.gate=false"}) is None
    # records that carry their resolved config are read from it, whatever the variant says
    from dataclasses import replace

    from agent.configio import to_dict

    cfg = load_agent_config("sim")
    carried = {
        "variant": "reid=conf, loc=mask",
        "agent_config": to_dict(replace(cfg, policy=replace(cfg.policy, potential_tau_ratio=0.25))),
    }
    assert evd.gate_threshold_of(carried) == pytest.approx(0.25 * base)


def test_max_f_threshold_per_bin() -> None:
    # 20 positives at 80; negatives: 30 at 10 and 5 at 90 -> threshold 80: P 0.8, R 1, F 0.889
    ev = synthetic([80.0] * 20 + [10.0] * 30 + [90.0] * 5, [True] * 20 + [False] * 35)
    m = evd.max_f_threshold(ev, ev.positive, ev.negative, TAU)
    assert m is not None and m.threshold == 80.0 and m.f == pytest.approx(2 * 0.8 / 1.8)
    assert not m.at_floor and m.f_at_tau == pytest.approx(m.f)
    few = ev.select(np.r_[np.arange(1, 20), np.arange(20, 55)])
    assert evd.max_f_threshold(few, few.positive, few.negative, TAU) is None  # 19 positives: too few


def test_max_f_threshold_is_searched_above_the_gate_bound_only() -> None:
    # positives 10 at 40 and 10 at 100; negatives 30 measured at 10 and 10 hidden by a gate bound of tau
    score = [40.0] * 10 + [100.0] * 10 + [10.0] * 30 + [0.0] * 10
    pos = [True] * 20 + [False] * 40
    free = evd.max_f_threshold(synthetic(score, pos), np.array(pos), ~np.array(pos), TAU)
    assert free is not None and free.threshold == 40.0 and free.f == pytest.approx(1.0)
    ev = synthetic(score, pos, censored=[False] * 50 + [True] * 10, bound=TAU)
    m = evd.max_f_threshold(ev, ev.positive, ev.negative, TAU)
    # 40 would count hidden negatives that may score above it: only 100 is searched, flagged as the floor
    assert m is not None and m.threshold == 100.0 and m.floor == TAU and m.at_floor
    assert m.f == pytest.approx(2 * 0.5 / 1.5)


def test_bin_rows_size_uses_glimpses_and_all_negatives(tmp_path: Path) -> None:
    px = [500] * 3 + [10000] * 2 + [0] * 4
    dist = [4.0] * 3 + [1.5] * 2 + [1.5, 1.5, 4.0, 6.0]
    ev = frames(
        tmp_path,
        [
            record(
                "train-s0-0000-0",
                [1.0] * 3 + [90.0] * 2 + [0.0, 80.0, 0.0, 0.0],
                [50.0] * 5 + [10.0, 80.0, 50.0, 50.0],
                px,
                dist,
            )
        ],
    )
    size = evd.bin_rows(ev, evd.SIZE_BINS, TAU, negatives_in_bin=False, min_positives=1)
    assert [r.positives for r in size] == [3, 0, 2, 0, 0] and all(r.negatives == 4 for r in size)
    assert size[2].pos_at_tau == (1.0, 1.0) and size[2].neg_at_tau == (0.25, 0.25)
    by_dist = evd.bin_rows(ev, evd.DIST_BINS, TAU, negatives_in_bin=True, min_positives=1)
    assert [r.positives for r in by_dist] == [0, 2, 0, 0, 0]  # glimpses are not "in view"
    assert [r.negatives for r in by_dist] == [0, 2, 0, 1, 1]
    # one of the two is hidden by a gate bound of tau: known below tau, unknown at tau/2
    assert by_dist[1].neg_at_tau == (0.5, 0.5) and by_dist[1].neg_at_half_tau == (0.5, 1.0)


def test_val_and_test_records_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "episodes.jsonl"
    p.write_text(record("val-s0-0000-0", [1.0], [3.0], [0], [1.0]) + "\n")
    with pytest.raises(ValueError, match="val split"):
        evd.frames_evidence([p], TAU, GATE, [GATE])
    # a train-looking id in a test home is still refused
    p.write_text(json.dumps({"episode_id": "train-s0-0000-0", "scene_seed": 200_000_001}) + "\n")
    with pytest.raises(ValueError, match="test split"):
        evd.read_train_records(p)


def test_cli_writes_tables_marks_thin_bins_and_plots(tmp_path: Path) -> None:
    lines = [
        record(
            f"train-s0-0000-{k}",
            [90.0, 60.0, 0.0, 5.0] * 6,
            [80.0, 60.0, 10.0, 40.0] * 6,
            [30000, 4000, 0, 0] * 6,
            [0.8, 2.5, 2.5, 2.5] * 6,
        )
        for k in range(2)
    ]
    rec = tmp_path / "episodes.jsonl"
    rec.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert evd.main(["--records", str(rec), "--gate-thresholds", "36", "--out", str(out)]) == 0
    md = (out / "evidence.md").read_text()
    assert "too few samples" in md and "| 10-30% | 12 (2) |" in md and (out / "evidence.png").stat().st_size > 0
    data = json.loads((out / "evidence.json").read_text())
    assert data["frames"] == {"episodes": 2, "frames": 48, "censored": 12}


def test_conclusion_names_the_peak_and_the_bins_below_tau() -> None:
    from sim.evaluation.evidence_report import conclusion

    scores = [[10.0] * 20, [120.0] * 20, [40.0] * 20]  # small views weak, mid strong, close views weaker again
    rows = [
        evd.BinRow(label, 20, 5, 0, ((s[0], s[0]),) * 3, (0.0, 0.0), (0.0, 0.0), 0, (0.0, 0.0), (0.0, 0.0), None)
        for label, s in zip(("a", "b", "c"), scores)
    ]
    text = " ".join(conclusion("X", rows, TAU, 20, False))
    assert "peaks at b" in text and "median below tau in a, c" in text and "(b 120 -> c 40)" in text


def test_records_without_distances_leave_the_distance_bins_empty(tmp_path: Path) -> None:
    p = tmp_path / "episodes.jsonl"
    p.write_text(
        json.dumps(
            {
                "episode_id": "train-s0-0000-0",
                "variant": "reid=conf, loc=mask",
                "modiin": {"trace": {"reid_score": [90.0, 1.0], "gate_score": [80.0, 50.0], "goal_px": [5000, 0]}},
            }
        )
        + "\n"
    )
    ev = evd.frames_evidence([p], TAU, GATE, [GATE])
    assert np.isnan(ev.dist_m).all()
    assert all(r.positives == 0 and r.negatives == 0 for r in evd.bin_rows(ev, evd.DIST_BINS, TAU, True))


def test_a_pair_is_binned_by_its_harder_image() -> None:
    ps = evd.PairSample(
        pairs=np.array([[0, 1], [0, 2]]),
        label=np.array([True, False]),
        weight=np.array([1.0, 8.0]),
        conf=np.array([120.0, 3.0]),
        share=np.array([0.25, 0.08, 0.4]),
        dist_m=np.array([1.2, 0.7, 2.5]),
        instance=np.array(["h_1", "h_1", "h_2"]),
    )
    ev = ps.evidence()
    assert ev.share.tolist() == [0.08, 0.25] and ev.dist_m.tolist() == [1.2, 2.5]
    assert ev.positive.tolist() == [True, False] and ev.negative.tolist() == [False, True]
    assert ev.weight.tolist() == [1.0, 8.0] and not ev.censored.any()
