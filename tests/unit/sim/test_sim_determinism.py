"""Same seed, byte-identical episode JSON and identical goal images."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.episode_gen import EpisodeGenConfig, generate_episode_set
from sim.episodes import load_episode_set


@pytest.mark.slow
def test_same_seed_gives_identical_episode_sets(tmp_path: Path) -> None:
    cfg = EpisodeGenConfig(episodes_per_scene=2)
    a, b = tmp_path / "a", tmp_path / "b"
    generate_episode_set("val", 3, 2, a, cfg, progress=False)
    generate_episode_set("val", 3, 2, b, cfg, progress=False)
    assert (a / "episodes.json").read_bytes() == (b / "episodes.json").read_bytes()
    pngs = sorted(p.name for p in (a / "goals").glob("*.png"))
    assert len(pngs) == 2 and pngs == sorted(p.name for p in (b / "goals").glob("*.png"))
    for name in pngs:
        assert (a / "goals" / name).read_bytes() == (b / "goals" / name).read_bytes()
    es = load_episode_set(a)
    assert es.split == "val" and len(es) == 2
    e = es.episodes[0]
    assert e.geodesic_distance_m >= 1.5 and len(e.viewpoints_xy_m) >= 8
    assert es.load_goal_image(e).shape == (512, 512, 3)
