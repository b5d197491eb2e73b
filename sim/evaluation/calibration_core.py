"""Re-ID threshold calibration, independent of where the images come from (Krantz et al. 2023, 3.2).

Given goal images labelled by instance, score every same-instance pair and a uniform
sample of the different-instance pairs with a matcher, build the precision-recall and
F-measure curves over the threshold, and pick the tau of maximal F.

Different-instance pairs outnumber same-instance pairs by ~100:1 (1000 images of 100
instances: 4,500 vs ~495,000). Matching all of them would take hours on 2 CPU cores, so at
most ``max_negatives`` are drawn uniformly (fixed seed) and each carries the weight
``all_negatives / drawn`` in the counts: the curves estimate those of *all* pairs, as in
the paper, not of a rebalanced set.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from agent.reid.base import Features, Matcher

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, eq=False)
class PairSet:
    """pairs: (P, 2) int64 image indices; label: (P,) bool same instance; weight: (P,) float64."""

    pairs: np.ndarray
    label: np.ndarray
    weight: np.ndarray
    n_negatives_total: int


def make_pairs(instance_of_image: Sequence[int | str], max_negatives: int, seed: int = 0) -> PairSet:
    inst = np.asarray(instance_of_image)
    n = len(inst)
    i, j = np.triu_indices(n, k=1)
    same = inst[i] == inst[j]
    pos = np.stack([i[same], j[same]], axis=1)
    neg_all = np.flatnonzero(~same)
    rng = np.random.default_rng(seed)
    if max_negatives > 0 and len(neg_all) > max_negatives:
        pick = np.sort(rng.choice(neg_all, size=max_negatives, replace=False))
    else:
        pick = neg_all
    neg = np.stack([i[pick], j[pick]], axis=1)
    w_neg = len(neg_all) / max(len(pick), 1)
    pairs = np.vstack([pos, neg]).astype(np.int64)
    label = np.concatenate([np.ones(len(pos), bool), np.zeros(len(neg), bool)])
    weight = np.concatenate([np.ones(len(pos)), np.full(len(neg), w_neg)])
    return PairSet(pairs, label, weight, int(len(neg_all)))


def score_pairs(
    matcher: Matcher,
    features: Sequence[Features],
    pairs: np.ndarray,
    progress: Iterable | None = None,
    features_obs: Sequence[Features] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(conf, count) per pair: the two score functions from one matching pass. A pair (a, b) is
    ``features[a]`` (the goal's role) against ``features_obs[b]`` (the frame's role; None: the
    same list, both images as they are)."""
    obs = features if features_obs is None else features_obs
    conf = np.zeros(len(pairs), np.float64)
    count = np.zeros(len(pairs), np.float64)
    it = progress if progress is not None else range(len(pairs))
    for k in it:
        a, b = pairs[k]
        m = matcher.match(features[a], obs[b])
        conf[k] = float(np.sum(m.confidence, dtype=np.float64))
        count[k] = float(len(m))
    return conf, count


@dataclass(frozen=True, slots=True, eq=False)
class Curves:
    """Operating points for ``score >= threshold``, thresholds descending. All (T,) float64."""

    threshold: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    f: np.ndarray

    @property
    def best(self) -> int:
        return int(np.argmax(self.f))

    @property
    def tau(self) -> float:
        return float(self.threshold[self.best])

    @property
    def max_f(self) -> float:
        return float(self.f[self.best])

    def auc_pr(self) -> float:
        """Area under the precision-recall curve (step interpolation)."""
        r = np.concatenate([[0.0], self.recall])
        return float(np.sum(np.diff(r) * self.precision))


def pr_curves(scores: np.ndarray, label: np.ndarray, weight: np.ndarray | None = None) -> Curves:
    s = np.asarray(scores, np.float64)
    y = np.asarray(label, bool)
    w = np.ones(len(s)) if weight is None else np.asarray(weight, np.float64)
    order = np.argsort(-s, kind="stable")
    s, y, w = s[order], y[order], w[order]
    tp = np.cumsum(np.where(y, w, 0.0))
    fp = np.cumsum(np.where(y, 0.0, w))
    last = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]  # the last index of each tied score
    tp, fp, thr = tp[last], fp[last], s[last]
    p_total = max(float(np.sum(w[y])), 1e-12)
    precision = tp / np.maximum(tp + fp, 1e-12)
    recall = tp / p_total
    f = np.where(precision + recall > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-12), 0.0)
    return Curves(thr, precision, recall, f)


@dataclass(frozen=True, slots=True)
class OperatingPoint:
    """Precision, recall and F of ``score >= tau`` (weighted as the curves are)."""

    tau: float
    precision: float
    recall: float
    f: float


def operating_point(scores: np.ndarray, label: np.ndarray, weight: np.ndarray | None, tau: float) -> OperatingPoint:
    """The figures at a given threshold (e.g. the agent's tau, on pairs it was not chosen on)."""
    s = np.asarray(scores, np.float64)
    y = np.asarray(label, bool)
    w = np.ones(len(s)) if weight is None else np.asarray(weight, np.float64)
    hit = s >= tau
    tp = float(np.sum(w[hit & y]))
    fp = float(np.sum(w[hit & ~y]))
    precision = tp / (tp + fp) if tp + fp > 0 else 0.0
    recall = tp / max(float(np.sum(w[y])), 1e-12)
    f = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return OperatingPoint(float(tau), precision, recall, f)


def plot_curves(
    path: str, curves: dict[str, Curves], title: str, marks: dict[str, OperatingPoint] | None = None
) -> None:
    """PR curves and F over the threshold, one line per label, as a PNG. ``marks``: per label, an
    operating point drawn on its curves (a cross, a dashed line at its tau)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for name, c in curves.items():
        ax1.plot(c.recall, c.precision, label=f"{name} (max F {c.max_f:.3f})")
        ax1.plot(c.recall[c.best], c.precision[c.best], "o", color=ax1.lines[-1].get_color())
        ax2.plot(c.threshold, c.f, label=f"{name}: tau {c.tau:.3g}")
        ax2.axvline(c.tau, color=ax2.lines[-1].get_color(), ls=":")
        mark = (marks or {}).get(name)
        if mark is not None:
            color = ax2.lines[-1].get_color()
            ax1.plot(mark.recall, mark.precision, "x", ms=9, color=color, label=f"{name} at tau {mark.tau:.3g}")
            ax2.axvline(mark.tau, color=color, ls="--", label=f"{name}: F {mark.f:.3f} at tau {mark.tau:.3g}")
    ax1.set(xlabel="recall", ylabel="precision", xlim=(0, 1), ylim=(0, 1.02), title="precision-recall")
    ax2.set(xlabel="threshold tau (score >= tau)", ylabel="F-measure", ylim=(0, 1.02), title="F-measure")
    ax2.set_xscale("symlog", linthresh=1.0)
    ax2.set_xlim(left=0.0)
    save_figure(fig, (ax1, ax2), title, path)


def save_figure(fig, axes, title: str, path) -> None:
    """The calibration plots' common finish: grid and legend on each axis, title, PNG, closed."""
    import matplotlib.pyplot as plt

    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
