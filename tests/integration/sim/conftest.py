from __future__ import annotations

from pathlib import Path

import pytest

from sim.episode_gen import EpisodeGenConfig, generate_episode_set
from tests.helpers.shared import shared_dir


@pytest.fixture(scope="session")
def small_episode_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three val episodes from one generated home (shared by the sim integration tests and by
    the xdist workers; read-only)."""

    def generate(out: Path) -> None:
        generate_episode_set("val", 7, 3, out, EpisodeGenConfig(episodes_per_scene=3), progress=False)

    return shared_dir(tmp_path_factory, "small-episode-set", generate)
