"""What LightGlue's adaptive depth (``reid.early_stop``) saves and changes, on egocentric frames.

    .venv/bin/python benchmarks/bench_matcher_depth.py [--episodes DIR] [--count 6] [--every 2]
        [--early-stop 0.95 0.9] [--threads 1]

The shortest-path oracle drives through the first ``--count`` episodes of a train set (a small
one is generated into a temporary directory when none is given), so the frames run from the
start, where the goal is usually out of sight, to the goal viewpoint. Every ``--every``-th frame
is extracted once (XFeat, the agent's settings) and matched against the episode's goal image by
LighterGlue with every layer (the default, under which tau and the gate were calibrated) and with
each ``--early-stop`` value, back to back on the same features. Prints, per setting, the median
and p90 match time, the ratio to all layers, the layers run, the score change, and how many
frames change side of tau and of tau/2 (the potential-evidence threshold of the sim deployment);
once over every frame and once over the frames the sim deployment's gate lets through (the only
ones on which the full matcher runs while exploring).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.episode_sets import load_or_generate  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", default=None, help="train episode set (default: generate --count into a temp dir)")
    p.add_argument("--count", type=int, default=6)
    p.add_argument("--every", type=int, default=2, help="use every k-th frame")
    p.add_argument("--early-stop", type=float, nargs="+", default=[0.95, 0.9])
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: as inside imgnav eval)")
    p.add_argument("--config", default="sim")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)

    import numpy as np
    import torch

    from agent.config import load_agent_config
    from agent.reid.base import score
    from agent.reid.gate import MNNGate
    from agent.reid.identifier import resolve_gate_threshold, resolve_tau
    from agent.reid.xfeat import XFeatLighterGlue
    from sim.backend import SimBackend
    from sim.oracle_agent import OracleAgent
    from sim.world import SimWorld

    torch.set_num_threads(args.threads)
    cfg = load_agent_config(args.config)
    rc = cfg.reid
    if rc.matcher != "xfeat_lighterglue":
        raise SystemExit(f"{args.config}: matcher {rc.matcher}, this benchmark is for xfeat_lighterglue")
    tau = resolve_tau(rc)
    ratio = cfg.policy.potential_tau_ratio
    gate_base = resolve_gate_threshold(rc)
    gate_threshold = None if gate_base is None else gate_base * ratio
    settings = [-1.0] + list(args.early_stop)
    matchers = {s: XFeatLighterGlue(rc.max_side_px, rc.min_confidence, early_stop=s) for s in settings}
    extractor = matchers[-1.0]

    es, tmp = load_or_generate(args.episodes, "train", 7, args.count)

    rows: list[dict] = []  # per frame: gate score, and per setting (score, ms, layers)
    for ep in list(es.episodes)[: args.count]:
        with SimWorld.from_seed(ep.scene_seed) as world:
            backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep))
            obs = backend.reset()
            goal = extractor.extract(obs.goal_image, rc.goal_max_keypoints)
            gate = MNNGate(rc.gate_min_cosine)
            gate.set_goal(goal.descriptors)
            agent = OracleAgent(backend.oracle)
            agent.reset(obs.goal_image)
            k = 0
            while not backend.done:
                if k % args.every == 0:
                    feats = extractor.extract(obs.rgb, rc.obs_max_keypoints)
                    row = {"gate": gate.score(feats.descriptors)}
                    for s, m in matchers.items():
                        t0 = time.perf_counter()
                        mt = m.match(goal, feats)
                        row[s] = (score(mt, rc.score), 1e3 * (time.perf_counter() - t0), m.layers_run)
                    rows.append(row)
                k += 1
                backend.apply(agent.act(obs))
                if not backend.done:
                    obs = backend.observe()
            backend.close()
    if tmp is not None:
        tmp.cleanup()

    def report(title: str, sel: list[dict]) -> None:
        print(f"{title}: {len(sel)} frames")
        if not sel:
            return
        base_ms = [r[-1.0][1] for r in sel]
        print(f"  {'setting':<16} {'match ms':>9} {'p90':>7} {'ratio':>6} {'layers':>6} {'|d score| med/max':>18}"
              f" {'>=tau':>6} {'flips':>5} {'>=tau/2':>7} {'flips':>5}")
        for s in settings:
            ms = [r[s][1] for r in sel]
            sc = np.array([r[s][0] for r in sel])
            b = np.array([r[-1.0][0] for r in sel])
            d = np.abs(sc - b)
            layers = statistics.median([r[s][2] for r in sel])
            p90 = sorted(ms)[int(0.9 * (len(ms) - 1))]
            ratio_ms = statistics.median(ms) / statistics.median(base_ms)
            flips_tau = int(((sc >= tau) != (b >= tau)).sum())
            flips_half = int(((sc >= ratio * tau) != (b >= ratio * tau)).sum())
            name = "all layers" if s == -1.0 else f"early stop {s:g}"
            print(f"  {name:<16} {statistics.median(ms):7.1f}   {p90:6.1f} {ratio_ms:6.2f} {layers:6.1f}"
                  f" {np.median(d):8.2f} / {d.max():7.2f} {int((sc >= tau).sum()):6d} {flips_tau:5d}"
                  f" {int((sc >= ratio * tau).sum()):7d} {flips_half:5d}")

    print(f"LighterGlue adaptive depth on {len(rows)} frames of {min(args.count, len(es.episodes))} {es.split} "
          f"episodes (oracle paths), torch threads {args.threads}; tau {tau:.1f}, tau x {ratio:g} = {ratio * tau:.1f}")
    report("every frame", rows)
    if gate_threshold is not None:
        report(f"frames through the gate (threshold {gate_threshold:g})", [r for r in rows if r["gate"] >= gate_threshold])
    return 0


if __name__ == "__main__":
    sys.exit(main())
