"""Presentation of ``sim.evaluation.evidence``: its Markdown tables, the plain-text conclusion
drawn from the numbers only, and the figure (scores against apparent size and distance)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.evaluation.evidence import FRAME_PX, OUT_OF_VIEW_PX, BinRow, Bins, Evidence, Range


def _r(v: Range, pct: bool = False) -> str:
    f = (lambda x: f"{100 * x:.0f}%") if pct else (lambda x: f"{x:.0f}")
    return "-" if not math.isfinite(v[0]) else f(v[0]) if f(v[0]) == f(v[1]) else f"{f(v[0])}..{f(v[1])}"


def score_table(rows: list[BinRow], unit: str, with_negatives: bool) -> str:
    head = f"| bin | positives ({unit}) | gated | score q25 / q50 / q75 | pos >= tau | pos >= tau/2 |"
    if with_negatives:
        head += " negatives | neg >= tau | neg >= tau/2 |"
    lines = [head, "|" + " --- |" * (head.count("|") - 1)]
    for r in rows:
        line = (
            f"| {r.label} | {r.positives} ({r.units}) | {r.censored} | {' / '.join(_r(q) for q in r.quartiles)} "
            f"| {_r(r.pos_at_tau, True)} | {_r(r.pos_at_half_tau, True)} |"
        )
        if with_negatives:
            line += f" {r.negatives} | {_r(r.neg_at_tau, True)} | {_r(r.neg_at_half_tau, True)} |"
        lines.append(line)
    return "\n".join(lines)


def threshold_table(named_rows: dict[str, list[BinRow]]) -> str:
    lines = [
        "| data | bin | positives | negatives | max-F threshold | F | precision | recall | F at tau |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, rows in named_rows.items():
        for r in rows:
            m, head = r.max_f, f"| {name} | {r.label} | {r.positives} | {r.negatives} |"
            thr = (
                ""
                if m is None
                else f"<= {m.threshold:.1f} (floor {m.floor:.1f})"
                if m.at_floor
                else f"{m.threshold:.1f}"
            )
            lines.append(
                f"{head} too few samples | | | | |"
                if m is None
                else f"{head} {thr} | {m.f:.2f} | {m.precision:.2f} | {m.recall:.2f} | {m.f_at_tau:.2f} |"
            )
    return "\n".join(lines)


def _mid(v: Range) -> float:
    return 0.5 * (v[0] + v[1])


def conclusion(name: str, rows: list[BinRow], tau: float, min_positives: int, with_negatives: bool) -> list[str]:
    """Plain sentences from the numbers only (bins with >= min_positives positives)."""
    ok = [r for r in rows if r.positives >= min_positives]
    if len(ok) < 2:
        return [f"{name}: fewer than two bins with {min_positives}+ positives; no shape to report."]
    med = [_mid(r.quartiles[1]) for r in ok]
    peak = int(np.argmax(med))
    # steps within 15% count as level: a few episodes' frames are too correlated for finer claims
    drops = med[-1] < 0.85 * med[peak]
    shape = (
        f"peaks at {ok[peak].label}"
        if drops and peak > 0
        else "rises"
        if med[-1] > 1.15 * med[0] and all(b >= 0.85 * a for a, b in zip(med, med[1:]))
        else "falls"
        if med[-1] < 0.85 * med[0] and all(b <= 1.15 * a for a, b in zip(med, med[1:]))
        else "shows no trend beyond 15%"
    )
    out = [
        f"{name}: the median true-goal score {shape} across bins ("
        + ", ".join(f"{r.label} {_r(r.quartiles[1])}" for r in ok)
        + f"; tau {tau:.1f})."
    ]
    below = [r.label for r in ok if r.quartiles[1][1] < tau]
    out.append(
        f"{name}: median below tau in "
        + (", ".join(below) if below else "no bin")
        + "; share >= tau "
        + ", ".join(f"{r.label} {_r(r.pos_at_tau, True)}" for r in ok)
        + "."
    )
    if drops and peak > 0:
        out.append(
            f"{name}: beyond the peak the score drops ({ok[peak].label} {med[peak]:.0f} -> "
            f"{ok[-1].label} {med[-1]:.0f})."
        )
    if with_negatives:
        neg = [r for r in rows if r.negatives >= min_positives]
        out.append(
            f"{name}: negatives >= tau "
            + ", ".join(f"{r.label} {_r(r.neg_at_tau, True)} of {r.negatives}" for r in neg)
            + "."
        )
    fs = [(r.label, r.max_f) for r in rows if r.max_f is not None]
    if fs:
        out.append(
            f"{name}: max-F thresholds "
            + ", ".join(f"{label} {'<=' if m.at_floor else ''}{m.threshold:.0f}" for label, m in fs)
            + "."
        )
    return out


def plot(path: Path, panels: dict[str, tuple[Evidence, Bins, list[BinRow]]], tau: float, title: str) -> None:
    """One panel per (data, binning): scores against the binned quantity, per-bin medians and max-F thresholds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.evaluation.calibration_core import save_figure

    rows_n = (len(panels) + 1) // 2
    fig, axes = plt.subplots(rows_n, 2, figsize=(11, 4.5 * rows_n), squeeze=False)
    for ax, (name, (ev, bins, rows)) in zip(axes.flat, panels.items()):
        size = bins.quantity == "share"
        x = getattr(ev, bins.quantity) * (100 if size else 1)
        pos = ev.positive | ev.glimpse if size else ev.positive
        # a frame without the goal has (almost) no goal size to draw; a different-instance pair has one
        neg = ev.negative & np.isfinite(x) & (x >= 100 * OUT_OF_VIEW_PX / FRAME_PX if size else True)
        y = np.where(ev.censored, 0.5, ev.score)  # gated frames drawn just above 0 on the symlog axis
        ax.scatter(x[neg], y[neg], s=3, alpha=0.15, c="tab:red", label="negatives")
        ax.scatter(x[pos & ~ev.censored], y[pos & ~ev.censored], s=4, alpha=0.4, c="tab:blue", label="positives")
        ax.scatter(x[pos & ev.censored], y[pos & ev.censored], s=8, marker="v", c="tab:cyan", label="positives, gated")
        lo_hi = np.clip(np.asarray(bins.edges) * (100 if size else 1), 0.04 if size else 0.0, 100 if size else 8.0)
        for r, lo, hi in zip(rows, lo_hi[:-1], lo_hi[1:]):
            if r.positives >= 5:
                ax.plot([lo, hi], [_mid(r.quartiles[1])] * 2, c="navy", lw=2)
            if r.max_f is not None:
                ax.plot([lo, hi], [r.max_f.threshold] * 2, c="darkorange", lw=2, ls="--")
        ax.plot([], [], c="navy", lw=2, label="median of positives (bins with 5+)")  # legend entries once
        ax.plot([], [], c="darkorange", lw=2, ls="--", label="max-F threshold per bin")
        ax.axhline(tau, color="k", ls=":", label=f"tau {tau:.1f}")
        ax.set(
            title=name,
            ylabel="score (sum of confidences)",
            xlabel="goal share of the image (%)" if size else "distance to the goal footprint (m)",
        )
        ax.set_yscale("symlog", linthresh=10)
        ax.set_ylim(0, 1.3 * max(float(ev.score.max(initial=0.0)), 2 * tau))
        if size:
            ax.set_xscale("log")
            ax.set_xticks([0.03, 0.1, 0.3, 1, 3, 10, 30, 100], ["0.03", "0.1", "0.3", "1", "3", "10", "30", "100"])
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    save_figure(fig, axes.flat[: len(panels)], title, path)
