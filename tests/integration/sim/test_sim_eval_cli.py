"""`imgnav eval` with the oracle: records, summary, resume."""

from __future__ import annotations

import json
from pathlib import Path

from console.cli import main


def oracle_eval(episodes: Path, out: Path, *more: str) -> int:
    """``imgnav eval`` with the oracle agent on ``episodes`` into ``out``; its exit code."""
    return main(["eval", "--episodes", str(episodes), "--agent", "oracle", *more, "--out", str(out)])


def test_eval_writes_records_and_resumes(small_episode_set: Path, tmp_path: Path) -> None:
    """One episode, then a resume that keeps it, drops a torn line and runs the second: each
    part of resuming is met once (more episodes would only repeat them)."""
    out = tmp_path / "eval"
    assert oracle_eval(small_episode_set, out, "--limit", "1") == 0
    lines = (out / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 1
    rec = json.loads(lines[0])
    for key in (
        "episode_id",
        "category",
        "success",
        "spl",
        "ne",
        "steps",
        "path_length_m",
        "trajectory",
        "stop_reason",
        "timing",
    ):
        assert key in rec
    assert rec["success"] and rec["stop_reason"] == "stop"
    assert len(rec["trajectory"]["poses_world"]) == rec["steps"] + 1 == len(rec["trajectory"]["actions"]) + 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 1 and summary["sr"] == 1.0 and summary["spl"] >= 0.8
    assert {"sr", "spl", "ne", "max_st", "episodes", "per_category"} <= set(summary)

    # a torn last line (crash mid-write) is dropped; finished episodes are skipped; the rest runs
    with (out / "episodes.jsonl").open("a") as fh:
        fh.write('{"episode_id": "half')
    assert oracle_eval(small_episode_set, out, "--limit", "2") == 0
    lines = (out / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 2 and lines[0] == json.dumps(rec)  # the finished one is kept as it was
    ids = [json.loads(x)["episode_id"] for x in lines]
    assert len(set(ids)) == 2
    assert json.loads((out / "summary.json").read_text())["episodes"] == 2
    # nothing left to do: a rerun adds nothing
    assert oracle_eval(small_episode_set, out, "--limit", "2") == 0
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 2


def test_show_draws_a_map_with_the_path_and_a_goal_sheet(small_episode_set: Path, tmp_path: Path) -> None:
    from sim.episodes import load_episode_set, read_rgb

    out = tmp_path / "eval"
    assert oracle_eval(small_episode_set, out, "--limit", "1") == 0
    episode = load_episode_set(small_episode_set).episodes[0]
    pics = tmp_path / "show"
    assert (
        main(
            [
                "show",
                "--episodes",
                str(small_episode_set),
                "--episode",
                episode.episode_id,
                "--eval",
                str(out),
                "--out",
                str(pics),
            ]
        )
        == 0
    )
    assert main(["show", "--episodes", str(small_episode_set), "--out", str(pics)]) == 0
    assert main(["show", "--scene", str(episode.scene_seed), "--out", str(pics)]) == 0
    for name in (
        f"map-{episode.episode_id}.png",
        f"goal-{episode.episode_id}.png",
        "goals.png",
        f"map-{episode.scene_seed}.png",
    ):
        img = read_rgb(pics / name)
        assert img.ndim == 3 and img.shape[0] > 100 and img.std() > 10, name
    assert main(["show", "--out", str(pics)]) == 2  # nothing to draw


def test_eval_runs_only_the_named_episodes(small_episode_set: Path, tmp_path: Path) -> None:
    from sim.episodes import load_episode_set

    ids = [e.episode_id for e in load_episode_set(small_episode_set).episodes]
    assert len(ids) >= 3
    out = tmp_path / "some"
    listed = tmp_path / "ids.txt"
    listed.write_text(f"# re-run these\n{ids[2]}\n")
    assert oracle_eval(small_episode_set, out, "--episode-ids", ids[0], f"@{listed}") == 0
    got = [json.loads(x)["episode_id"] for x in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted(got) == sorted([ids[0], ids[2]])
    assert json.loads((out / "summary.json").read_text())["episodes"] == 2
    # an id the set does not hold is a clear error, and nothing is run
    bad = tmp_path / "bad"
    assert oracle_eval(small_episode_set, bad, "--episode-ids", "val-s9-9999-9") == 2
    assert not (bad / "episodes.jsonl").exists() or not (bad / "episodes.jsonl").read_text().strip()
