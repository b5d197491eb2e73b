"""The Mod-IIN agent's summary of an evaluation (``summarize``: failure causes, noise, the parts of
a step, the paper's table row) and the paper-layout comparison of several runs
(``comparison_tables``; ``python -m sim.evaluation.modiin OUT1 OUT2 ...``)."""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sim.evaluation.compare import FAILURE_CLASSES


def failure_distribution(records: list[dict[str, Any]]) -> dict[str, Any]:
    failed = [r for r in records if not r.get("success")]
    counts = Counter(r.get("failure_cause") or ("error" if r.get("error") else "unattributed") for r in failed)
    n = max(len(failed), 1)
    return {"failed": len(failed), "counts": dict(counts), "shares": {k: round(v / n, 3) for k, v in counts.items()}}


def _with_ci(value: float, ci: Any) -> str:
    if isinstance(ci, (list, tuple)) and len(ci) == 2 and all(isinstance(c, (int, float)) for c in ci):
        return f"{value:.3f} [{ci[0]:.2f}, {ci[1]:.2f}]"
    return f"{value:.3f}"


def table_row(label: str, summary: Mapping[str, Any]) -> str:
    """One row of the paper's layout; SR and SPL carry their 95% bootstrap-over-homes interval
    and the episode count its number of homes, when the summary has them."""
    ne = summary.get("ne")
    ne_s = f"{ne:.2f}" if isinstance(ne, (int, float)) and math.isfinite(ne) else str(ne)
    sr = _with_ci(summary["sr"], summary.get("sr_ci95"))
    spl = _with_ci(summary["spl"], summary.get("spl_ci95"))
    n = f"{summary['episodes']}" + (f" ({summary['homes']} homes)" if "homes" in summary else "")
    return f"| {label} | {ne_s} | {summary['max_st']:.3f} | {sr} | {spl} | {n} |"


TABLE_HEADER = (
    "| variant | NE (m) | Max-ST | SR [95% CI] | SPL [95% CI] | episodes |\n| --- | --- | --- | --- | --- | --- |"
)


def noise_diagnostics(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Phantom obstacles and pose error, over successes and failures (medians): what a realism
    profile's noise did to the agent's map and pose."""
    out: dict[str, Any] = {}
    for name, group in (
        ("success", [r for r in records if r.get("success")]),
        ("failure", [r for r in records if not r.get("success")]),
    ):
        ghosts = [
            r["modiin"]["ghost_obstacle_cells"]
            for r in group
            if r.get("modiin", {}).get("ghost_obstacle_cells") is not None
        ]
        drift = [r["modiin"]["pose_error_m"]["max"] for r in group if "pose_error_m" in r.get("modiin", {})]
        out[name] = {
            "episodes": len(group),
            "median_ghost_obstacle_cells": float(np.median(ghosts)) if ghosts else None,
            "median_max_pose_error_m": round(float(np.median(drift)), 3) if drift else None,
        }
    return out


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    from sim.metrics import aggregate

    variants = sorted({r.get("variant", "?") for r in records})
    agg = aggregate([{**r, "ne": float(r["ne"])} for r in records])
    per_step = {}
    for key in ("mapping", "reid", "localisation", "planning", "total"):
        vals = [r["modiin"]["median_ms"][key] for r in records if key in r.get("modiin", {}).get("median_ms", {})]
        if vals:
            per_step[key] = round(float(np.median(vals)), 2)
    return {
        "variant": variants[0] if len(variants) == 1 else variants,
        "failure_causes": failure_distribution(records),
        "noise": noise_diagnostics(records),
        "agent_median_ms_per_step": per_step,
        "table_md": TABLE_HEADER + "\n" + table_row(", ".join(variants), agg),
    }


def comparison_tables(out_dirs: list[str]) -> str:
    """The paper-layout table and the failure shares of several evaluation outputs, as Markdown."""
    rows, fails = [TABLE_HEADER], []
    for d in out_dirs:
        s = json.loads((Path(d) / "summary.json").read_text())
        label = s.get("variant", d)
        rows.append(table_row(label if isinstance(label, str) else d, s))
        fc = s.get("failure_causes", {}).get("shares", {})
        fails.append(f"| {label} | " + " | ".join(f"{fc.get(c, 0.0):.2f}" for c in FAILURE_CLASSES) + " |")
    header = ["| variant | " + " | ".join(FAILURE_CLASSES) + " |", "| --- |" + " --- |" * len(FAILURE_CLASSES)]
    return "\n".join(rows) + "\n\n" + "\n".join(header + fails)
