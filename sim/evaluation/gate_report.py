"""What the re-ID gate would drop, from a shadow run (``python -m sim.evaluation.gate_report``).

A run with ``--modiin-set reid.gate=false --modiin-set reid.gate_shadow=true`` gives every frame
the full matcher and records, per step, the full score, the first stage's MNN count and the exit
stage's score (``modiin.trace``). With the thresholds in force (the deployment's calibration
file, scaled for potential evidence as the agent scales them), this counts the frames each stage
and both together would have scored 0 among those the full matcher scores at or above tau, and at
or above the potential-evidence bar, and the share of all frames that would still get every layer.
Frames of every mode count (near a candidate the agent does not gate: an upper bound).

    python -m sim.evaluation.gate_report runs/tr10_off [--config sim]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def shadow_frames(run_dir: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(full, gate, exit) per recorded frame with all three scores, and the episodes they came from."""
    full, gate, exit_, episodes = [], [], [], 0
    for line in (Path(run_dir) / "episodes.jsonl").read_text().splitlines():
        if not line.strip():
            continue
        tr = (json.loads(line).get("modiin") or {}).get("trace") or {}
        rows = [
            (f, g, e)
            for f, g, e in zip(tr.get("reid_score") or [], tr.get("gate_score") or [], tr.get("exit_score") or [])
            if None not in (f, g, e)
        ]
        episodes += bool(rows)
        for f, g, e in rows:
            full.append(f)
            gate.append(g)
            exit_.append(e)
    return np.asarray(full, float), np.asarray(gate, float), np.asarray(exit_, float), episodes


def report(
    full: np.ndarray, gate: np.ndarray, exit_: np.ndarray, tau: float, gate_thr: float, exit_thr: float, ratio: float
) -> list[str]:
    lines = [
        f"{len(full)} frames; tau {tau:.4g}; first stage {gate_thr:g}, exit stage {exit_thr:.3g} "
        f"(x {ratio:g} for potential evidence: {gate_thr * ratio:g}, {exit_thr * ratio:.3g})"
    ]
    for name, bar, scale in (("tau", tau, 1.0), (f"{ratio:g} tau", ratio * tau, ratio)):
        pos = full >= bar
        s1 = gate < gate_thr * scale
        s2 = exit_ < exit_thr * scale
        n = int(pos.sum())
        lines.append(
            f"  frames >= {name}: {n}; dropped by the first stage {int((pos & s1).sum())}, by the exit stage "
            f"{int((pos & s2).sum())}, by either {int((pos & (s1 | s2)).sum())} "
            f"({(pos & (s1 | s2)).sum() / max(n, 1):.1%})"
        )
    g2 = ~(gate < gate_thr * ratio) & ~(exit_ < exit_thr * ratio)
    g1 = ~(gate < gate_thr * ratio)
    lines.append(f"  every layer would run on {g2.mean():.1%} of the frames (first stage alone: {g1.mean():.1%})")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", help="evaluation directories of shadow runs")
    p.add_argument("--config", default="sim")
    args = p.parse_args(argv)
    from agent.config import load_agent_config
    from agent.reid.identifier import resolve_exit_threshold, resolve_gate_threshold, resolve_tau

    cfg = load_agent_config(args.config)
    tau, gate_thr, exit_thr = resolve_tau(cfg.reid), resolve_gate_threshold(cfg.reid), resolve_exit_threshold(cfg.reid)
    if gate_thr is None or exit_thr is None:
        print(f"the {args.config} deployment has no gate thresholds in force", file=sys.stderr)
        return 2
    ratio = cfg.policy.potential_tau_ratio if cfg.policy.potential_tau_ratio < 1.0 else 1.0
    for run in args.runs:
        full, gate, exit_, episodes = shadow_frames(run)
        if not len(full):
            print(
                f"{run}: no frame with all three scores (run it with reid.gate=false, reid.gate_shadow=true)",
                file=sys.stderr,
            )
            return 2
        print(f"{run} ({episodes} episodes):")
        print("\n".join(report(full, gate, exit_, tau, gate_thr, exit_thr, ratio)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
