from __future__ import annotations

from pathlib import Path

import pytest

from sim.episode_gen import EpisodeGenConfig, generate_episode_set


@pytest.fixture(scope="session")
def small_episode_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three val episodes from one generated home (shared by the sim integration tests)."""
    out = tmp_path_factory.mktemp("episodes") / "val"
    generate_episode_set("val", 7, 3, out, EpisodeGenConfig(episodes_per_scene=3), progress=False)
    return out
