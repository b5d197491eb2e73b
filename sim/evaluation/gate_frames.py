"""Record what a re-ID gate needs, frame by frame, on train episodes (``python -m sim.evaluation.gate_frames``).

A gate (agent/reid/gate.py) decides from the keypoint features alone whether the full matcher
(LighterGlue) is worth running on a frame. Choosing and calibrating one needs, for each frame the
agent sees: its features, the full matcher's score and what the agent was doing. This runs the
deployment's agent with the gate off (the full matcher on every frame, so every frame has its true
score and the agent acts as the gated agent would wherever the gate keeps the frames that matter) and
writes one compressed ``.npz`` per episode:

    goal_kp (G, 2) float32, goal_desc (G, 64) float16, goal_size_wh (2,)   the goal image's features
    kp      (T, K, 2) float32 pixel xy of each frame's keypoints (padded; n_kp gives the count)
    desc    (T, K, 64) float16 descriptors (float16 halves the file; the gate's scores move < 1e-3)
    n_kp    (T,) int32, size_wh (2,) the frames' size
    full    (T,) float32 full re-ID score (sum of LighterGlue confidences)
    searching (T,) bool   the agent was looking around, exploring or rescanning (where a gate acts)
    goal_px (T,) int32    goal pixels in the frame (ground truth, for analysis only)
    tau     ()            the tau in force

Train only (``--split`` is checked): these frames choose a threshold.

    python -m sim.evaluation.gate_frames --episodes data/episodes/trainph40 --count 20 \
        --max-steps 400 --workers 2 --out runs/gate_frames
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from agent.reid import Features

log = logging.getLogger(__name__)

SEARCHING_MODES = ("look_around", "explore", "rescan")


class _RecordingMatcher:
    """Passes everything to the real matcher and keeps the last features it extracted."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.name = inner.name
        self.last: Features | None = None  # what extract() returned last

    def extract(self, rgb, max_keypoints):
        self.last = self.inner.extract(rgb, max_keypoints)
        return self.last

    def match(self, goal, obs):
        return self.inner.match(goal, obs)


def _as_numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def record_episode(world, es, episode, config, max_steps: int, out_path: Path) -> dict:
    """Run one episode with the gate off and write its frames; returns a small summary."""
    from agent.loop import run_loop
    from agent.policy import ModIINAgent
    from agent.reid.identifier import make_matcher
    from sim.backend import SimBackend

    rec = _RecordingMatcher(make_matcher(config.reid))
    agent = ModIINAgent(config, matcher=rec)
    backend = SimBackend.for_episode(world, episode, es.goal_image_path(episode))
    frames: dict[str, list] = {k: [] for k in ("kp", "desc", "full", "searching", "goal_px")}

    class Sink:
        def before_apply(self, s) -> None:
            f = rec.last
            assert f is not None  # the agent extracted this step's frame
            frames["kp"].append(_as_numpy(f.extra.get("kp_resized", f.keypoints_xy)).astype(np.float32))
            frames["desc"].append(_as_numpy(f.descriptors).astype(np.float16))
            frames["full"].append(float(s.record.reid_score))
            frames["searching"].append(s.record.mode in SEARCHING_MODES)
            frames["goal_px"].append(int(backend.oracle.goal_mask().sum()))

        def step(self, s) -> None:
            pass

    run_loop(backend, agent, max_steps, sinks=(Sink(),), should_stop=lambda: backend.done)
    assert agent.reid is not None and agent.reid.goal is not None and rec.last is not None
    goal, last = agent.reid.goal, rec.last
    backend.close()
    n = len(frames["full"])
    k = max((len(x) for x in frames["kp"]), default=0)
    kp = np.zeros((n, k, 2), np.float32)
    desc = np.zeros((n, k, goal.descriptors.shape[-1]), np.float16)
    n_kp = np.zeros(n, np.int32)
    for i, (a, d) in enumerate(zip(frames["kp"], frames["desc"])):
        kp[i, : len(a)], desc[i, : len(d)], n_kp[i] = a, d, len(a)
    np.savez_compressed(
        out_path,
        goal_kp=_as_numpy(goal.extra.get("kp_resized", goal.keypoints_xy)).astype(np.float32),
        goal_desc=_as_numpy(goal.descriptors).astype(np.float16),
        goal_size_wh=np.asarray(goal.extra.get("size_resized_wh", goal.image_size_wh), np.float32),
        kp=kp,
        desc=desc,
        n_kp=n_kp,
        size_wh=np.asarray(last.extra.get("size_resized_wh", last.image_size_wh), np.float32),
        full=np.asarray(frames["full"], np.float32),
        searching=np.asarray(frames["searching"], bool),
        goal_px=np.asarray(frames["goal_px"], np.int32),
        tau=np.float32(agent.tau),
    )
    return {"episode_id": episode.episode_id, "frames": n}


def _run_scene(job: tuple) -> list[dict]:
    episodes_dir, ids, config_name, max_steps, out, threads = job
    import torch

    from agent.config import load_agent_config
    from sim.episodes import load_episode_set
    from sim.world import SimWorld

    torch.set_num_threads(threads)
    es = load_episode_set(episodes_dir)
    by_id = {e.episode_id: e for e in es.episodes}
    cfg = load_agent_config(config_name)
    cfg = replace(cfg, reid=replace(cfg.reid, gate=False, gate_shadow=False, num_threads=threads))
    done = []
    world = SimWorld.from_seed(by_id[ids[0]].scene_seed)
    try:
        for eid in ids:
            path = Path(out) / f"{eid}.npz"
            if path.is_file():
                continue
            done.append(record_episode(world, es, by_id[eid], cfg, max_steps, path))
            log.info("%s: %d frames", eid, done[-1]["frames"])
    finally:
        world.close()
    return done


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", required=True, help="a train episode set")
    p.add_argument("--count", type=int, default=20)
    p.add_argument("--max-steps", type=int, default=400)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--config", default="sim")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from sim.episodes import load_episode_set

    es = load_episode_set(args.episodes)
    eps = list(es.episodes)[: args.count]
    bad = [e.episode_id for e in eps if e.split != "train"]
    if bad:
        print(f"gate frames are recorded on train episodes only, not {bad[0]}", file=sys.stderr)
        return 2
    Path(args.out).mkdir(parents=True, exist_ok=True)
    scenes: dict[int, list[str]] = {}
    for e in eps:
        scenes.setdefault(e.scene_seed, []).append(e.episode_id)
    jobs = [(args.episodes, ids, args.config, args.max_steps, args.out, 1) for ids in scenes.values()]
    if args.workers > 1:
        with mp.get_context("spawn").Pool(args.workers) as pool:
            for res in pool.imap_unordered(_run_scene, jobs):
                for r in res:
                    print(f"{r['episode_id']}: {r['frames']} frames", flush=True)
    else:
        for job in jobs:
            for r in _run_scene(job):
                print(f"{r['episode_id']}: {r['frames']} frames", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
