"""``imgnav calibrate --gate``: the re-ID gate's threshold (agent/reid/gate.py).

The gate skips the full matcher on frames whose mutual-nearest-neighbour count is below a
threshold. It must not change the agent's decisions, so the threshold is the largest one that
drops at most ``--gate-max-drop`` (1%) of the frames the full matcher scores at or above tau,
measured on two kinds of train data:

1. goal-image pairs of train instances (the same images as tau's calibration: every
   same-instance pair and a sample of different-instance pairs), scored by both stages;
2. egocentric frames recorded by the agent on train episodes, either as scores (``imgnav eval
   --agent modiin --modiin-set reid.gate=false --modiin-set reid.gate_shadow=true``: the full
   score and the gate score of every step, in each record's ``modiin.trace``), passed with
   ``--gate-records``; or as features (``python -m sim.evaluation.gate_frames``: every frame's
   keypoints and descriptors), passed with ``--gate-frames``, which are scored here by both stages
   with the settings being calibrated (so a change of the matcher's settings, such as its early
   stop, needs no new episodes).

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
    parser.add_argument(
        "--gate",
        action="store_true",
        help="calibrate the re-ID gate's threshold (needs tau calibrated; see --gate-records)",
    )
    parser.add_argument(
        "--gate-records",
        nargs="*",
        default=[],
        help="episodes.jsonl of train evaluations run with reid.gate_shadow=true",
    )
    parser.add_argument(
        "--gate-frames",
        nargs="*",
        default=[],
        help="directories of train frames recorded by `python -m sim.evaluation.gate_frames`",
    )
    parser.add_argument(
        "--gate-max-drop",
        type=float,
        default=0.01,
        help="largest share of frames with full score >= tau that the gate may drop",
    )
    parser.add_argument(
        "--gate-negatives",
        type=int,
        default=2000,
        help="different-instance goal-image pairs scored for the gate's pass rate",
    )


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
                raise ValueError(
                    f"{p}: episode {rec.get('episode_id')} is from the {split} split; "
                    "the gate is calibrated on train only"
                )
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


def frames_from_recordings(
    dirs: list[str], matcher, gate_min_cosine: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(full scores, gate scores, exit scores, episodes) of every frame of ``gate_frames``
    recordings, all scored here from the recorded features: the full matcher's sum of confidences
    (``matcher`` with the settings being calibrated), the first stage's mutual-nearest-neighbour
    count and the exit stage's sum of confidences after the matcher's ``exit_layer`` (NaN when it
    has none)."""
    import torch

    from agent.reid.base import Features
    from agent.reid.gate import mnn_count, normalise_rows

    full, gate, exit_conf, episodes = [], [], [], 0
    for d in dirs:
        for path in sorted(Path(d).glob("*.npz")):
            if path.name.split("-", 1)[0] in ("val", "test"):
                raise ValueError(
                    f"{path}: recorded on the {path.name.split('-', 1)[0]} split; the gate is calibrated on train only"
                )
            z = dict(np.load(path))
            episodes += 1
            gk = torch.from_numpy(z["goal_kp"])
            gw, gh = (int(v) for v in z["goal_size_wh"])
            gsize = (gw, gh)
            goal = Features(
                gk.numpy(),
                torch.from_numpy(z["goal_desc"].astype(np.float32)),
                gsize,
                {"kp_resized": gk, "size_resized_wh": gsize},
            )
            goal_t = normalise_rows(goal.descriptors).T
            w, h = (int(v) for v in z["size_wh"])
            size = (w, h)
            for i, n in enumerate(z["n_kp"]):
                kp = torch.from_numpy(z["kp"][i, :n])
                obs = Features(
                    kp.numpy(),
                    torch.from_numpy(z["desc"][i, :n].astype(np.float32)),
                    size,
                    {"kp_resized": kp, "size_resized_wh": size},
                )
                full.append(float(np.sum(matcher.match(goal, obs).confidence, dtype=np.float64)))
                exit_conf.append(exit_scores_of(matcher, goal, obs)[0])
                gate.append(float(mnn_count(normalise_rows(obs.descriptors) @ goal_t, gate_min_cosine)))
    return np.asarray(full, np.float64), np.asarray(gate, np.float64), np.asarray(exit_conf, np.float64), episodes


