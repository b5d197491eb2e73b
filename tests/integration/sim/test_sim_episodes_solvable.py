"""Every generated episode is solvable by the shortest-path oracle agent (checked at generation
time by ``sim.episode_gen.oracle_solves``): over many homes, the oracle agent run on the stored
episodes (JSON round trip, freshly built worlds) succeeds on every one.

Four homes per split, one episode each (eight homes in all, each with its own floor plan,
furniture and goal): several layouts, both splits' seeds and the JSON round trip, which is what
can break between generation and use."""

from __future__ import annotations

from pathlib import Path

import pytest

import sim.episode_gen as episode_gen
from agent.types import Pose2D
from sim.backend import SimBackend
from sim.episode_gen import EpisodeGenConfig, generate_episode_set
from sim.episodes import load_episode_set
from sim.oracle_agent import run_blind
from sim.world import SimWorld

HOMES = 4  # per split, one episode each


def _oracle_result(world: SimWorld, episode, goal_path: Path):
    """The oracle agent on a stored episode, without renders (``test_sim_oracle_episode`` runs
    it with real ones)."""
    return run_blind(SimBackend.for_episode(world, episode, goal_path))


@pytest.mark.parametrize("split,seed", [("train", 901), ("val", 901)])
def test_the_oracle_solves_every_generated_episode_over_many_homes(tmp_path: Path, split: str, seed: int) -> None:
    out = tmp_path / split
    generate_episode_set(split, seed, HOMES, out, EpisodeGenConfig(episodes_per_scene=1), progress=False)
    es = load_episode_set(out)
    assert len(es.episodes) == HOMES and len({e.scene_seed for e in es.episodes}) == HOMES
    for e in es.episodes:
        world = SimWorld.from_seed(e.scene_seed)
        try:
            m = _oracle_result(world, e, es.goal_image_path(e))
        finally:
            world.close()
        assert m is not None and m.success and m.steps > 1, (e.episode_id, m)


def test_a_start_the_oracle_does_not_solve_is_replaced(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    refused: list[Pose2D] = []
    real = episode_gen.oracle_solves

    def first_start_unsolved(world, start, inst, vp, geo):
        if not refused or refused[-1][1] != inst:
            refused.append((start, inst))
            return False
        return real(world, start, inst, vp, geo)

    monkeypatch.setattr(episode_gen, "oracle_solves", first_start_unsolved)
    eps = generate_episode_set("train", 902, 2, tmp_path, EpisodeGenConfig(episodes_per_scene=2), progress=False)
    assert len(eps) == 2 and refused
    refused_starts = {(p.x_m, p.y_m, p.yaw_rad) for p, _ in refused}
    assert all(
        (e.start_pose_world.x_m, e.start_pose_world.y_m, e.start_pose_world.yaw_rad) not in refused_starts for e in eps
    )
