"""The re-ID search setting's curve (issue 32): what fewer pixels and keypoints per frame cost in
re-identification and save in time, on train goal-image pairs.

    .venv/bin/python benchmarks/reid_search_curve.py --instances 30 --images-per-instance 6 \\
        --sides 640 480 320 --keypoints 1024 512 256 --max-negatives 1000 --threads 2 \\
        --out runs/search_curve

For each setting (longer side, keypoints) of the grid, the pairs of ``imgnav calibrate`` (every
same-instance pair of the train instances' goal images and a weighted sample of the
different-instance pairs; ``sim.evaluation.calibration_core``) are scored as the agent would score
a searching frame: image a as the goal at the full setting (the deployment's ``max_side_px`` and
``goal_max_keypoints``), image b as the frame at the setting. A setting's side is a side of the
agent's frames (360 x 640): the 512 x 512 calibration images are shrunk by the same factor
(``search_image_side``: 480 -> 384 pixels, 320 -> 256). Per setting:

* the maximal F of the Keypoint-Conf score (the deployment's), precision and recall at its tau,
  the area under the PR curve, and the difference in max F to the full setting with a 95% interval
  from resampling the instances (the pairs are the same in every setting: a paired comparison);
* the gate's two stages on these pairs alone (``gate_threshold_for`` at the setting's tau: the
  first stage's MNN count and the exit stage's score after LighterGlue's exit layer, with the
  share of pairs each lets through): goal-image pairs only, not the episode frames the deployed
  gate is also calibrated on, so a guide, not a calibration;
* medians per frame: the extraction, the first stage (normalising the frame's descriptors and
  counting), LighterGlue with every layer, and LighterGlue stopped after its exit layer; at each
  ``--threads`` (the scores come from the first).

Writes OUT/search_curve.json, a PR/F plot per setting (OUT/search_curve_<side>x<keypoints>.png)
and one with every setting's Keypoint-Conf curves (OUT/search_curve_pr.png), and prints the table.
Images are sampled as ``imgnav calibrate`` samples them and cached in ``--image-cache`` (default
OUT/images). Train only. Timings on a loaded machine are not final.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

log = logging.getLogger("reid_search_curve")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--instances", type=int, default=30)
    p.add_argument("--images-per-instance", type=int, default=6)
    p.add_argument("--scene-set", type=int, default=500, help="set seed of the train homes (as imgnav calibrate)")
    p.add_argument("--max-negatives", type=int, default=1000, help="different-instance pairs drawn (weighted back)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sides", type=int, nargs="+", default=[640, 480, 320], help="frame longer sides")
    p.add_argument("--keypoints", type=int, nargs="+", default=[1024, 512, 256], help="keypoints per frame")
    p.add_argument("--threads", type=int, nargs="+", default=[2], help="torch threads (scores at the first)")
    p.add_argument("--timing-pairs", type=int, default=100, help="pairs timed at the other thread counts and exiting")
    p.add_argument("--bootstrap", type=int, default=500, help="resamples of the instances for the max-F intervals")
    p.add_argument("--config", default="sim", help="the deployment whose re-ID is the full setting")
    p.add_argument("--out", default="runs/search_curve")
    p.add_argument("--image-cache", default=None, help="cached goal images (default OUT/images)")
    return p.parse_args(argv)


def median(xs) -> float:
    return float(statistics.median(xs)) if len(xs) else float("nan")


def instance_bootstrap(
    pairs: np.ndarray, label: np.ndarray, weight: np.ndarray, inst_idx: np.ndarray, n_inst: int, b: int, seed: int
):
    """Weights of ``b`` resamples of the instances (with replacement): a pair counts once per
    copy of its instances drawn (n_i for a same-instance pair, n_i x n_j otherwise)."""
    rng = np.random.default_rng(seed)
    ia, ib = inst_idx[pairs[:, 0]], inst_idx[pairs[:, 1]]
    for _ in range(b):
        n = np.bincount(rng.integers(0, n_inst, n_inst), minlength=n_inst).astype(np.float64)
        mult = np.where(label, n[ia], n[ia] * n[ib])
        yield weight * mult


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    # torch's OpenMP threads wait passively, as under `imgnav` (console/cli.py): beside other jobs
    # an actively waiting second thread made a match several times slower (set before torch loads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import torch
    from tqdm import tqdm

    from agent.config import load_agent_config
    from agent.reid.base import extract_at
    from agent.reid.gate import gate_threshold_for
    from agent.reid.identifier import make_matcher
    from sim.episodes import read_rgb
    from sim.evaluation.calibrate import load_or_sample_images
    from sim.evaluation.calibration_core import make_pairs, plot_curves, pr_curves, search_image_side
    from sim.evaluation.gate_calibration import score_pairs_both_stages

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(args.image_cache) if args.image_cache else out / "images"
    entries = load_or_sample_images(cache, args.instances, args.images_per_instance, args.scene_set)
    images = [read_rgb(cache / e["path"]) for e in entries]
    inst = [e["instance"] for e in entries]
    names = sorted(set(inst))
    inst_idx = np.array([names.index(i) for i in inst])
    ps = make_pairs(inst, args.max_negatives, args.seed)
    timing_idx = np.unique(np.linspace(0, len(ps.pairs) - 1, min(args.timing_pairs, len(ps.pairs))).astype(int))

    base = load_agent_config(args.config).reid
    if base.matcher != "xfeat_lighterglue":
        raise SystemExit(f"{base.matcher}: the curve measures XFeat + LighterGlue (its exit stage included)")
    threads = list(dict.fromkeys(args.threads))
    cfg = replace(base, num_threads=threads[0], gate=True)
    matcher = make_matcher(cfg)
    exit_layer = int(getattr(matcher, "exit_layer", 0))
    matcher.always_score_exit = True  # type: ignore[attr-defined]
    full = (cfg.max_side_px, cfg.obs_max_keypoints)
    grid = list(itertools.product(args.sides, args.keypoints))
    if full not in grid:
        grid.insert(0, full)
    grid.sort(key=lambda s: (-s[0], -s[1]))
    log.info(
        "%d images of %d instances, %d pairs (%d same); goal at %d px / %d keypoints; settings %s",
        len(images),
        len(names),
        len(ps.pairs),
        int(ps.label.sum()),
        cfg.max_side_px,
        cfg.goal_max_keypoints,
        grid,
    )
    goals = [extract_at(matcher, im, cfg.max_side_px, cfg.goal_max_keypoints) for im in tqdm(images, desc="goals")]

    def timed_extract(side: int, kp: int, imgs) -> tuple[list, list[float]]:
        feats, ms = [], []
        for im in imgs:
            s = search_image_side(max(im.shape[:2]), cfg.max_side_px, side)
            t0 = time.perf_counter()
            feats.append(extract_at(matcher, im, s, kp))
            ms.append((time.perf_counter() - t0) * 1e3)
        return feats, ms

    def timed_exit(frames) -> list[float]:
        """LighterGlue stopped after its exit layer (a bar no pair reaches): what a frame the exit
        stage stops costs."""
        ms = []
        matcher.always_score_exit = False  # type: ignore[attr-defined]
        for k in timing_idx:
            a, b = ps.pairs[k]
            t0 = time.perf_counter()
            matcher.match(goals[a], frames[b], exit_below=("conf", float("inf")))  # type: ignore[call-arg]
            ms.append((time.perf_counter() - t0) * 1e3)
        matcher.always_score_exit = True  # type: ignore[attr-defined]
        return ms

    rows = []
    curves_all = {}
    weights = list(
        instance_bootstrap(ps.pairs, ps.label, ps.weight, inst_idx, len(names), args.bootstrap, args.seed + 1)
    )
    ref_conf = None
    for side, kp in grid:
        label = f"{side}/{kp}"
        torch.set_num_threads(threads[0])
        frames, ext_ms = timed_extract(side, kp, tqdm(images, desc=f"{label} frames", leave=False))
        times: dict[str, list[float]] = {}
        conf, count, gate, exit_conf, _ = score_pairs_both_stages(
            matcher,
            cfg.gate_min_cosine,
            goals,
            ps.pairs,
            tqdm(range(len(ps.pairs)), desc=f"{label} pairs", leave=False),
            obs_feats=frames,
            times=times,
        )
        per_threads = {
            str(threads[0]): {
                "extract_ms": median(ext_ms),
                "gate_ms": median(times["gate_ms"]),
                "match_ms": median(times["match_ms"]),
                "exit_ms": median(timed_exit(frames)) if exit_layer else None,
            }
        }
        for t in threads[1:]:
            torch.set_num_threads(t)
            sub = [images[i] for i in sorted({int(b) for b in ps.pairs[timing_idx, 1]})]
            _, ext_t = timed_extract(side, kp, sub)
            tt: dict[str, list[float]] = {}
            score_pairs_both_stages(
                matcher, cfg.gate_min_cosine, goals, ps.pairs[timing_idx], obs_feats=frames, times=tt
            )
            per_threads[str(t)] = {
                "extract_ms": median(ext_t),
                "gate_ms": median(tt["gate_ms"]),
                "match_ms": median(tt["match_ms"]),
                "exit_ms": median(timed_exit(frames)) if exit_layer else None,
            }
        torch.set_num_threads(threads[0])
        c_conf, c_count = pr_curves(conf, ps.label, ps.weight), pr_curves(count, ps.label, ps.weight)
        curves_all[label] = c_conf
        plot_curves(
            str(out / f"search_curve_{side}x{kp}.png"),
            {"conf": c_conf, "count": c_count},
            f"frames at {side} px / {kp} keypoints (images at {search_image_side(512, cfg.max_side_px, side)} px), "
            f"goal at {cfg.max_side_px} / {cfg.goal_max_keypoints}: {len(names)} instances, {len(images)} images",
        )
        if ref_conf is None:
            ref_conf = conf  # the full setting comes first (the grid is sorted largest first)
        boot = np.array([pr_curves(conf, ps.label, w).max_f - pr_curves(ref_conf, ps.label, w).max_f for w in weights])
        tau = c_conf.tau
        gate_thr, gate_fig = gate_threshold_for(conf, gate, tau)
        row = {
            "max_side_px": side,
            "max_keypoints": kp,
            "image_side_px": search_image_side(512, cfg.max_side_px, side),
            "keypoints_median": median([len(f) for f in frames]),
            "tau": tau,
            "max_f": c_conf.max_f,
            "precision_at_tau": float(c_conf.precision[c_conf.best]),
            "recall_at_tau": float(c_conf.recall[c_conf.best]),
            "auc_pr": c_conf.auc_pr(),
            "max_f_count": c_count.max_f,
            "tau_count": c_count.tau,
            "delta_f_vs_full": c_conf.max_f - pr_curves(ref_conf, ps.label, ps.weight).max_f,
            "delta_f_ci95": [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))] if len(boot) else None,
            "pairs_gate_threshold": gate_thr,
            "pairs_gate_pass_share": gate_fig["pass_share"],
            "timings": per_threads,
        }
        if exit_layer:
            exit_thr, exit_fig = gate_threshold_for(conf, exit_conf, tau)
            row.update(pairs_exit_threshold=exit_thr, pairs_exit_pass_share=exit_fig["pass_share"])
        rows.append(row)
        log.info("%s: max F %.3f at tau %.4g; timings %s", label, c_conf.max_f, tau, per_threads)
    plot_curves(
        str(out / "search_curve_pr.png"),
        curves_all,
        f"Keypoint-Conf per frame setting (side/keypoints); goal at {cfg.max_side_px} / {cfg.goal_max_keypoints}",
    )
    result = {
        "instances": len(names),
        "images": len(images),
        "same_pairs": int(ps.label.sum()),
        "different_pairs_scored": int((~ps.label).sum()),
        "different_pairs_total": ps.n_negatives_total,
        "scene_set": args.scene_set,
        "seed": args.seed,
        "split": "train",
        "goal_max_side_px": cfg.max_side_px,
        "goal_max_keypoints": cfg.goal_max_keypoints,
        "exit_layer": exit_layer,
        "threads": threads,
        "bootstrap": args.bootstrap,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "settings": rows,
    }
    (out / "search_curve.json").write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))
    return 0


def table(result: dict) -> str:
    threads = [str(t) for t in result["threads"]]
    head = (
        "| side/kp (image px) | kp median | tau | max F | P | R | AUC-PR | dF vs full [95%] | gate / exit thr (pass) |"
    )
    head += "".join(f" ms @{t}t: extract / gate / match / exit |" for t in threads)
    lines = [
        f"{result['instances']} train instances x {result['images'] // max(result['instances'], 1)} images, "
        f"{result['same_pairs']} same / {result['different_pairs_scored']} of {result['different_pairs_total']} "
        f"different pairs; goal at {result['goal_max_side_px']} px / {result['goal_max_keypoints']} keypoints",
        head,
        "|" + " --- |" * (head.count("|") - 1),
    ]
    for r in result["settings"]:
        ci = r["delta_f_ci95"]
        cells = [
            f"{r['max_side_px']}/{r['max_keypoints']} ({r['image_side_px']})",
            f"{r['keypoints_median']:.0f}",
            f"{r['tau']:.4g}",
            f"{r['max_f']:.3f}",
            f"{r['precision_at_tau']:.3f}",
            f"{r['recall_at_tau']:.3f}",
            f"{r['auc_pr']:.3f}",
            f"{r['delta_f_vs_full']:+.3f}" + (f" [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else ""),
            f"{r['pairs_gate_threshold']:g} / {r.get('pairs_exit_threshold', float('nan')):.3g} "
            f"({r['pairs_gate_pass_share']:.0%} / {r.get('pairs_exit_pass_share', float('nan')):.0%})",
        ]
        for t in threads:
            m = r["timings"][t]
            ex = "-" if m["exit_ms"] is None else f"{m['exit_ms']:.1f}"
            cells.append(f"{m['extract_ms']:.1f} / {m['gate_ms']:.1f} / {m['match_ms']:.1f} / {ex}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
