"""Distance-aware evidence (issue 13): the re-ID score against the goal's apparent size and distance.

    python -m sim.evaluation.evidence --records runs/tr20_A/episodes.jsonl runs/tr20_B/episodes.jsonl \\
        --pairs-instances 12 --out runs/evidence

Frames: each step of ``modiin.trace`` in train eval records (val/test refused): the full score, the
goal's true pixels in the 360x640 frame and the robot's distance to the goal footprint. Positive: in
view (>= 2300 px, 1%, the eval's "seen"); negative: < 100 px; between: a glimpse, a positive only in
the size table's < 1% bin.

Censoring: with the gate on, a searching frame whose gate score is below the run's gate threshold
scores 0 without the full matcher. By the gate's calibration (it drops <= 1% of frames at or above
ratio x tau; linear in the score) its score is below ``gate_bound = tau x threshold / calibrated
threshold``: a share "score >= t" is exact for t >= gate_bound and a range below, a quantile among
gated frames a range, and a bin's max-F threshold is searched only at t >= its largest gate bound
(a run gated lower, potential_tau_ratio 0.5, shows the curve below tau).

Pairs: goal images of train instances (``sim.goals.sample_goal_images``, ``imgnav calibrate``'s
seeds), same-instance pairs and sampled different ones (``calibration_core.make_pairs``, inverse-rate
weights), scored by the agent's matcher; OUT/pairs.npz keeps each pair's score and both images'
share and distance. Size: the smaller instance share of the two images; distance: the larger
camera-to-footprint distance (the harder image limits the match).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

FRAME_PX = 360 * 640  # the egocentric frame (docs/architecture.md section 1)
IN_VIEW_PX = 2300  # 1% of the frame: the eval's "goal seen" (--modiin-seen-px)
OUT_OF_VIEW_PX = 100  # below it a detection cannot be the goal (modiin.py's det_unseen)


@dataclass(frozen=True, slots=True, eq=False)
class Evidence:
    """One sample per frame or goal-image pair; every field is an (N,) array.

    score: float64 full score (sum of confidences), 0 where censored; censored: bool, the gate hid it;
    gate_bound: float64 full score below which this source's gate may hide a sample (0: no gate);
    share: float64 goal's share of the image, 0..1; dist_m: float64 to the goal footprint (nan: unknown);
    positive / glimpse / negative: bool; weight: float64 count weight; unit: str episode or instance."""

    score: np.ndarray
    censored: np.ndarray
    gate_bound: np.ndarray
    share: np.ndarray
    dist_m: np.ndarray
    positive: np.ndarray
    glimpse: np.ndarray
    negative: np.ndarray
    weight: np.ndarray
    unit: np.ndarray

    def __len__(self) -> int:
        return len(self.score)

    def select(self, mask: np.ndarray) -> Evidence:
        return Evidence(**{f.name: getattr(self, f.name)[mask] for f in dataclasses.fields(self)})


@dataclass(frozen=True, slots=True)
class Bins:
    """Left-closed bins [edges[k], edges[k+1]) of one quantity."""

    quantity: str  # "share" or "dist_m", the Evidence field binned
    edges: tuple[float, ...]
    labels: tuple[str, ...]

    def index(self, values: np.ndarray) -> np.ndarray:
        """(N,) int64 bin of each value; -1 for nan or outside the edges."""
        v = np.asarray(values, np.float64)
        k = np.searchsorted(np.asarray(self.edges), v, side="right") - 1
        k[~np.isfinite(v) | (k < 0) | (k >= len(self.labels))] = -1
        return k.astype(np.int64)


SIZE_BINS = Bins(
    "share", (0.0, IN_VIEW_PX / FRAME_PX, 0.03, 0.10, 0.30, 1.0 + 1e-9), ("<1%", "1-3%", "3-10%", "10-30%", ">30%")
)
DIST_BINS = Bins("dist_m", (0.0, 1.0, 2.0, 3.0, 5.0, math.inf), ("<1 m", "1-2 m", "2-3 m", "3-5 m", ">5 m"))


def read_train_records(path: str | Path) -> list[dict]:
    """Records of an episodes.jsonl; ValueError on any val/test record (thresholds are tuned on train).
    Every clue counts: a split field, the episode id's prefix, the scene seed's range."""
    from sim.episodes import SPLITS, split_of_scene

    out = []
    for line in filter(str.strip, Path(path).read_text().splitlines()):
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:  # a run still writing its last line
            log.warning("%s: skipping an incomplete line", path)
            continue
        seed = rec.get("scene_seed")
        clues = [
            c
            for c in (
                rec.get("split"),
                str(rec.get("episode_id", "")).split("-", 1)[0],
                None if seed is None else split_of_scene(int(seed)),
            )
            if c in SPLITS
        ]
        split = next((c for c in clues if c != "train"), clues[0] if clues else None)
        if split != "train":
            raise ValueError(
                f"{path}: episode {rec.get('episode_id')} is from the {split} split; "
                "thresholds are calibrated on train records only"
            )
        out.append(rec)
    return out


def gate_threshold_of(rec: dict) -> float | None:
    """The gate threshold the record's agent ran with (scaled by potential_tau_ratio, the
    policy's rule): from the resolved ``agent_config`` the record carries, or, for records
    written before it did, rebuilt from its variant (the --modiin-set items) by the eval's own
    config code over the sim deployment of that time, which had no potential evidence."""
    from agent.config import agent_config_from_dict
    from agent.reid.identifier import resolve_gate_threshold
    from sim.evaluation.modiin import build_config

    if isinstance(rec.get("agent_config"), dict):
        cfg = agent_config_from_dict(rec["agent_config"])
    else:
        kv = dict(s.split("=", 1) for s in str(rec.get("variant", "")).split(", ") if "=" in s)
        ns = argparse.Namespace(
            modiin_config="sim",
            modiin_reid=kv.pop("reid", "conf"),
            modiin_loc=kv.pop("loc", "mask"),
            modiin_matcher=kv.pop("matcher", None),
            modiin_tau=None,
            modiin_threads=1,
            workers=1,
            modiin_set=["policy.potential_tau_ratio=1.0"] + [f"{k}={v}" for k, v in kv.items()],
        )
        cfg = build_config(ns)
    base, ratio = resolve_gate_threshold(cfg.reid), cfg.policy.potential_tau_ratio
    return None if base is None else base * min(ratio, 1.0)


def frames_evidence(
    paths: Sequence[str | Path],
    tau: float,
    calibrated_gate: float,
    gate_thresholds: Sequence[float | None] | None = None,
) -> Evidence:
    """Frames of train records; ``gate_thresholds`` per path (default: from each file's variant)."""
    cols: dict[str, list] = {f.name: [] for f in dataclasses.fields(Evidence)}
    for k, path in enumerate(paths):
        records = read_train_records(path)
        if len({r.get("variant") for r in records}) > 1:  # one gate threshold per file
            raise ValueError(f"{path} mixes agent variants; pass one run per file")
        thr = gate_thresholds[k] if gate_thresholds is not None else gate_threshold_of(records[0]) if records else None
        bound = 0.0 if thr is None else tau * thr / calibrated_gate
        log.info(
            "%s: %d train episodes, gate threshold %s (censored frames score < %.1f)", path, len(records), thr, bound
        )
        for rec in records:
            tr = (rec.get("modiin") or {}).get("trace") or {}
            scores, px = tr.get("reid_score") or [], tr.get("goal_px") or []
            gates = tr.get("gate_score") or [None] * len(scores)
            dists = tr.get("goal_dist_m") or [math.nan] * len(scores)  # runs before the distance trace
            for s, g, p, d in zip(scores, gates, px, dists):
                if s is None:  # no matcher score at this step
                    continue
                cens = thr is not None and s == 0.0 and g is not None and g < thr
                for name, v in (
                    ("score", s),
                    ("censored", cens),
                    ("gate_bound", bound),
                    ("share", p / FRAME_PX),
                    ("dist_m", math.nan if d is None else d),
                    ("positive", p >= IN_VIEW_PX),
                    ("glimpse", OUT_OF_VIEW_PX <= p < IN_VIEW_PX),
                    ("negative", p < OUT_OF_VIEW_PX),
                    ("weight", 1.0),
                    ("unit", f"{path}:{rec.get('episode_id')}"),
                ):
                    cols[name].append(v)
    types = {"censored": bool, "positive": bool, "glimpse": bool, "negative": bool, "unit": object}
    return Evidence(**{k: np.asarray(v, dtype=types.get(k, np.float64)) for k, v in cols.items()})


def footprint_distance_m(x_m: float, y_m: float, bounds_xy_m: tuple[float, float, float, float]) -> float:
    """Distance from a point to an axis-aligned footprint (0 inside), as the eval's goal_dist_m."""
    x0, y0, x1, y1 = bounds_xy_m
    return math.hypot(max(x0 - x_m, 0.0, x_m - x1), max(y0 - y_m, 0.0, y_m - y1))


@dataclass(frozen=True, slots=True, eq=False)
class PairSample:
    """Scored goal-image pairs. pairs: (P, 2) int64 image indices; label: (P,) bool same instance;
    weight, conf: (P,) float64; per image (I,): share (instance mask share), dist_m (camera to the
    instance footprint), instance (str key)."""

    pairs: np.ndarray
    label: np.ndarray
    weight: np.ndarray
    conf: np.ndarray
    share: np.ndarray
    dist_m: np.ndarray
    instance: np.ndarray

    def evidence(self) -> Evidence:
        (a, b), n = self.pairs.T, len(self.pairs)
        return Evidence(
            score=self.conf,
            censored=np.zeros(n, bool),
            gate_bound=np.zeros(n),
            share=np.minimum(self.share[a], self.share[b]),
            dist_m=np.maximum(self.dist_m[a], self.dist_m[b]),
            positive=self.label.copy(),
            glimpse=np.zeros(n, bool),
            negative=~self.label,
            weight=self.weight,
            unit=self.instance[a],
        )


def sample_pairs(
    instances: int,
    per_instance: int,
    max_negatives: int,
    scene_set: int = 500,
    seed: int = 0,
    config: str = "sim",
    threads: int = 1,
) -> PairSample:
    """Same-instance and sampled different-instance goal-image pairs of train instances, scored."""
    from agent.config import load_agent_config
    from agent.reid.identifier import make_matcher
    from sim.episodes import scene_seed_for
    from sim.evaluation.calibration_core import make_pairs, score_pairs
    from sim.goals import sample_goal_images
    from sim.world import SimWorld

    cfg = dataclasses.replace(load_agent_config(config).reid, num_threads=threads)
    matcher = make_matcher(cfg)
    feats: list[Any] = []  # the matcher's Features
    inst: list[str] = []
    share: list[float] = []
    dist: list[float] = []
    for k in range(200):  # homes; far more than any sample needs
        if len(set(inst)) >= instances:
            break
        home_seed = scene_seed_for("train", scene_set, k)
        with SimWorld.from_seed(home_seed) as world:
            for obj in world.home.instances:
                if len(set(inst)) >= instances:
                    break
                imgs = sample_goal_images(world, obj.object_id, per_instance, seed=(home_seed, obj.object_id, 17))
                if len(imgs) < per_instance:
                    continue  # as imgnav calibrate: every instance contributes per_instance images
                for gi in imgs:
                    feats.append(matcher.extract(gi.rgb, cfg.goal_max_keypoints))
                    inst.append(f"{home_seed}_{obj.object_id}")
                    share.append(gi.coverage)
                    dist.append(footprint_distance_m(gi.camera.eye_xyz_m[0], gi.camera.eye_xyz_m[1], obj.bounds_xy_m()))
        log.info("home %d: %d instances so far", home_seed, len(set(inst)))
    ps = make_pairs(inst, max_negatives, seed)
    conf, _ = score_pairs(matcher, feats, ps.pairs)
    return PairSample(ps.pairs, ps.label, ps.weight, conf, np.asarray(share), np.asarray(dist), np.asarray(inst, str))


Range = tuple[float, float]  # (low, high): equal when exact, apart where censored frames decide


def share_at_least(ev: Evidence, t: float) -> Range:
    """Weighted share of samples scoring >= t; censored ones with a gate bound above t are unknown."""
    if (tot := float(ev.weight.sum())) <= 0:
        return (math.nan, math.nan)
    above = float(ev.weight[~ev.censored & (ev.score >= t)].sum())
    unknown = float(ev.weight[ev.censored & (ev.gate_bound > t)].sum())
    return (above / tot, (above + unknown) / tot)


def quantile(ev: Evidence, q: float) -> Range:
    """Score quantile with censored samples at 0 (low) and at their gate bound (high)."""
    if len(ev) == 0:
        return (math.nan, math.nan)
    hi = np.where(ev.censored, ev.gate_bound, ev.score)
    return (float(np.quantile(ev.score, q)), float(np.quantile(hi, q)))


@dataclass(frozen=True, slots=True)
class MaxF:
    threshold: float
    f: float
    precision: float
    recall: float
    floor: float  # thresholds below it were not searched (the bin's largest gate bound)
    at_floor: bool  # the best is the lowest threshold searched: the optimum may lie below it
    f_at_tau: float


def max_f_threshold(
    ev: Evidence, pos: np.ndarray, neg: np.ndarray, tau: float, min_positives: int = 20, min_negatives: int = 20
) -> MaxF | None:
    """The threshold of maximal F separating ``pos`` from ``neg`` (masks on ev); None: too few samples."""
    from sim.evaluation.calibration_core import pr_curves

    if int(pos.sum()) < min_positives or int(neg.sum()) < min_negatives:
        return None
    m = pos | neg
    floor = float(np.max(ev.gate_bound[m & ev.censored], initial=0.0))
    c = pr_curves(ev.score[m], pos[m], ev.weight[m])  # censored at 0: exact at thresholds >= floor
    ok = np.flatnonzero(c.threshold >= floor)
    if len(ok) == 0:
        return None
    best = int(ok[np.argmax(c.f[ok])])
    w, s, y = ev.weight[m], ev.score[m], pos[m]
    tp, fp = w[y & (s >= tau)].sum(), w[~y & (s >= tau)].sum()
    f_tau = 2 * tp / max(tp + fp + w[y].sum(), 1e-12) if tau >= floor else math.nan
    return MaxF(
        float(c.threshold[best]),
        float(c.f[best]),
        float(c.precision[best]),
        float(c.recall[best]),
        floor,
        bool(floor > 0 and best == ok[-1] and len(ok) < len(c.threshold)),
        float(f_tau),
    )


@dataclass(frozen=True, slots=True)
class BinRow:
    label: str
    positives: int
    units: int  # distinct episodes (frames) or instances (pairs) among the positives
    censored: int  # positives whose score the gate hid
    quartiles: tuple[Range, Range, Range]  # 25/50/75% of the positives' scores
    pos_at_tau: Range
    pos_at_half_tau: Range
    negatives: int
    neg_at_tau: Range
    neg_at_half_tau: Range
    max_f: MaxF | None


def bin_rows(ev: Evidence, bins: Bins, tau: float, negatives_in_bin: bool, min_positives: int = 20) -> list[BinRow]:
    """Per bin. Positives: in view, plus glimpses in size bins; negatives: those of the bin, or all
    of them when ``negatives_in_bin`` is False (a frame without the goal has no goal size)."""
    k = bins.index(getattr(ev, bins.quantity))
    base_pos = ev.positive | ev.glimpse if bins.quantity == "share" else ev.positive
    rows = []
    for b, label in enumerate(bins.labels):
        pos, neg = base_pos & (k == b), ev.negative & (k == b) if negatives_in_bin else ev.negative
        p, n = ev.select(pos), ev.select(neg)
        rows.append(
            BinRow(
                label,
                int(pos.sum()),
                len(set(p.unit)),
                int(p.censored.sum()),
                (quantile(p, 0.25), quantile(p, 0.5), quantile(p, 0.75)),
                share_at_least(p, tau),
                share_at_least(p, 0.5 * tau),
                int(neg.sum()),
                share_at_least(n, tau),
                share_at_least(n, 0.5 * tau),
                max_f_threshold(ev, pos, neg, tau, min_positives),
            )
        )
    return rows


def _analyse(
    name: str, ev: Evidence, frames: bool, tau: float, min_positives: int
) -> tuple[str, dict, dict, list[str]]:
    """Markdown tables, threshold rows, plot panels and conclusions of one data source."""
    from sim.evaluation.evidence_report import conclusion, score_table

    # a frame without the goal has no goal size: the frames' size rows use all negatives
    size, dist = (
        bin_rows(ev, SIZE_BINS, tau, not frames, min_positives),
        bin_rows(ev, DIST_BINS, tau, True, min_positives),
    )
    what = (
        (
            f"apparent size (negatives: all {int(ev.negative.sum())} frames without the goal)",
            "distance to the goal footprint",
        )
        if frames
        else ("the smaller apparent size of the two", "the larger camera distance of the two")
    )
    md = (
        f"By {what[0]}:\n\n{score_table(size, 'episodes' if frames else 'instances', not frames)}\n\n"
        f"By {what[1]}:\n\n{score_table(dist, 'episodes' if frames else 'instances', True)}"
    )
    notes = conclusion(f"{name}, by size", size, tau, min_positives, not frames)
    return (
        md,
        {f"{name}, size": size, f"{name}, distance": dist},
        {f"{name} by size": (ev, SIZE_BINS, size), f"{name} by distance": (ev, DIST_BINS, dist)},
        notes + conclusion(f"{name}, by distance", dist, tau, min_positives, True),
    )


def _pairs(args: argparse.Namespace, out: Path) -> PairSample:
    """Scored pairs (OUT/pairs.npz), reused when the same sample was scored before."""
    key = np.asarray([args.pairs_instances, args.pairs_per_instance, args.pairs_negatives, args.scene_set, args.seed])
    cache = out / "pairs.npz"
    cached = np.load(cache) if cache.is_file() else None
    if cached is not None and np.array_equal(cached["key"], key):
        log.info("pair scores reused from %s", cache)
        return PairSample(**{f.name: cached[f.name] for f in dataclasses.fields(PairSample)})
    pairs = sample_pairs(
        args.pairs_instances,
        args.pairs_per_instance,
        args.pairs_negatives,
        args.scene_set,
        args.seed,
        threads=args.threads,
    )
    np.savez_compressed(cache, key=key, **{f.name: getattr(pairs, f.name) for f in dataclasses.fields(pairs)})
    return pairs


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--records", nargs="*", default=[], help="episodes.jsonl of train evaluations (modiin)")
    ap.add_argument(
        "--gate-thresholds",
        nargs="*",
        default=None,
        help="gate threshold per --records file ('none': gate off); default: from each run's variant",
    )
    ap.add_argument("--pairs-instances", type=int, default=0, help="train instances for goal-image pairs (0: no pairs)")
    for flag, default, what in (
        ("--pairs-per-instance", 6, "goal images per instance"),
        ("--pairs-negatives", 300, "different-instance pairs drawn"),
        ("--scene-set", 500, "train home set (imgnav calibrate's: the same goal images)"),
        ("--seed", 0, "pair sampling seed"),
        ("--threads", 1, "torch threads for the pairs"),
        ("--min-positives", 20, "positives a bin needs for a threshold (and 20 negatives)"),
    ):
        ap.add_argument(flag, type=int, default=default, help=what)
    ap.add_argument("--out", default="runs/evidence")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    from agent.config import load_agent_config
    from agent.reid.identifier import resolve_gate_threshold, resolve_tau
    from sim.evaluation.evidence_report import plot, threshold_table

    reid = load_agent_config("sim").reid
    tau, calibrated_gate = resolve_tau(reid), resolve_gate_threshold(reid) or 1.0
    thr = None if args.gate_thresholds is None else [None if t == "none" else float(t) for t in args.gate_thresholds]
    if thr is not None and len(thr) != len(args.records):
        ap.error("--gate-thresholds needs one value per --records file")
    if not args.records and not args.pairs_instances:
        ap.error("nothing to analyse: give --records and/or --pairs-instances")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sections: list[str] = []
    named: dict[str, Any] = {}
    panels: dict[str, Any] = {}
    notes: list[str] = []
    report: dict[str, Any] = {"tau": tau, "records": args.records}
    if args.records:
        ev = frames_evidence(args.records, tau, calibrated_gate, thr)
        report["frames"] = {"episodes": len(set(ev.unit)), "frames": len(ev), "censored": int(ev.censored.sum())}
        parts = [
            ("Frames", ev, f"{len(set(ev.unit))} episodes, {len(ev)} frames, {int(ev.censored.sum())} below the gate")
        ]
        low = float(ev.gate_bound.min()) if len(ev) else 0.0
        if len(ev) and ev.gate_bound.max() > low:  # the lowest-gated run(s) alone are exact below the others' bound
            sub = ev.select(ev.gate_bound <= low)
            parts.append(
                (
                    f"Frames, runs with gate bound {low:.1f} only",
                    sub,
                    f"{len(set(sub.unit))} episodes, {len(sub)} frames, {int(sub.censored.sum())} below the gate",
                )
            )
        for name, sub, what in parts:
            md, n, p, c = _analyse(name, sub, True, tau, args.min_positives)
            sections.append(f"## {name} ({what})\n\n{md}")
            named, panels, notes = named | n, panels | (p if sub is ev else {}), notes + c
    if args.pairs_instances:
        ev = _pairs(args, out).evidence()
        md, n, p, c = _analyse("Pairs", ev, False, tau, args.min_positives)
        sections.append(
            f"## Goal-image pairs ({len(set(ev.unit))} train instances x {args.pairs_per_instance} images: "
            f"{int(ev.positive.sum())} same, {int(ev.negative.sum())} different pairs)\n\n{md}"
        )
        named, panels, notes = named | n, panels | p, notes + c
    sections += [
        f"## Max-F threshold per bin (>= {args.min_positives} positives; '<= x (floor f)': best at the lowest "
        "threshold the gated frames allow; F depends on the bin's positive:negative ratio)\n\n"
        + threshold_table(named),
        "## Conclusion\n\n" + "\n".join(f"- {n}" for n in notes),
    ]
    md = (
        f"# Distance-aware evidence (tau {tau:.1f}; a..b: a range where gated frames decide)\n\n"
        + "\n\n".join(sections)
        + "\n"
    )
    (out / "evidence.md").write_text(md)
    report.update({k: [dataclasses.asdict(r) for r in v] for k, v in named.items()}, conclusion=notes)
    (out / "evidence.json").write_text(json.dumps(report, indent=1, default=float) + "\n")
    plot(
        out / "evidence.png", panels, tau, "re-ID score (XFeat + LighterGlue, conf) against apparent size and distance"
    )
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
