"""`imgnav eval --realism`: an episode under a noise profile is deterministic, the record keeps
the truth beside the estimate, and a run is never mixed across profiles (the noise itself, its
seed and its components alone: tests/unit/sim/test_sim_realism.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from console.cli import main


def _eval(episodes: Path, out: Path, *more: str) -> dict:
    """One oracle episode under ``more``'s realism options; its record without the timings."""
    assert (
        main(["eval", "--episodes", str(episodes), "--agent", "oracle", "--limit", "1", *more, "--out", str(out)]) == 0
    )
    rec = json.loads((out / "episodes.jsonl").read_text().splitlines()[0])
    rec.pop("timing")
    return rec


def test_an_episode_under_the_stretch_profile_is_deterministic(
    small_episode_set: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    a = _eval(small_episode_set, tmp_path / "a", "--realism", "stretch")
    b = _eval(small_episode_set, tmp_path / "b", "--realism", "stretch")
    assert a == b  # field for field: trajectory, believed poses, metrics
    assert a["realism"]["profile"] == "stretch"
    truth, believed = a["trajectory"]["poses_world"], a["trajectory"]["poses_estimate_world"]
    assert len(truth) == len(believed) == a["steps"] + 1 and truth != believed
    # resuming a run with another profile is refused, and the records stay as they were
    before = (tmp_path / "a" / "episodes.jsonl").read_text()
    args = ["eval", "--episodes", str(small_episode_set), "--agent", "oracle", "--limit", "2"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 2
    assert "another realism profile" in caplog.text
    assert (tmp_path / "a" / "episodes.jsonl").read_text() == before
