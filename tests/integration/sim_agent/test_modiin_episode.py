"""One real simulated episode end to end with the Mod-IIN agent (PyBullet, real renders)."""

import numpy as np
import pytest

from agent.config import AgentConfig, PolicyConfig
from agent.policy import ModIINAgent
from agent.reid.identifier import ReIDConfig
from agent.types import Action, AgentRecord, MapSnapshot
from sim.backend import SimBackend
from sim.episode_gen import generate_episode_set
from sim.episodes import load_episode_set, save_episode_set
from sim.world import SimWorld
from tests.helpers.eval_args import modiin_args


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    d = tmp_path_factory.mktemp("episodes")
    generate_episode_set("train", 7, 5, d, progress=False)
    es = load_episode_set(d)
    ep = min(es.episodes, key=lambda e: e.geodesic_distance_m)  # the easiest: small and fast
    save_episode_set(d, es.split, es.seed, [ep], es.meta)  # keep only it (its goal PNG stays)
    es = load_episode_set(d)
    world = SimWorld.from_seed(ep.scene_seed)
    yield es, ep, world
    world.close()


def test_oracle_reid_and_localisation_reach_the_goal(episode):
    es, ep, world = episode
    backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep), max_steps=400)
    cfg = AgentConfig(policy=PolicyConfig(reid_source="oracle", localisation_source="oracle"))
    agent = ModIINAgent(
        cfg,
        oracle_reid=lambda obs: int(backend.oracle.goal_mask().sum()) >= 400,
        oracle_ego_mask=lambda obs: backend.oracle.goal_mask(),
    )
    obs = backend.reset()
    agent.reset(obs.goal_image)
    while not backend.done:
        action = agent.act(obs)
        assert agent.last_record is not None and agent.last_record.planner_error is None or action != Action.STOP
        backend.apply(action)
        if not backend.done:
            obs = backend.observe()
    m = backend.result()
    assert m is not None and m.called_stop and m.success, (m, agent.last_record.mode, agent.last_record.reason)


def test_default_agent_steps_with_real_matching(episode):
    es, ep, world = episode
    backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep), max_steps=16)
    agent = ModIINAgent(AgentConfig(reid=ReIDConfig(tau=10.0, num_threads=1, gate=False)))
    obs = backend.reset()
    agent.reset(obs.goal_image)
    records: list[AgentRecord] = []
    while not backend.done:
        action = agent.act(obs)
        records.append(agent.last_record)
        backend.apply(action)
        if not backend.done:
            obs = backend.observe()
    assert records
    # the look-around turns 12 times unless a candidate (a detection, or potential evidence at
    # tau/2, verified from the ring) ends it; then the run may stop at that candidate early
    early = [r for r in records[:12] if r.mode != "look_around"]
    if early:
        assert early[0].candidates and early[0].candidate_id is not None, early[0].reason
    else:
        assert len(records) >= 12
    if records[-1].action == Action.STOP:
        assert records[-1].event == "stop_at_goal" and records[-1].candidate_id is not None
    for r in records:
        assert r.reid_score is not None and r.reid_tau == 10.0
        assert r.matches_goal_xy.shape == r.matches_obs_xy.shape and r.matches_goal_xy.shape[1] == 2
        assert {"mapping", "reid", "localisation", "planning", "total"} <= set(r.timings_ms)
        assert isinstance(r.map, MapSnapshot) and r.map.explored.any() and r.map.obstacle.shape == r.map.explored.shape
    # the map is in the start-relative frame: the start cell is visited
    snap = records[-1].map
    i, j = snap.xy_to_ij(np.array([[0.0, 0.0]]))[0]
    assert snap.visited[i, j]


def test_eval_plugin_runs_an_episode(episode, tmp_path):
    from sim.evaluation.runner import run_evaluation

    es, ep, _ = episode
    args = modiin_args(modiin_reid="oracle", modiin_loc="oracle", modiin_set=["policy.look_around_turns=0"])
    summary = run_evaluation(es.directory, "modiin", args, tmp_path, limit=1, progress=False, fail_fast=True)
    assert summary["episodes"] == 1 and "failure_causes" in summary and "table_md" in summary


def test_recorded_gate_frames_rescore_like_the_agent_scored_them(episode, tmp_path):
    """`python -m sim.evaluation.gate_frames` keeps each frame's features, so the gate can be
    calibrated for other matcher settings without new episodes: re-scored from the file, every
    frame gets the score the agent gave it (float16 descriptors move it a little) and the gate
    score the agent's gate would give it."""
    from dataclasses import replace

    import torch

    from agent.config import load_agent_config
    from agent.reid.gate import MNNGate
    from agent.reid.identifier import make_matcher
    from sim.evaluation.gate_calibration import frames_from_recordings
    from sim.evaluation.gate_frames import record_episode

    es, ep, world = episode
    cfg = load_agent_config("sim")
    cfg = replace(cfg, reid=replace(cfg.reid, gate=False, num_threads=1))
    summary = record_episode(world, es, ep, cfg, 6, tmp_path / f"{ep.episode_id}.npz")
    z = dict(np.load(tmp_path / f"{ep.episode_id}.npz"))
    n = summary["frames"]
    assert 1 <= n <= 6 and z["full"].shape == z["searching"].shape == z["n_kp"].shape == (n,)
    assert z["kp"].shape[:2] == z["desc"].shape[:2] == (n, int(z["n_kp"].max())) and z["desc"].dtype == np.float16
    assert z["searching"][0]  # the first step looks around
    matcher = make_matcher(cfg.reid)
    full, gate, exit_, episodes = frames_from_recordings([str(tmp_path)], matcher, cfg.reid.gate_min_cosine)
    assert episodes == 1 and len(full) == len(exit_) == n
    assert np.all(np.isnan(exit_))  # this matcher has no exit layer (the recorder's config has the gate off)
    assert np.allclose(full, z["full"], rtol=0.03, atol=1.0), (full, z["full"])
    g = MNNGate(cfg.reid.gate_min_cosine)
    g.set_goal(torch.from_numpy(z["goal_desc"].astype(np.float32)))
    expect = [g.score(torch.from_numpy(z["desc"][i, : z["n_kp"][i]].astype(np.float32))) for i in range(n)]
    assert gate.tolist() == expect
    # with the exit layer, every frame also gets the exit stage's score (and the same full score)
    exit_matcher = make_matcher(replace(cfg.reid, gate=True))
    full2, _, exit2, _ = frames_from_recordings([str(tmp_path)], exit_matcher, cfg.reid.gate_min_cosine)
    assert np.array_equal(full2, full) and np.all(np.isfinite(exit2)) and np.all(exit2 >= 0)
    # a val recording is refused
    (tmp_path / f"{ep.episode_id}.npz").rename(tmp_path / "val-s0-0000-0.npz")
    with pytest.raises(ValueError, match="train only"):
        frames_from_recordings([str(tmp_path)], matcher, cfg.reid.gate_min_cosine)
