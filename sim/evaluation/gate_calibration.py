"""``imgnav calibrate --gate``: the re-ID gate's threshold (agent/reid/gate.py).

The gate skips the full matcher on frames whose mutual-nearest-neighbour count is below a
threshold. It must not change the agent's decisions, so the threshold is the largest one that
drops at most ``--gate-max-drop`` (1%) of the frames the full matcher scores at or above tau,
measured on two kinds of train data:

1. goal-image pairs of train instances (the same images as tau's calibration: every
   same-instance pair and a sample of different-instance pairs), scored by both stages;
2. egocentric frames recorded by the agent on train episodes (``imgnav eval --agent modiin
   --modiin-set reid.gate=false --modiin-set reid.gate_shadow=true``: the full score and the
   gate score of every step, in each record's ``modiin.trace``), passed with ``--gate-records``.

The threshold is the smaller of the two sources' (each must keep its own drop within the
bound). It is written beside tau into ``agent/calibration/<matcher>_<score>.json`` for both score
kinds (``gate_threshold``, ``gate_min_cosine`` and the figures behind it), with a scatter plot of
gate score against full score (``<matcher>_gate.png``).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--gate", action="store_true",
                        help="calibrate the re-ID gate's threshold (needs tau calibrated; see --gate-records)")
    parser.add_argument("--gate-records", nargs="*", default=[],
                        help="episodes.jsonl of train evaluations run with reid.gate_shadow=true")
    parser.add_argument("--gate-max-drop", type=float, default=0.01,
                        help="largest share of frames with full score >= tau that the gate may drop")
    parser.add_argument("--gate-negatives", type=int, default=2000,
                        help="different-instance goal-image pairs scored for the gate's pass rate")


def frames_from_records(paths: list[str], exclude_val: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """(full scores, gate scores, episodes) of every recorded step with both scores."""
    full, gate, episodes = [], [], 0
    for p in paths:
        for line in Path(p).read_text().splitlines():
            if not line.strip():
                continue
            rec = json.loads(line)
            split = str(rec.get("episode_id", "")).split("-", 1)[0]
            if exclude_val and split in ("val", "test"):
                raise ValueError(f"{p}: episode {rec.get('episode_id')} is from the {split} split; "
                                 "the gate is calibrated on train only")
            trace = (rec.get("modiin") or {}).get("trace") or {}
            fs, gs = trace.get("reid_score") or [], trace.get("gate_score") or []
            if not gs or all(g is None for g in gs):
                continue
            episodes += 1
            for f, g in zip(fs, gs):
                if f is not None and g is not None:
                    full.append(float(f))
                    gate.append(float(g))
    return np.asarray(full, np.float64), np.asarray(gate, np.float64), episodes


def score_pairs_both_stages(matcher, gate_min_cosine: float, feats, pairs: np.ndarray, progress=None):
    """(conf, count, gate) per pair: the full matcher's two scores and the gate's MNN count."""
    from agent.reid.gate import mnn_count, normalise_rows

    desc = [normalise_rows(f.descriptors) for f in feats]
    conf = np.zeros(len(pairs))
    count = np.zeros(len(pairs))
    gate = np.zeros(len(pairs))
    for k in (progress if progress is not None else range(len(pairs))):
        a, b = pairs[k]
        m = matcher.match(feats[a], feats[b])
        conf[k] = float(np.sum(m.confidence, dtype=np.float64))
        count[k] = float(len(m))
        gate[k] = mnn_count(desc[b] @ desc[a].T, gate_min_cosine)
    return conf, count, gate


def plot_gate(path: Path, sources: dict[str, tuple[np.ndarray, np.ndarray]], tau: float, threshold: float,
              title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.evaluation.calibration_core import save_figure

    fig, axes = plt.subplots(1, len(sources), figsize=(5.5 * len(sources), 4.5), squeeze=False)
    for ax, (name, (full, gate)) in zip(axes[0], sources.items()):
        pos = full >= tau
        ax.scatter(gate[~pos], full[~pos], s=4, alpha=0.3, label=f"full < tau ({int((~pos).sum())})")
        ax.scatter(gate[pos], full[pos], s=6, alpha=0.6, label=f"full >= tau ({int(pos.sum())})")
        ax.axhline(tau, color="k", ls=":", label=f"tau {tau:.3g}")
        ax.axvline(threshold, color="r", ls="--", label=f"gate threshold {threshold:g}")
        dropped = float(np.mean(gate[pos] < threshold)) if pos.any() else float("nan")
        passed = float(np.mean(gate >= threshold)) if len(gate) else float("nan")
        ax.set(xlabel="gate score (mutual nearest neighbours)", ylabel="full score (sum of confidences)",
               title=f"{name}\ndrops {dropped:.1%} of >= tau; full matcher on {passed:.1%}")
        ax.set_xscale("symlog", linthresh=10)
        ax.set_yscale("symlog", linthresh=10)
    save_figure(fig, axes[0], title, path)


def calibrate_gate(entries: list[dict], cache: Path, out: Path, args: argparse.Namespace) -> dict:
    from tqdm import tqdm

    from agent.config import load_agent_config
    from agent.reid.gate import gate_threshold_for
    from agent.reid.identifier import calibration_path, make_matcher, resolve_tau
    from sim.episodes import read_rgb
    from sim.evaluation.calibration_core import make_pairs

    base = load_agent_config(args.config).reid
    result: dict = {}
    for matcher_name in args.matcher:
        cfg = replace(base, matcher=matcher_name, num_threads=args.threads, tau=None,
                      early_stop=base.early_stop if matcher_name == "xfeat_lighterglue" else -1.0)
        taus = {kind: resolve_tau(replace(cfg, score=kind)) for kind in ("conf", "count")}
        matcher = make_matcher(cfg)
        ps = make_pairs([e["instance"] for e in entries], args.gate_negatives, args.seed)
        scores_path = out / f"{matcher_name}_gate_pairs.npz"
        key = np.asarray([e["path"] for e in entries])
        cached = np.load(scores_path) if scores_path.is_file() else None
        if (cached is not None and np.array_equal(cached["pairs"], ps.pairs) and np.array_equal(cached["images"], key)
                and float(cached["min_cosine"]) == cfg.gate_min_cosine
                and (float(cached["early_stop"]) if "early_stop" in cached.files else -1.0) == cfg.early_stop):
            # the same images and pairs were scored by an earlier run (e.g. before more records came)
            conf, count, gate, ms_pair = cached["conf"], cached["count"], cached["gate"], float(cached["ms_pair"])
            log.info("pair scores reused from %s", scores_path)
        else:
            feats = [matcher.extract(read_rgb(cache / e["path"]), cfg.goal_max_keypoints)
                     for e in tqdm(entries, desc=f"{matcher_name} features", unit="img")]
            t0 = time.perf_counter()
            conf, count, gate = score_pairs_both_stages(
                matcher, cfg.gate_min_cosine, feats, ps.pairs,
                tqdm(range(len(ps.pairs)), desc=f"{matcher_name} pairs (both stages)", unit="pair"))
            ms_pair = 1000 * (time.perf_counter() - t0) / max(len(ps.pairs), 1)
            np.savez_compressed(scores_path, pairs=ps.pairs, label=ps.label, images=key, conf=conf, count=count,
                                gate=gate, min_cosine=cfg.gate_min_cosine, ms_pair=ms_pair,
                                early_stop=cfg.early_stop)
        ego_full, ego_gate, ego_eps = frames_from_records(args.gate_records)
        per_kind = {}
        for kind, full_pairs in (("conf", conf), ("count", count)):
            tau = taus[kind]
            sources = {"goal-image pairs": (full_pairs, gate)}
            if kind == cfg.score and len(ego_full) and np.any(ego_full >= tau):
                sources["train-episode frames"] = (ego_full, ego_gate)  # recorded with the deployment's score
            figures = {}
            for name, (f, g) in sources.items():
                thr, stats = gate_threshold_for(f, g, tau, args.gate_max_drop)
                figures[name] = {"threshold": thr, **stats}
            threshold = min(v["threshold"] for v in figures.values())
            for name, (f, g) in sources.items():  # each source's figures at the chosen threshold
                pos = f >= tau
                figures[name].update(dropped_share_at_threshold=float(np.mean(g[pos] < threshold)),
                                     pass_share_at_threshold=float(np.mean(g >= threshold)))
            if "train-episode frames" in figures:
                figures["train-episode frames"]["episodes"] = ego_eps
            plot_gate(out / f"{matcher_name}_{kind}_gate.png", sources, tau, threshold,
                      f"{matcher_name}/{kind}: gate threshold {threshold:g} (MNN cosine >= {cfg.gate_min_cosine})")
            path = calibration_path(matcher_name, kind, cfg.early_stop)
            data = json.loads(path.read_text())
            data.update(gate_threshold=threshold, gate_min_cosine=cfg.gate_min_cosine,
                        gate_max_drop=args.gate_max_drop, gate_sources=figures,
                        gate_pairs=int(len(ps.pairs)), gate_ms_per_pair_both_stages=ms_pair,
                        gate_created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
            (out / f"{matcher_name}_{kind}_gate.json").write_text(json.dumps(data, indent=1) + "\n")
            if not args.no_write_agent:
                path.write_text(json.dumps(data, indent=1) + "\n")
                import shutil

                shutil.copyfile(out / f"{matcher_name}_{kind}_gate.png", path.with_name(f"{matcher_name}_{kind}_gate.png"))
            log.info("%s/%s gate: threshold %g (tau %.4g); %s", matcher_name, kind, threshold, tau,
                     "; ".join(f"{n}: drops {v['dropped_share_at_threshold']:.2%} of {int(v['positives'])} "
                               f">= tau, full matcher on {v['pass_share_at_threshold']:.1%} of {int(v['frames'])}"
                               for n, v in figures.items()))
            per_kind[kind] = {"threshold": threshold, "sources": figures}
        result[matcher_name] = per_kind
    (out / "gate_summary.json").write_text(json.dumps(result, indent=1) + "\n")
    return result
