"""Tau on phone-like goal photos against tau on clean goal images: what changes for the agent (issue 30).

Reads the pair scores of two ``imgnav calibrate`` runs on the same images and pairs, one clean and
one under a realism profile (``<matcher>_scores.npz`` and ``<matcher>_<profile>_scores.npz`` in
``--out``), and prints per score:

* each run's own figures (tau at max F, max F, precision, recall, AUC-PR), and both at the tau the
  agent uses today (``--agent-tau``, default the packaged calibration file);
* the same with the different-instance pairs weighted to another ratio of different to same pairs
  (``--negative-ratio``; default 110, the 100-instance protocol's 495,000 / 4,500): with 50
  instances there are 54 different pairs per same pair, half the protocol's, so precision at a
  given tau is higher and the max-F tau lower than the protocol's;
* the held-out gain of choosing tau on the profile's pairs: over ``--splits`` random halvings of
  the instances, tau at max F on one half's pairs (within-half pairs only, weighted to the ratio),
  F on the other half at that tau and at the agent's tau; the mean gain and its 5th-95th percentiles;
* with ``--at TAU ...``: both runs' figures at those thresholds of the first score (``conf``).

The instances are read from the pairs themselves (every same-instance pair is scored, so the
instances are the groups the same pairs join): the scores files alone are enough.

    python benchmarks/calibration_phone.py --out docs/results/i30_realism/calibration_phone --at 75.3 61
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.reid.identifier import calibration_path  # noqa: E402
from sim.evaluation.calibration_core import operating_point, pr_curves  # noqa: E402


def instances_of_images(pairs: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(N,) instance index per image: the groups that the same-instance pairs join."""
    parent = list(range(int(pairs.max()) + 1))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in pairs[label]:
        parent[root(int(a))] = root(int(b))
    roots = np.array([root(i) for i in range(len(parent))])
    return np.unique(roots, return_inverse=True)[1]


def reweighted(label: np.ndarray, weight: np.ndarray, ratio: float) -> np.ndarray:
    """Weights with the different pairs scaled so that their total is ``ratio`` times the same pairs'."""
    w = np.asarray(weight, np.float64).copy()
    neg = ~label
    if neg.any() and label.any():
        w[neg] *= ratio * w[label].sum() / w[neg].sum()
    return w


def figures(scores: np.ndarray, label: np.ndarray, weight: np.ndarray, agent_tau: float) -> dict[str, float]:
    c = pr_curves(scores, label, weight)
    at = operating_point(scores, label, weight, agent_tau)
    return {
        "tau": c.tau,
        "max_f": c.max_f,
        "precision": float(c.precision[c.best]),
        "recall": float(c.recall[c.best]),
        "auc_pr": c.auc_pr(),
        "precision_at_agent_tau": at.precision,
        "recall_at_agent_tau": at.recall,
        "f_at_agent_tau": at.f,
    }


