from __future__ import annotations

from pathlib import Path

import pytest

from sim.episode_gen import EpisodeGenConfig, generate_episode_set
from sim.sequence_gen import SequenceGenConfig, generate_sequence_set
from tests.helpers.shared import shared_dir


@pytest.fixture(scope="session")
def small_episode_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three val episodes from one generated home (shared by the sim integration tests and by
    the xdist workers; read-only)."""

    def generate(out: Path) -> None:
        generate_episode_set("val", 7, 3, out, EpisodeGenConfig(episodes_per_scene=3), progress=False)

    return shared_dir(tmp_path_factory, "small-episode-set", generate)


@pytest.fixture(scope="session")
def small_sequence_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two val sequences of three goals from one generated home (multi-goal, issue 31; shared
    and read-only like ``small_episode_set``)."""

    def generate(out: Path) -> None:
        generate_sequence_set("val", 7, 2, out, SequenceGenConfig(goals=3, sequences_per_scene=2), progress=False)

    return shared_dir(tmp_path_factory, "small-sequence-set", generate)