def exit_scores_of(matcher, goal, obs) -> tuple[float, float]:
    """The exit stage's (conf, count) scores of a pair at the matcher's settings (its exit layer,
    on its exit keypoints); NaN when the matcher has no exit layer, 0 when a side has no keypoints."""
    if not getattr(matcher, "exit_layer", 0):
        return float("nan"), float("nan")
    scores = matcher.exit_stage(goal, obs)
    return (0.0, 0.0) if scores is None else (float(scores["conf"]), float(scores["count"]))


def score_pairs_both_stages(matcher, gate_min_cosine: float, feats, pairs: np.ndarray, progress=None):
    """(conf, count, gate, exit_conf, exit_count) per pair: the full matcher's two scores, the
    gate's MNN count, and the exit stage's two scores (NaN without an exit layer)."""
    from agent.reid.gate import mnn_count, normalise_rows

    desc = [normalise_rows(f.descriptors) for f in feats]
    conf, count, gate = np.zeros(len(pairs)), np.zeros(len(pairs)), np.zeros(len(pairs))
    exit_conf, exit_count = np.full(len(pairs), np.nan), np.full(len(pairs), np.nan)
    for k in progress if progress is not None else range(len(pairs)):
        a, b = pairs[k]
        m = matcher.match(feats[a], feats[b])
        conf[k] = float(np.sum(m.confidence, dtype=np.float64))
        count[k] = float(len(m))
        exit_conf[k], exit_count[k] = exit_scores_of(matcher, feats[a], feats[b])
        gate[k] = mnn_count(desc[b] @ desc[a].T, gate_min_cosine)
    return conf, count, gate, exit_conf, exit_count


def plot_gate(
    path: Path,
    sources: dict[str, tuple[np.ndarray, np.ndarray]],
    tau: float,
    threshold: float,
    title: str,
    xlabel: str = "gate score (mutual nearest neighbours)",
) -> None:
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
        ax.set(
            xlabel=xlabel,
            ylabel="full score (sum of confidences)",
            title=f"{name}\ndrops {dropped:.1%} of >= tau; full matcher on {passed:.1%}",
        )
        ax.set_xscale("symlog", linthresh=10)
        ax.set_yscale("symlog", linthresh=10)
    save_figure(fig, axes[0], title, path)


def _stage_threshold(
    sources: dict[str, tuple[np.ndarray, np.ndarray]], tau: float, max_drop: float
) -> tuple[float, dict[str, dict]]:
    """One stage's threshold: the smallest of its sources' (each keeps its own drop within the
    bound), with each source's figures, also at the chosen threshold."""
    from agent.reid.gate import gate_threshold_for

    figures = {}
    for name, (f, g) in sources.items():
        thr, stats = gate_threshold_for(f, g, tau, max_drop)
        figures[name] = {"threshold": thr, **stats}
    threshold = min(v["threshold"] for v in figures.values())
    for name, (f, g) in sources.items():
        pos = f >= tau
        figures[name].update(
            dropped_share_at_threshold=float(np.mean(g[pos] < threshold)),
            pass_share_at_threshold=float(np.mean(g >= threshold)),
        )
    return threshold, figures


