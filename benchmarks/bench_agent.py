"""Median per-step latency of the Mod-IIN agent and of each of its parts on val episodes.

    .venv/bin/python benchmarks/bench_agent.py [--episodes DIR] [--count 3] [--steps 150] [--threads 2]

Runs the default agent (agent/configs/sim.yaml: XFeat + LighterGlue, re-ID gate, early stop as
configured) through the real simulator on the first ``--count`` episodes of a val episode set (a small one is
generated into a temporary directory when none is given) for at most ``--steps`` steps each.
Shadow agents, identical but without LighterGlue's early stop ("all layers"), without the gate's exit
stage ("no exit stage") and without the gate ("no gate, all layers": the agent before issue 9), act on
the very same observations right
after it (their actions are discarded), so all are measured back to back on the same frames.
Prints, for each, the median milliseconds per step of the whole ``act`` (total) and its parts:
mapping, reid (feature extraction, gate, full matching), localisation and planning, the ratios
default / shadow, and the share of frames on which the full matcher ran. The simulator's render
time is reported apart. Target: total <= 50 ms median with the gate on, 2 threads.
Timings from a loaded machine are not final: run it on a quiet one.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.episode_sets import load_or_generate  # noqa: E402

PARTS = ("mapping", "reid", "reid_extract", "reid_gate", "reid_match", "localisation", "planning", "total")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", default=None, help="val episode set (default: generate 3 into a temp dir)")
    p.add_argument("--count", type=int, default=3)
    p.add_argument("--steps", type=int, default=150)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--config", default="sim")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)

    import torch

    from agent.config import load_agent_config
    from agent.loop import run_loop
    from agent.policy import ModIINAgent
    from sim.backend import SimBackend
    from sim.world import SimWorld

    torch.set_num_threads(args.threads)
    es, tmp = load_or_generate(args.episodes, "val", 0, args.count)
    cfg = load_agent_config(args.config)
    from dataclasses import replace

    cfg = replace(cfg, reid=replace(cfg.reid, num_threads=args.threads))
    agent = ModIINAgent(cfg)
    # the shadows: the same agent without what issue 9 added, acting on the very same frames
    variants = {"default": cfg}
    if cfg.reid.gate and cfg.reid.gate_exit_layer:
        variants["no exit stage"] = replace(cfg, reid=replace(cfg.reid, gate_exit_layer=0))
    if cfg.reid.gate:
        variants["no gate"] = replace(cfg, reid=replace(cfg.reid, gate=False))
    shadows = {name: ModIINAgent(c) for name, c in variants.items() if name != "default"}
    samples = {name: {k: [] for k in PARTS} for name in variants}
    full_runs = {name: 0 for name in samples}

    def keep(name: str, rec) -> None:
        for k in PARTS:
            if rec is not None and k in rec.timings_ms:
                samples[name][k].append(float(rec.timings_ms[k]))
        full_runs[name] += bool(rec is not None and rec.reid_full_matcher)

    class Timings:
        """The driving agent's record, and each shadow agent on the very same frame, back to back
        (their actions are discarded); a before-apply sink, so they see the frame the agent acted on."""

        def before_apply(self, s) -> None:
            keep("default", s.record)
            for name, shadow in shadows.items():
                shadow.act(s.obs)
                keep(name, shadow.last_record)

        def step(self, s) -> None:
            pass

    class ShadowReset:
        """Resets the shadow agents with the episode's goal when the loop resets the driver."""

        def __init__(self, backend) -> None:
            self.backend = backend

        def reset(self):
            obs = self.backend.reset()
            for shadow in shadows.values():
                shadow.reset(obs.goal_image)
            return obs

        def __getattr__(self, name):
            return getattr(self.backend, name)

    sim_ms: list[float] = []
    worlds: dict[int, SimWorld] = {}
    for ep in list(es.episodes)[: args.count]:
        world = worlds.get(ep.scene_seed) or worlds.setdefault(ep.scene_seed, SimWorld.from_seed(ep.scene_seed))
        backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep))
        result = run_loop(ShadowReset(backend), agent, args.steps, sinks=(Timings(),))
        if result.n_steps > 1:
            sim_ms.append(1000 * result.backend_s / result.n_steps)
        backend.close()
    for w in worlds.values():
        w.close()
    n = len(samples["default"]["total"])
    print(
        f"Mod-IIN agent, {cfg.reid.matcher} ({cfg.reid.obs_max_keypoints} keypoints per frame, "
        f"{cfg.reid.goal_max_keypoints} goal), gate {'on' if cfg.reid.gate else 'off'}, "
        f"torch threads {args.threads}, {n} steps of {min(args.count, len(es.episodes))} "
        f"{es.split} episodes; every variant on the same frames, back to back"
    )
    med = {name: {k: statistics.median(v) for k, v in per.items() if v} for name, per in samples.items()}
    names = list(variants)
    print(
        f"  {'part':<13}"
        + "".join(f" {name:>20} {'p90':>8}" for name in names)
        + "".join(f"   default/{name}" for name in names[1:])
    )
    for k in PARTS:
        if any(k not in med[name] for name in names):
            continue
        cells = []
        for name in names:
            v = sorted(samples[name][k])
            cells.append(f" {med[name][k]:17.1f} ms {v[int(0.9 * (len(v) - 1))]:6.1f} ms")
        ratios = [
            f"   {med['default'][k] / med[name][k]:{len('default/' + name)}.2f}"
            if med[name][k] > 0.05
            else "   " + "-".rjust(len("default/" + name))
            for name in names[1:]
        ]
        print(f"  {k:<13}" + "".join(cells) + "".join(ratios))
    print(
        "  full matcher ran on "
        + ", ".join(
            f"{full_runs[name]} of {n} frames ({100 * full_runs[name] / max(n, 1):.1f}%) {name}" for name in names
        )
    )
    if sim_ms:
        print(
            f"  (simulator apply+render per step, median over episodes {statistics.median(sim_ms):.1f} ms, "
            "not part of the agent)"
        )
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
