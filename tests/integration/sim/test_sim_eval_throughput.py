"""Evaluation throughput (issue 32) with the oracle: episodes longest first, one home split
across two workers, the same records with one worker or two, throughput in summary.json."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from sim.episodes import load_episode_set
from sim.evaluation.compare import identical
from sim.evaluation.runner import read_records, run_evaluation


def _plausible(t: dict, episodes: int, workers: int) -> None:
    assert t["covers"] == "this_invocation" and t["episodes"] == episodes and t["workers"] == workers
    assert t["cpu_s"] > 0 and t["cpu_s_source"] == "processes" and t["episode_cpu_s"] > 0
    assert 0 < t["busy_share"] <= 1
    assert t["episodes_per_cpu_hour"] > 0 and t["episodes_per_wall_hour"] > 0
    assert t["episodes_per_core_hour"] == pytest.approx(3600 * episodes / (workers * t["wall_s"]), rel=1e-3)
    assert t["episode_wall_s"] <= workers * t["wall_s"]
    assert t["worker_start_s"] >= 0 and t["tail_idle_s"] >= 0 and t["scene_build_s"] > 0


def test_one_home_on_two_workers_gives_the_records_of_one_worker(small_episode_set: Path, tmp_path: Path) -> None:
    es = load_episode_set(small_episode_set)
    assert len(es) == 3 and len({e.scene_seed for e in es.episodes}) == 1
    args = argparse.Namespace()

    # one worker: the home built once, its episodes longest first
    one = tmp_path / "one"
    summary = run_evaluation(small_episode_set, "oracle", args, one, workers=1, progress=False)
    recs = read_records(one)
    paths = [r["shortest_path_m"] for r in recs]
    assert paths == sorted(paths, reverse=True)
    assert all(r["timing"]["cpu_s"] > 0 and r["timing"]["scene_build_cpu_s"] > 0 for r in recs)
    t = summary["throughput"]
    _plausible(t, 3, 1)
    assert t["scene_builds"] == 1 and t["tail_idle_s"] == 0.0
    assert summary["timing"]["cpu_s_per_episode"] > 0

    # two workers, resumed after one episode: the two left run at once, each worker building the
    # home (the old runner ran a one-home set on one worker)
    two = tmp_path / "two"
    run_evaluation(
        small_episode_set, "oracle", args, two, workers=2, progress=False, episode_ids=[es.episodes[1].episode_id]
    )
    summary = run_evaluation(small_episode_set, "oracle", args, two, workers=2, progress=False)
    t = summary["throughput"]
    _plausible(t, 2, 2)  # the figures cover the episodes of this invocation
    assert t["scene_builds"] == 2
    assert summary["episodes"] == 3 and summary["sr"] == 1.0

    # the same records apart from timings and their order in the file; the same summary
    n, differences = identical(str(one), str(two))
    assert n == 3 and differences == []
    first = json.loads((one / "summary.json").read_text())
    for key in ("sr", "spl", "ne", "max_st", "episodes", "per_category", "errors"):
        assert summary[key] == first[key], key

    # nothing left to run: the figures of the invocation that ran episodes are kept
    again = run_evaluation(small_episode_set, "oracle", args, two, workers=2, progress=False)
    assert again["throughput"] == {**t, "kept_from_earlier_invocation": True}