def calibrate_gate(entries: list[dict], cache: Path, out: Path, args: argparse.Namespace) -> dict:
    """Both stages of the gate for every score kind: the first stage's MNN-count threshold and,
    when the deployment's matcher has an exit layer, the exit stage's threshold on LighterGlue's
    score after that layer; written beside tau (unless ``--no-write-agent``)."""
    from tqdm import tqdm

    from agent.config import load_agent_config
    from agent.reid.identifier import calibration_path, make_matcher, resolve_tau
    from sim.episodes import read_rgb
    from sim.evaluation.calibration_core import make_pairs

    base = load_agent_config(args.config).reid
    result: dict = {}
    for matcher_name in args.matcher:
        cfg = replace(
            base,
            matcher=matcher_name,
            num_threads=args.threads,
            tau=None,
            gate=True,
            gate_exit_layer=base.gate_exit_layer if matcher_name == "xfeat_lighterglue" else 0,
        )
        taus = {kind: resolve_tau(replace(cfg, score=kind)) for kind in ("conf", "count")}
        matcher = make_matcher(cfg)
        exit_layer = int(getattr(matcher, "exit_layer", 0))
        exit_keypoints = int(getattr(matcher, "exit_keypoints", 0))
        ps = make_pairs([e["instance"] for e in entries], args.gate_negatives, args.seed)
        scores_path = out / f"{matcher_name}_gate_pairs.npz"
        key = np.asarray([e["path"] for e in entries])
        cached = np.load(scores_path) if scores_path.is_file() else None
        if (
            cached is not None
            and np.array_equal(cached["pairs"], ps.pairs)
            and np.array_equal(cached["images"], key)
            and float(cached["min_cosine"]) == cfg.gate_min_cosine
            and (float(cached["early_stop"]) if "early_stop" in cached.files else -1.0) == -1.0
            and (int(cached["exit_layer"]) if "exit_layer" in cached.files else 0) == exit_layer
            and (int(cached["exit_keypoints"]) if "exit_keypoints" in cached.files else 0) == exit_keypoints
        ):
            # the same images and pairs were scored by an earlier run (e.g. before more records came)
            conf, count, gate, ms_pair = cached["conf"], cached["count"], cached["gate"], float(cached["ms_pair"])
            exit_conf, exit_count = cached["exit_conf"], cached["exit_count"]
            log.info("pair scores reused from %s", scores_path)
        else:
            feats = [
                matcher.extract(read_rgb(cache / e["path"]), cfg.goal_max_keypoints)
                for e in tqdm(entries, desc=f"{matcher_name} features", unit="img")
            ]
            t0 = time.perf_counter()
            conf, count, gate, exit_conf, exit_count = score_pairs_both_stages(
                matcher,
                cfg.gate_min_cosine,
                feats,
                ps.pairs,
                tqdm(range(len(ps.pairs)), desc=f"{matcher_name} pairs (both stages)", unit="pair"),
            )
            ms_pair = 1000 * (time.perf_counter() - t0) / max(len(ps.pairs), 1)
            np.savez_compressed(
                scores_path,
                pairs=ps.pairs,
                label=ps.label,
                images=key,
                conf=conf,
                count=count,
                gate=gate,
                exit_conf=exit_conf,
                exit_count=exit_count,
                exit_layer=exit_layer,
                exit_keypoints=exit_keypoints,
                min_cosine=cfg.gate_min_cosine,
                ms_pair=ms_pair,
            )
        ego_full, ego_gate, ego_eps = frames_from_records(args.gate_records)
        ego_exit = np.full(len(ego_full), np.nan)  # score records carry no exit-stage scores
        if getattr(args, "gate_frames", None):
            f_full, f_gate, f_exit, f_eps = frames_from_recordings(args.gate_frames, matcher, cfg.gate_min_cosine)
            ego_full, ego_gate = np.concatenate([ego_full, f_full]), np.concatenate([ego_gate, f_gate])
            ego_exit = np.concatenate([ego_exit, f_exit])
            ego_eps += f_eps
        per_kind = {}
        for kind, full_pairs, exit_pairs in (("conf", conf, exit_conf), ("count", count, exit_count)):
            tau = taus[kind]
            ego = (
                kind == cfg.score and len(ego_full) and np.any(ego_full >= tau)
            )  # recorded with the deployment's score
            sources = {"goal-image pairs": (full_pairs, gate)}
            if ego:
                sources["train-episode frames"] = (ego_full, ego_gate)
            threshold, figures = _stage_threshold(sources, tau, args.gate_max_drop)
            if "train-episode frames" in figures:
                figures["train-episode frames"]["episodes"] = ego_eps
            plot_gate(
                out / f"{matcher_name}_{kind}_gate.png",
                sources,
                tau,
                threshold,
                f"{matcher_name}/{kind}: gate threshold {threshold:g} (MNN cosine >= {cfg.gate_min_cosine})",
            )
            update = dict(
                gate_threshold=threshold,
                gate_min_cosine=cfg.gate_min_cosine,
                gate_max_drop=args.gate_max_drop,
                gate_sources=figures,
                gate_pairs=int(len(ps.pairs)),
                gate_ms_per_pair_both_stages=ms_pair,
                gate_created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            )
            exit_threshold = None
            if exit_layer:
                exit_sources = {"goal-image pairs": (full_pairs, exit_pairs)}
                if ego and np.any(np.isfinite(ego_exit) & (ego_full >= tau)):
                    ok = np.isfinite(ego_exit)
                    exit_sources["train-episode frames"] = (ego_full[ok], ego_exit[ok])
                exit_threshold, exit_figures = _stage_threshold(exit_sources, tau, args.gate_max_drop)
                for name, (f, e) in exit_sources.items():  # both stages together
                    g = sources[name][1] if name == "goal-image pairs" else ego_gate[np.isfinite(ego_exit)]
                    pos = f >= tau
                    both = (g >= threshold) & (e >= exit_threshold)
                    exit_figures[name].update(
                        dropped_share_both_stages=float(np.mean(~both[pos])),
                        full_matcher_share_both_stages=float(np.mean(both)),
                    )
                plot_gate(
                    out / f"{matcher_name}_{kind}_gate_exit.png",
                    exit_sources,
                    tau,
                    exit_threshold,
                    f"{matcher_name}/{kind}: exit threshold {exit_threshold:.3g} after layer {exit_layer}"
                    f" on {exit_keypoints or 'all'} keypoints",
                    xlabel=f"exit-stage score (after layer {exit_layer}, {exit_keypoints or 'all'} keypoints)",
                )
                update.update(
                    gate_exit_layer=exit_layer,
                    gate_exit_keypoints=exit_keypoints,
                    gate_exit_threshold=exit_threshold,
                    gate_exit_sources=exit_figures,
                )
            path = calibration_path(matcher_name, kind)
            data = json.loads(path.read_text())
            data.update(update)
            (out / f"{matcher_name}_{kind}_gate.json").write_text(json.dumps(data, indent=1) + "\n")
            if not args.no_write_agent:
                import shutil

                path.write_text(json.dumps(data, indent=1) + "\n")
                for suffix in ("gate", "gate_exit"):
                    png = out / f"{matcher_name}_{kind}_{suffix}.png"
                    if png.is_file():
                        shutil.copyfile(png, path.with_name(png.name))
            log.info(
                "%s/%s gate: threshold %g, exit threshold %s (tau %.4g); %s",
                matcher_name,
                kind,
                threshold,
                "off" if exit_threshold is None else f"{exit_threshold:.3g}",
                tau,
                "; ".join(
                    f"{n}: drops {v['dropped_share_at_threshold']:.2%} of {int(v['positives'])} "
                    f">= tau, passes {v['pass_share_at_threshold']:.1%} of {int(v['frames'])}"
                    for n, v in figures.items()
                ),
            )
            per_kind[kind] = {
                "threshold": threshold,
                "sources": figures,
                "exit_threshold": exit_threshold,
                "exit_sources": update.get("gate_exit_sources"),
            }
        result[matcher_name] = per_kind
    (out / "gate_summary.json").write_text(json.dumps(result, indent=1) + "\n")
    return result