def heldout_gain(
    scores: np.ndarray,
    label: np.ndarray,
    pair_instances: np.ndarray,
    n_instances: int,
    agent_tau: float,
    ratio: float,
    splits: int,
    seed: int,
) -> dict[str, float]:
    """F at a tau chosen on the other half of the instances minus F at the agent's tau."""
    rng = np.random.default_rng(seed)
    gains, taus = [], []
    for _ in range(splits):
        half = np.zeros(n_instances, bool)
        half[rng.permutation(n_instances)[: n_instances // 2]] = True
        side = half[pair_instances]  # (P, 2): each image's instance in the first half
        for fit, test in ((side.all(axis=1), (~side).all(axis=1)), ((~side).all(axis=1), side.all(axis=1))):
            w_fit = reweighted(label[fit], np.ones(int(fit.sum())), ratio)
            tau = pr_curves(scores[fit], label[fit], w_fit).tau
            w_test = reweighted(label[test], np.ones(int(test.sum())), ratio)
            f_chosen = operating_point(scores[test], label[test], w_test, tau).f
            f_agent = operating_point(scores[test], label[test], w_test, agent_tau).f
            gains.append(f_chosen - f_agent)
            taus.append(tau)
    g = np.asarray(gains)
    return {
        "gain_mean": float(g.mean()),
        "gain_p05": float(np.percentile(g, 5)),
        "gain_p95": float(np.percentile(g, 95)),
        "tau_median": float(np.median(taus)),
        "tau_p05": float(np.percentile(taus, 5)),
        "tau_p95": float(np.percentile(taus, 95)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="the --out of both calibrate runs")
    ap.add_argument("--matcher", default="xfeat_lighterglue")
    ap.add_argument("--profile", default="stretch")
    ap.add_argument("--agent-tau", type=float, nargs=2, default=None, metavar=("CONF", "COUNT"))
    ap.add_argument("--negative-ratio", type=float, default=495000 / 4500)
    ap.add_argument("--splits", type=int, default=200)
    ap.add_argument("--at", type=float, nargs="*", default=[], metavar="TAU", help="more thresholds of conf")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args()

    out = Path(args.out)
    runs = {
        "clean": np.load(out / f"{args.matcher}_scores.npz"),
        args.profile: np.load(out / f"{args.matcher}_{args.profile}_scores.npz"),
    }
    clean, prof = runs["clean"], runs[args.profile]
    for key in ("pairs", "label", "weight"):
        if not np.array_equal(clean[key], prof[key]):
            raise SystemExit(f"the two runs' {key} differ: not the same images and pairs")
    pairs, label, weight = clean["pairs"], clean["label"].astype(bool), clean["weight"]
    inst = instances_of_images(pairs, label)
    if not np.array_equal(inst[pairs[:, 0]] == inst[pairs[:, 1]], label):
        raise SystemExit("the same-instance pairs do not form whole instances (not all same pairs scored?)")
    n_instances = int(inst.max()) + 1
    pair_instances = inst[pairs]

    result: dict = {"instances": n_instances, "negative_ratio": args.negative_ratio, "splits": args.splits}
    for kind_i, kind in enumerate(("conf", "count")):
        if args.agent_tau is not None:
            agent_tau = args.agent_tau[kind_i]
        else:
            agent_tau = float(json.loads(calibration_path(args.matcher, kind).read_text())["tau"])
        per: dict = {"agent_tau": agent_tau}
        for name, run in runs.items():
            s = run[kind]
            per[name] = {
                "as_run": figures(s, label, weight, agent_tau),
                "reweighted": figures(s, label, reweighted(label, weight, args.negative_ratio), agent_tau),
                "heldout": heldout_gain(
                    s, label, pair_instances, n_instances, agent_tau, args.negative_ratio, args.splits, args.seed
                ),
            }
        result[kind] = per
        print(f"\n{kind} (agent's tau {agent_tau:.4g})")
        print("| run | weighting | tau | max F | P | R | AUC-PR | P at agent's tau | R there | F there |")
        print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for name in runs:
            for w in ("as_run", "reweighted"):
                f = per[name][w]
                label_w = "as run" if w == "as_run" else f"different pairs x{args.negative_ratio:.0f}"
                print(
                    f"| {name} | {label_w} | {f['tau']:.4g} | {f['max_f']:.3f} | {f['precision']:.3f} | "
                    f"{f['recall']:.3f} | {f['auc_pr']:.3f} | {f['precision_at_agent_tau']:.3f} | "
                    f"{f['recall_at_agent_tau']:.3f} | {f['f_at_agent_tau']:.3f} |"
                )
        for name in runs:
            h = per[name]["heldout"]
            print(
                f"held out, {name}: F gain of a tau chosen on the other half {h['gain_mean']:+.3f} "
                f"[{h['gain_p05']:+.3f}, {h['gain_p95']:+.3f}]; that tau median {h['tau_median']:.4g} "
                f"[{h['tau_p05']:.4g}, {h['tau_p95']:.4g}]"
            )
        if kind == "conf" and args.at:
            per["at"] = {}
            print("| run | weighting | tau | P | R | F |\n| --- | --- | ---: | ---: | ---: | ---: |")
            for name, run in runs.items():
                for w_name, w in (("as run", weight), ("reweighted", reweighted(label, weight, args.negative_ratio))):
                    for tau in args.at:
                        p = operating_point(run[kind], label, w, tau)
                        per["at"][f"{name} {w_name} {tau:g}"] = {"precision": p.precision, "recall": p.recall, "f": p.f}
                        print(f"| {name} | {w_name} | {tau:g} | {p.precision:.3f} | {p.recall:.3f} | {p.f:.3f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
