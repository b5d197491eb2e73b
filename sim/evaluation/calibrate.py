"""``imgnav calibrate``: choose the re-ID threshold tau by maximal F-measure (Krantz et al. 2023, 3.2).

    imgnav calibrate --matcher xfeat_lighterglue sift --instances 100 --images-per-instance 10 \\
        --out runs/calibration

1. Goal images of train-split instances (``sim.goals.sample_goal_images``, the episodes'
   own sampler): homes ``scene_seed_for("train", --scene-set, k)`` for k = 0, 1, ... until
   ``--instances`` instances have ``--images-per-instance`` images each. Cached as PNGs in
   ``--image-cache`` (default OUT/images) and reused by later runs and other matchers.
2. Per matcher: features once per image (the agent's settings from ``--config``), then every
   same-instance pair and a uniform sample of ``--max-negatives`` different-instance pairs,
   each weighted by the inverse sampling rate (``calibration_core``); one matching pass gives
   both scores, ``conf`` and ``count``.
3. Per score: PR and F curves (OUT/<matcher>_pr.png), the max-F tau and the figures in
   OUT/<matcher>_<score>.json, and the calibration file the agent reads,
   agent/calibration/<matcher>_<score>.json (unless ``--no-write-agent``).

``--realism PROFILE`` (default ``clean``: the above, unchanged) scores each pair (i, j) as a
phone-like goal photo of image i against a robot camera frame of image j, each processed by the
profile's own models with a seed from the image's name (``calibration_realism``). Its outputs name
the profile (OUT/<matcher>_<profile>_pr.png, OUT/<matcher>_<profile>_<score>.json,
OUT/summary_<profile>.*) and add the figures at the tau the agent uses today; the agent's
calibration files are left alone unless ``--write-agent`` asks for them.

Only the train split is used; asking for another split is refused.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from agent.reid.base import ScoreKind
    from agent.reid.identifier import MatcherName
    from sim.evaluation.calibration_core import OperatingPoint
    from sim.realism import Realism

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--matcher", nargs="+", default=["xfeat_lighterglue"], choices=["xfeat_lighterglue", "aliked_lightglue", "sift"]
    )
    parser.add_argument("--instances", type=int, default=100, help="train instances (>= 100 for the paper's protocol)")
    parser.add_argument("--images-per-instance", type=int, default=10)
    parser.add_argument("--scene-set", type=int, default=500, help="set seed of the train homes used for calibration")
    parser.add_argument(
        "--max-negatives",
        type=int,
        default=8000,
        help="different-instance pairs drawn uniformly (weighted by the inverse rate); 0 = all",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", default="sim", help="agent deployment or YAML whose reid settings are used")
    parser.add_argument("--out", default="runs/calibration")
    parser.add_argument("--image-cache", default=None, help="directory of cached goal images (default OUT/images)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    write = parser.add_mutually_exclusive_group()
    write.add_argument(
        "--no-write-agent",
        action="store_true",
        help="do not write agent/calibration/*.json (the default under --realism other than clean)",
    )
    write.add_argument(
        "--write-agent",
        action="store_true",
        help="write agent/calibration/*.json even under --realism other than clean (the agent's tau then "
        "comes from the profile's pairs)",
    )
    from sim.evaluation.cli import add_realism_arguments

    # --realism: goal photos processed like a phone's against robot frames (calibration_realism);
    # the pairs, their sampling and weights stay the same
    add_realism_arguments(
        parser,
        realism_help="clean (default): pairs of rendered goal images as they are; stretch: each pair is a "
        "phone-like goal photo against a robot camera frame, made by the profile's models (seeded by the "
        "image's name); outputs named by the profile, and agent/calibration/*.json is not written "
        "unless --write-agent",
    )
    from sim.evaluation.cli import add_ray_arguments

    add_ray_arguments(
        parser
    )  # --ray: pairs scored as Ray tasks (sim.evaluation.ray_calibration); local: --threads CPUs
    from sim.evaluation.gate_calibration import add_arguments as add_gate_arguments

    add_gate_arguments(parser)


# --- images ---------------------------------------------------------------------------


def load_or_sample_images(cache: Path, instances: int, per_instance: int, scene_set: int) -> list[dict]:
    """Index entries {path, instance, scene_seed, instance_id, category}, sampling what is missing."""
    from sim.episodes import read_rgb, scene_seed_for, write_rgb  # noqa: F401 (read_rgb used by callers)
    from sim.goals import sample_goal_images
    from sim.world import SimWorld

    cache.mkdir(parents=True, exist_ok=True)
    index_path = cache / "index.json"
    index: dict = json.loads(index_path.read_text()) if index_path.exists() else {"scenes_done": [], "images": []}
    if index.get("per_instance") not in (None, per_instance) or index.get("scene_set") not in (None, scene_set):
        raise ValueError(f"{cache} holds another image set (per_instance/scene_set differ); use another --image-cache")
    index["per_instance"], index["scene_set"] = per_instance, scene_set

    def n_instances() -> int:
        return len({e["instance"] for e in index["images"]})

    k = 0
    from tqdm import tqdm

    bar = tqdm(total=instances, initial=min(n_instances(), instances), desc="goal images", unit="inst")
    while n_instances() < instances:
        seed = scene_seed_for("train", scene_set, k)
        k += 1
        if seed in index["scenes_done"]:
            continue
        with SimWorld.from_seed(seed) as world:
            for obj in world.home.instances:
                if n_instances() >= instances:
                    break
                imgs = sample_goal_images(world, obj.object_id, per_instance, seed=(seed, obj.object_id, 17))
                if len(imgs) < per_instance:
                    continue  # the protocol needs per_instance images of every instance
                key = f"{seed}_{obj.object_id}"
                for j, gi in enumerate(imgs):
                    p = cache / f"{key}_{j:02d}.png"
                    write_rgb(p, gi.rgb)
                    index["images"].append(
                        {
                            "path": p.name,
                            "instance": key,
                            "scene_seed": seed,
                            "instance_id": obj.object_id,
                            "category": obj.category,
                        }
                    )
                bar.update(1)
        index["scenes_done"].append(seed)
        index_path.write_text(json.dumps(index))
    bar.close()
    keys = sorted({e["instance"] for e in index["images"]})[:instances]
    chosen = set(keys)
    return [e for e in index["images"] if e["instance"] in chosen]


# --- one matcher ------------------------------------------------------------------------


def profile_tag(realism: Realism | None) -> str | None:
    """The profile's part of the output names (None: clean, today's names), e.g. ``stretch`` or
    ``stretch-goal_photo`` for ``--realism stretch --realism-only goal_photo``."""
    if realism is None:
        return None
    return realism.profile.name.replace("[", "-").replace("]", "")


def writes_agent(args: argparse.Namespace, realism: Realism | None) -> bool:
    """Whether agent/calibration/*.json is written: clean unless ``--no-write-agent``; under a
    profile only with ``--write-agent``."""
    if getattr(args, "no_write_agent", False):
        return False
    return realism is None or bool(getattr(args, "write_agent", False))


def calibrate_matcher(
    matcher_name: MatcherName, entries: list[dict], cache: Path, out: Path, args: argparse.Namespace
) -> dict:
    from dataclasses import replace

    from tqdm import tqdm

    from agent.config import load_agent_config
    from agent.reid.identifier import calibration_path, make_matcher, resolve_tau
    from sim.episodes import read_rgb
    from sim.evaluation.calibration_core import make_pairs, operating_point, plot_curves, pr_curves
    from sim.evaluation.calibration_realism import role_features, score_calibration_pairs
    from sim.evaluation.cli import realism_of

    realism = realism_of(args)
    tag = profile_tag(realism)
    stem = matcher_name if tag is None else f"{matcher_name}_{tag}"
    base = load_agent_config(args.config).reid
    cfg = replace(base, matcher=matcher_name, num_threads=args.threads)
    inst = [e["instance"] for e in entries]
    ps = make_pairs(inst, args.max_negatives, args.seed)
    if getattr(args, "ray", None):  # features and matching in Ray tasks; times are task CPU seconds
        from sim.evaluation.cli import ray_options
        from sim.evaluation.ray_calibration import score_pairs_on_ray

        with tqdm(total=len(ps.pairs), desc=f"{matcher_name} pairs (ray)", unit="pair") as bar:
            conf, count, st = score_pairs_on_ray(
                ray_options(args, args.threads),
                cfg,
                [e["path"] for e in entries],
                [(cache / e["path"]).read_bytes() for e in entries],
                ps.pairs,
                progress=bar,
            )
        t_feat = st["extract_s"] * len(entries) / max(st["extracted"], 1)
        t_match = st["match_s"]
    else:
        matcher = make_matcher(cfg)
        t0 = time.perf_counter()
        goal_feats, frame_feats = role_features(
            matcher,
            (read_rgb(cache / e["path"]) for e in tqdm(entries, desc=f"{stem} features", unit="img")),
            [e["path"] for e in entries],
            realism,
            cfg.goal_max_keypoints,
            cfg.obs_max_keypoints,
        )
        t_feat = time.perf_counter() - t0
        t0 = time.perf_counter()
        conf, count = score_calibration_pairs(
            matcher, goal_feats, frame_feats, ps.pairs, tqdm(range(len(ps.pairs)), desc=f"{stem} pairs", unit="pair")
        )
        t_match = time.perf_counter() - t0
    cats = np.array([e["category"] for e in entries])
    same_cat = cats[ps.pairs[:, 0]] == cats[ps.pairs[:, 1]]
    np.savez_compressed(
        out / f"{stem}_scores.npz",
        pairs=ps.pairs,
        label=ps.label,
        weight=ps.weight,
        conf=conf,
        count=count,
        same_category=same_cat,
    )
    curves = {"conf": pr_curves(conf, ps.label, ps.weight), "count": pr_curves(count, ps.label, ps.weight)}
    # under a profile: the figures at the tau the agent reads today (its calibration file or
    # its config), on these pairs
    at_agent: dict[str, OperatingPoint] = {}
    if realism is not None:
        kinds: tuple[ScoreKind, ...] = ("conf", "count")
        for score_kind, v in zip(kinds, (conf, count), strict=True):
            try:
                tau = resolve_tau(replace(cfg, score=score_kind))
                at_agent[score_kind] = operating_point(v, ps.label, ps.weight, tau)
            except (FileNotFoundError, ValueError) as exc:
                log.warning("%s/%s: no tau of the agent to compare with (%s)", matcher_name, score_kind, exc)
    plot_curves(
        str(out / f"{stem}_pr.png"),
        curves,
        f"{matcher_name}{'' if tag is None else f' under {tag} (goal photo vs robot frame)'}: "
        f"{len(set(inst))} instances, {len(entries)} images, "
        f"{int(ps.label.sum())} same / {int((~ps.label).sum())} of {ps.n_negatives_total} different pairs",
        marks=at_agent or None,
    )
    results = {}
    for kind, c in curves.items():
        res = {
            "matcher": matcher_name,
            "score": kind,
            "tau": c.tau,
            "max_f": c.max_f,
            "precision_at_tau": float(c.precision[c.best]),
            "recall_at_tau": float(c.recall[c.best]),
            "auc_pr": c.auc_pr(),
            "instances": len(set(inst)),
            "images": len(entries),
            "same_pairs": int(ps.label.sum()),
            "different_pairs_scored": int((~ps.label).sum()),
            "different_pairs_total": ps.n_negatives_total,
            "negative_weight": float(ps.weight[~ps.label][0]) if (~ps.label).any() else 1.0,
            "split": "train",
            "scene_set": args.scene_set,
            "seed": args.seed,
            "goal_max_keypoints": cfg.goal_max_keypoints,
            "max_side_px": cfg.max_side_px,
            "feature_ms_per_image": 1000 * t_feat / max(len(entries), 1),
            "match_ms_per_pair": 1000 * t_match / max(len(ps.pairs), 1),
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
        if realism is not None:
            res["realism"] = realism.describe()
            res["frame_max_keypoints"] = cfg.obs_max_keypoints
            point = at_agent.get(kind)
            if point is not None:
                res["agent_tau"] = point.tau
                res["precision_at_agent_tau"] = point.precision
                res["recall_at_agent_tau"] = point.recall
                res["f_at_agent_tau"] = point.f
        (out / f"{stem}_{kind}.json").write_text(json.dumps(res, indent=1) + "\n")
        if writes_agent(args, realism):
            calibration_path(matcher_name, kind).write_text(json.dumps(res, indent=1) + "\n")
        log.info(
            "%s/%s: max F %.3f at tau %.4g (P %.3f, R %.3f)",
            matcher_name,
            kind,
            c.max_f,
            c.tau,
            res["precision_at_tau"],
            res["recall_at_tau"],
        )
        results[kind] = res
    return results


def run(args: argparse.Namespace) -> int:
    if args.instances < 2 or args.images_per_instance < 2:
        log.error("need at least 2 instances with 2 images each")
        return 2
    if args.instances < 100 or args.images_per_instance < 10:
        log.warning("fewer than the protocol's 100 instances x 10 images: a trial run")
    from sim.evaluation.cli import realism_of

    realism = realism_of(args)
    if realism is not None and (getattr(args, "ray", None) or getattr(args, "gate", False)):
        log.error("--realism is for the tau calibration on this machine; not with --ray or --gate")
        return 2
    if realism is not None and not writes_agent(args, realism):
        log.info("under --realism %s: agent/calibration/*.json is not written (--write-agent)", realism.profile.name)
    tag = profile_tag(realism)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(args.image_cache) if args.image_cache else out / "images"
    entries = load_or_sample_images(cache, args.instances, args.images_per_instance, args.scene_set)
    log.info("%d images of %d instances", len(entries), len({e["instance"] for e in entries}))
    if getattr(args, "gate", False):
        from sim.evaluation.gate_calibration import calibrate_gate

        calibrate_gate(entries, cache, out, args)
        return 0
    table = {}
    for name in args.matcher:
        try:
            table[name] = calibrate_matcher(name, entries, cache, out, args)
        except RuntimeError as exc:  # e.g. the optional matcher is not installed
            log.error("%s: %s", name, exc)
            return 2
    summary = "summary" if tag is None else f"summary_{tag}"
    (out / f"{summary}.json").write_text(json.dumps(table, indent=1) + "\n")
    lines = summary_lines(table)
    (out / f"{summary}.md").write_text("\n".join(lines) + "\n")
    log.info("calibration (also in %s):\n%s", out / f"{summary}.md", "\n".join(lines))
    return 0


def summary_lines(table: dict[str, dict[str, dict]]) -> list[str]:
    """The summary table (under a profile also the figures at the agent's tau)."""
    agent = any("agent_tau" in r for per in table.values() for r in per.values())
    head = "| matcher | score | tau | max F | precision | recall |"
    rule = "| --- | --- | --- | --- | --- | --- |"
    if agent:
        head += " agent's tau | precision there | recall there | F there |"
        rule += " --- | --- | --- | --- |"
    lines = [head, rule]
    for name, per in table.items():
        for kind, r in per.items():
            line = (
                f"| {name} | {kind} | {r['tau']:.4g} | {r['max_f']:.3f} | {r['precision_at_tau']:.3f} | "
                f"{r['recall_at_tau']:.3f} |"
            )
            if agent:
                line += (
                    f" {r['agent_tau']:.4g} | {r['precision_at_agent_tau']:.3f} | {r['recall_at_agent_tau']:.3f} | "
                    f"{r['f_at_agent_tau']:.3f} |"
                    if "agent_tau" in r
                    else " - | - | - | - |"
                )
            lines.append(line)
    return lines
