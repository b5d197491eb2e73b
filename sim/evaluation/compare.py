"""Paired comparison of evaluation runs on the same episodes (issue 13: "compare variants on
the same episodes").

Success varies far more between homes than between the episodes of one home, so two
variants are compared on the episodes both have finished, and the difference gets its own
interval from a bootstrap over homes of the *paired* per-episode differences (resampling
homes keeps the pairing: the two variants always see the same drawn episodes). That interval
is much narrower than the gap between two separate intervals.

    python -m sim.evaluation.compare runs/base runs/variant1 runs/variant2 ...

prints, on the episodes that every run has (a ladder in the paper's layout):

* each run's NE, Max-ST, SR and SPL with 95% intervals over homes;
* each run against the first: the paired difference in SR and SPL with its interval, and how
  many episodes it won (failed in the first, succeeded here) and lost;
* each run's failure causes on those episodes (counts, as in the paper's failure table);
* where each run stood on one spot: the episodes that ran out of steps, those in which the robot
  stayed within ``STAND_RADIUS_M`` of one place for ``STAND_STEPS`` steps or more (the longest
  such stretch), and the steps spent in runs of at least ``STUCK_TURNS`` turns alternating left
  and right (the longest run); a robot doing that in a home looks broken whatever the episode's
  outcome (issue 30);
* each run's cost: agent and simulator milliseconds per step, episodes per hour (meaningful
  between runs made side by side on one machine).

Against the first run each variant also says on how many episodes it took exactly the same
actions (a change meant to leave the agent's decisions alone should say "all").

Multi-goal runs (records with ``subtasks``, issue 31) are compared subtask by subtask: every
table above is over the subtasks (``<sequence id>#<goal index>``) and one more sets the first goal
against the later ones: each run's SR and SPL on first and on later goals, and against the first
run the paired differences on each and the later goals' SPL ratio (this run's mean SPL over the
first run's, on the same later subtasks), each with its interval over homes. Later subtasks of
two runs share the goal, not the start: each starts where its own run ended the goal before.

``--all`` uses each run's own episodes for the first table instead (unpaired).

``--outcomes`` adds one more table: each common episode that some run failed, one column a run,
the cell the failure's cause (``-`` for a success). It tells which failures of a run several
runs share, e.g. which of the full noise profile's failures each component alone repeats.

``--identical`` checks a change meant to leave the agent alone (a refactoring): on the episodes
both runs have, every field of each record must be equal, apart from timings (``timing``,
``modiin.median_ms``, a multi-goal subtask's ``memory.recall_ms``) and the fields named with
``--ignore`` (dotted paths, e.g. ``agent_config``; a path also names that field in the items of
a list, such as a multi-goal record's subtasks: ``timing`` leaves out ``subtasks[2].timing``);
it lists every other difference and exits 1 when there is one.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agent.types import Action
from sim.metrics import aggregate, bootstrap_ci

RECORDS = "episodes.jsonl"
# the failure causes of sim/evaluation/modiin.py Attribution, in the tables' order
FAILURE_CLASSES = (
    "reid_false_negative",
    "reid_false_positive",
    "exploration",
    "mapping_ghosts",
    "localisation",
    "local_navigation",
    "pose_drift",
)


def load_records(out_dir: str | Path) -> dict[str, dict[str, Any]]:
    """episode id -> record of one ``imgnav eval`` output (the first record of an id wins, as
    in the runner)."""
    path = Path(out_dir) / RECORDS
    if not path.is_file():
        raise FileNotFoundError(f"no {RECORDS} in {out_dir}")
    out: dict[str, dict[str, Any]] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}:{n}: not JSON ({exc})") from exc
        out.setdefault(str(r["episode_id"]), r)
    return out


def subtask_records(records: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """A multi-goal run's records as one record per subtask, ``<sequence id>#<goal index>``, with the
    sequence's home and fields (single-goal records are returned as they are)."""
    out: dict[str, dict[str, Any]] = {}
    for sid, r in records.items():
        if "subtasks" not in r:
            out[sid] = dict(r)
            continue
        shared = {k: v for k, v in r.items() if k not in ("subtasks", "timing", "steps", "success", "spl", "error")}
        for sub in r["subtasks"]:
            out[f"{sid}#{sub['goal_index']}"] = {**shared, **sub, "episode_id": f"{sid}#{sub['goal_index']}"}
    return out


def ratio_ci(
    base: Sequence[float], variant: Sequence[float], homes: Sequence[Any], resamples: int = 2000, seed: int = 0
) -> tuple[float, tuple[float, float]]:
    """mean(variant) / mean(base) on paired values, with a 95% percentile-bootstrap interval over
    resampled homes (each draw keeps the pairs: both runs see the same drawn episodes)."""
    import numpy as np

    b, v = np.asarray(base, np.float64), np.asarray(variant, np.float64)
    keys = {k: i for i, k in enumerate(dict.fromkeys(homes))}
    idx = np.fromiter((keys[k] for k in homes), np.int64, len(homes))
    sb = np.bincount(idx, weights=b, minlength=len(keys))
    sv = np.bincount(idx, weights=v, minlength=len(keys))
    draw = np.random.default_rng(seed).integers(0, len(keys), size=(resamples, len(keys)))
    with np.errstate(divide="ignore", invalid="ignore"):
        stats = sv[draw].sum(axis=1) / sb[draw].sum(axis=1)
    lo, hi = np.nanquantile(stats, [0.025, 0.975])
    value = float(v.sum() / b.sum()) if b.sum() > 0 else float("nan")
    return value, (round(float(lo), 4), round(float(hi), 4))


def _first_and_later(
    out_dirs: Sequence[str], raw: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]]
) -> list[str]:
    """The multi-goal table: first goal against later goals (module docstring)."""
    common_seq = sorted(set.intersection(*(set(r) for r in raw)))
    if not common_seq:
        return []
    first = [f"{k}#0" for k in common_seq]
    later = [f"{k}#{s['goal_index']}" for k in common_seq for s in raw[0][k]["subtasks"] if s["goal_index"] > 0]
    homes_later = [runs[0][k]["scene_seed"] for k in later]
    lines = [
        "",
        f"First goal against later goals on the {len(common_seq)} common sequences ({len(later)} later goals):",
        "",
        "| variant | first SR [95% CI] | first SPL [95% CI] | later SR [95% CI] | later SPL [95% CI] |",
        "| --- | --- | --- | --- | --- |",
    ]
    for d, recs in zip(out_dirs, runs):
        a = aggregate([{**recs[k], "ne": float(recs[k]["ne"])} for k in first])
        b = aggregate([{**recs[k], "ne": float(recs[k]["ne"])} for k in later])
        lines.append(
            f"| {_label(d, recs)} | {_ci(a['sr'], a['sr_ci95'])} | {_ci(a['spl'], a['spl_ci95'])} | "
            f"{_ci(b['sr'], b['sr_ci95'])} | {_ci(b['spl'], b['spl_ci95'])} |"
        )
    if len(runs) > 1:
        lines += [
            "",
            f"Paired against {out_dirs[0]} (bootstrap over homes):",
            "",
            "| variant | first d SR | first d SPL | later d SR | later d SPL | later SPL ratio [95% CI] |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for d, recs in zip(out_dirs[1:], runs[1:]):
            p0 = paired_difference(runs[0], recs, first)
            p1 = paired_difference(runs[0], recs, later)
            r, r_ci = ratio_ci([runs[0][k]["spl"] for k in later], [recs[k]["spl"] for k in later], homes_later)
            lines.append(
                f"| {_label(d, recs)} | {_signed_ci(p0.d_sr, p0.d_sr_ci95)} | {_signed_ci(p0.d_spl, p0.d_spl_ci95)} | "
                f"{_signed_ci(p1.d_sr, p1.d_sr_ci95)} | {_signed_ci(p1.d_spl, p1.d_spl_ci95)} | "
                f"{r:.2f} [{r_ci[0]:.2f}, {r_ci[1]:.2f}] |"
            )
    return lines


@dataclass(frozen=True, slots=True)
class PairedDiff:
    """variant minus base on the same episodes; intervals from a bootstrap over homes."""

    episodes: int
    homes: int
    d_sr: float
    d_sr_ci95: tuple[float, float]
    d_spl: float
    d_spl_ci95: tuple[float, float]
    won: int  # failed in the base, succeeded in the variant
    lost: int  # succeeded in the base, failed in the variant


def paired_difference(
    base: Mapping[str, Mapping[str, Any]], variant: Mapping[str, Mapping[str, Any]], ids: Sequence[str] | None = None
) -> PairedDiff:
    """The paired SR/SPL difference on ``ids`` (default: the episodes both have)."""
    ids = sorted(set(base) & set(variant)) if ids is None else list(ids)
    if not ids:
        raise ValueError("the two runs have no episode in common")
    homes = [base[k]["scene_seed"] for k in ids]
    d_sr = [float(bool(variant[k]["success"])) - float(bool(base[k]["success"])) for k in ids]
    d_spl = [float(variant[k]["spl"]) - float(base[k]["spl"]) for k in ids]
    won = sum(1 for k in ids if variant[k]["success"] and not base[k]["success"])
    lost = sum(1 for k in ids if base[k]["success"] and not variant[k]["success"])
    n = len(ids)
    return PairedDiff(
        n,
        len(set(homes)),
        sum(d_sr) / n,
        bootstrap_ci(d_sr, homes),
        sum(d_spl) / n,
        bootstrap_ci(d_spl, homes),
        won,
        lost,
    )


def _label(out_dir: str, records: Mapping[str, Mapping[str, Any]]) -> str:
    variants = {str(r.get("variant", "")) for r in records.values()} - {""}
    return f"{out_dir} ({variants.pop()})" if len(variants) == 1 else out_dir


def _ci(value: float, ci: Sequence[float]) -> str:
    return f"{value:.3f} [{ci[0]:.2f}, {ci[1]:.2f}]"


def _signed_ci(value: float, ci: Sequence[float]) -> str:
    return f"{value:+.3f} [{ci[0]:+.2f}, {ci[1]:+.2f}]"


def compare(out_dirs: Sequence[str], paired: bool = True, outcomes: bool = False) -> str:
    """The Markdown tables described in the module docstring (``outcomes``: also the table of
    the episodes some run failed)."""
    if len(out_dirs) < 1:
        raise ValueError("give at least one evaluation output")
    raw = [load_records(d) for d in out_dirs]
    multi = [any("subtasks" in r for r in recs.values()) for recs in raw]
    if any(multi) and not all(multi):
        raise ValueError("multi-goal and single-goal runs cannot be compared")
    runs = [subtask_records(recs) for recs in raw] if any(multi) else raw
    common = sorted(set.intersection(*(set(r) for r in runs)))
    if paired and not common:
        raise ValueError("the runs have no episode in common")
    lines = [
        f"Episodes in common: {len(common)} ({len({runs[0][k]['scene_seed'] for k in common})} homes)"
        if paired
        else "Each run on its own episodes",
        "",
        "| variant | NE (m) | Max-ST | SR [95% CI] | SPL [95% CI] | episodes |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for d, recs in zip(out_dirs, runs):
        rows = [recs[k] for k in common] if paired else list(recs.values())
        agg = aggregate([{**r, "ne": float(r["ne"])} for r in rows])
        lines.append(
            f"| {_label(d, recs)} | {agg['ne']:.2f} | {agg['max_st']:.3f} | {_ci(agg['sr'], agg['sr_ci95'])} | "
            f"{_ci(agg['spl'], agg['spl_ci95'])} | {agg['episodes']} ({agg['homes']} homes) |"
        )
    if len(runs) > 1 and common:
        lines += [
            "",
            f"Paired against {out_dirs[0]} on the {len(common)} common episodes (bootstrap over homes):",
            "",
            "| variant | d SR [95% CI] | d SPL [95% CI] | won | lost | same actions |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for d, recs in zip(out_dirs[1:], runs[1:]):
            p = paired_difference(runs[0], recs, common)
            same = sum(same_actions(runs[0][k], recs[k]) for k in common)
            lines.append(
                f"| {_label(d, recs)} | {_signed_ci(p.d_sr, p.d_sr_ci95)} | {_signed_ci(p.d_spl, p.d_spl_ci95)} | "
                f"{p.won} | {p.lost} | {same} of {len(common)} |"
            )
    if common:
        lines += [
            "",
            "Failures on the common episodes (counts):",
            "",
            "| variant | failed | " + " | ".join(FAILURE_CLASSES) + " | other |",
            "| --- | --- |" + " --- |" * (len(FAILURE_CLASSES) + 1),
        ]
        for d, recs in zip(out_dirs, runs):
            failed = [recs[k] for k in common if not recs[k]["success"]]
            c = Counter(failure_of(r) for r in failed)
            other = sum(v for k, v in c.items() if k not in FAILURE_CLASSES)
            lines.append(
                f"| {_label(d, recs)} | {len(failed)} | "
                + " | ".join(str(c.get(k, 0)) for k in FAILURE_CLASSES)
                + f" | {other} |"
            )
    if common:
        lines += [
            "",
            f"Standing on one spot, on the common episodes (within {STAND_RADIUS_M} m for {STAND_STEPS} steps or "
            f"more; runs of {STUCK_TURNS} or more turns alternating left and right):",
            "",
            "| variant | out of steps | episodes standing | longest stand (steps) | episodes turning to and fro "
            "| steps in those runs | longest run |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for d, recs in zip(out_dirs, runs):
            trajs = [recs[k].get("trajectory") or {} for k in common]
            stands = [longest_stand(t.get("poses_world") or []) for t in trajs]
            per = [to_and_fro_runs(t.get("actions") or []) for t in trajs]
            long = [[n for n in r if n >= STUCK_TURNS] for r in per]
            lines.append(
                f"| {_label(d, recs)} | {sum(bool(recs[k].get('max_steps_reached')) for k in common)} | "
                f"{sum(n >= STAND_STEPS for n in stands)} | {max(stands, default=0)} | "
                f"{sum(bool(x) for x in long)} | {sum(map(sum, long))} | {max((max(r, default=0) for r in per), default=0)} |"
            )
    if common and all(all("timing" in recs[k] for k in common) for recs in runs):
        lines += [
            "",
            "Cost on the common episodes (timings from each run's own machine and load: compare runs "
            "made side by side):",
            "",
            "| variant | agent ms/step (median over episodes) | simulator ms/step | episodes per hour | "
            "ratio to the first |",
            "| --- | --- | --- | --- | --- |",
        ]
        base_rate = None
        for d, recs in zip(out_dirs, runs):
            costs = cost([recs[k] for k in common])
            base_rate = base_rate or costs["episodes_per_hour"]
            lines.append(
                f"| {_label(d, recs)} | {costs['agent_ms_per_step']:.0f} | {costs['sim_ms_per_step']:.0f} | "
                f"{costs['episodes_per_hour']:.1f} | {costs['episodes_per_hour'] / base_rate:.2f} |"
            )
    if any(multi) and paired:
        lines += _first_and_later(out_dirs, raw, runs)
    if outcomes and common:
        lines += outcome_table(out_dirs, runs, common)
    return "\n".join(lines)


def failure_of(rec: Mapping[str, Any]) -> str:
    """A failed record's cause: its attribution, else ``error`` or ``unattributed``."""
    return str(rec.get("failure_cause") or ("error" if rec.get("error") else "unattributed"))


def outcome_table(
    out_dirs: Sequence[str], runs: Sequence[Mapping[str, Mapping[str, Any]]], common: Sequence[str]
) -> list[str]:
    """One row per episode of ``common`` that some run failed: its cause in each run (``-``: success)."""
    failed = [k for k in common if not all(recs[k]["success"] for recs in runs)]
    lines = [
        "",
        f"Episodes some run failed ({len(failed)} of {len(common)}; the cause in each run, - for a success; "
        "runs in the order given):",
        "",
        "| episode | " + " | ".join(f"{i + 1}" for i in range(len(runs))) + " | failed in |",
        "| --- |" + " --- |" * (len(runs) + 1),
    ]
    for k in failed:
        cells = ["-" if recs[k]["success"] else failure_of(recs[k]) for recs in runs]
        lines.append(f"| {k} | " + " | ".join(cells) + f" | {sum(c != '-' for c in cells)} of {len(runs)} |")
    lines.append("")
    lines += [f"{i + 1}: {_label(d, recs)}" for i, (d, recs) in enumerate(zip(out_dirs, runs))]
    return lines


STUCK_TURNS = 10  # a run of alternating turns this long is a robot stuck on one spot
# a robot within this radius of one place for this many steps stands still (a look-around or a
# rescan is 12 steps on the spot)
STAND_RADIUS_M = 0.5
STAND_STEPS = 100


def longest_stand(poses: Sequence[Sequence[float]], radius_m: float = STAND_RADIUS_M) -> int:
    """The most steps an episode's robot spent within ``radius_m`` of the pose a stretch began at
    (``poses``: its (x, y, yaw) per step)."""
    best = 0
    for i, (x, y, *_) in enumerate(poses):
        j = i
        while j + 1 < len(poses) and (poses[j + 1][0] - x) ** 2 + (poses[j + 1][1] - y) ** 2 <= radius_m**2:
            j += 1
        best = max(best, j - i)
        if best >= len(poses) - 1 - i:
            break
    return best


def to_and_fro_runs(actions: Sequence[int]) -> list[int]:
    """The lengths of the runs of turns alternating left and right (``Action`` values) in an
    episode's actions: left, right, left is a run of 3; two turns the same way start a new run."""
    turns = (int(Action.TURN_LEFT), int(Action.TURN_RIGHT))
    runs, n = [], 0
    for prev, cur in zip([None, *actions], actions):
        if cur in turns and prev in turns and prev != cur:
            n += 1
        else:
            if n > 1:
                runs.append(n)
            n = 1 if cur in turns else 0
    if n > 1:
        runs.append(n)
    return runs


def same_actions(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two records of one episode took exactly the same actions (the same decisions)."""
    ta, tb = a.get("trajectory") or {}, b.get("trajectory") or {}
    return bool(ta.get("actions")) and ta.get("actions") == tb.get("actions")


def cost(records: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Median agent and simulator milliseconds per step over episodes, and episodes per hour of
    episode wall time (one worker)."""
    import statistics

    t = [r["timing"] for r in records]
    wall = sum(float(x["wall_s"]) for x in t)
    return {
        "agent_ms_per_step": statistics.median(float(x["agent_ms_per_step"]) for x in t),
        "sim_ms_per_step": statistics.median(float(x["sim_ms_per_step"]) for x in t),
        "episodes_per_hour": 3600.0 * len(t) / wall if wall > 0 else float("nan"),
    }


TIMING_FIELDS = ("timing", "modiin.median_ms", "memory.recall_ms")


def _ignored(path: str, ignore: Sequence[str]) -> bool:
    """Whether ``path`` is in ``ignore``, itself or from inside a list item (``subtasks[0].timing``
    is ``timing`` within its item)."""
    return path in ignore or ("]." in path and path.rsplit("].", 1)[1] in ignore)


def record_differences(a: Any, b: Any, ignore: Sequence[str] = (), path: str = "") -> list[str]:
    """Dotted paths where two records differ (``ignore``: paths left out, with their subtrees,
    also inside list items; a key only one side has is a difference, listed as ``path (only in
    the first/second)``)."""
    if _ignored(path, ignore):
        return []
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            sub = f"{path}.{k}" if path else str(k)
            if _ignored(sub, ignore):
                continue
            if k not in b:
                out.append(f"{sub} (only in the first)")
            elif k not in a:
                out.append(f"{sub} (only in the second)")
            else:
                out += record_differences(a[k], b[k], ignore, sub)
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in record_differences(x, y, ignore, f"{path}[{i}]")]
    return [] if a == b else [path or "(record)"]


def identical(base_dir: str, other_dir: str, ignore: Sequence[str] = ()) -> tuple[int, list[str]]:
    """(episodes compared, lines naming each difference) between two runs' records."""
    a, b = load_records(base_dir), load_records(other_dir)
    common = sorted(set(a) & set(b))
    lines = []
    for eid in common:
        diffs = record_differences(a[eid], b[eid], (*TIMING_FIELDS, *ignore))
        lines += [f"{eid}: {d}: {_short(a[eid], d)} -> {_short(b[eid], d)}" for d in diffs]
    return len(common), lines


def _short(rec: Mapping[str, Any], dotted: str) -> str:
    v: Any = rec
    for part in dotted.split(" (")[0].replace("]", "").replace("[", ".").split("."):
        if isinstance(v, Mapping):
            v = v.get(part)
        elif isinstance(v, list) and part.isdigit() and int(part) < len(v):
            v = v[int(part)]
        else:
            return "?"
    text = json.dumps(v)
    return text if len(text) <= 120 else text[:117] + "..."


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim.evaluation.compare", description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dirs", nargs="+", help="imgnav eval output directories; the first is the base")
    ap.add_argument("--all", action="store_true", help="first table on each run's own episodes (unpaired)")
    ap.add_argument(
        "--outcomes", action="store_true", help="also each episode some run failed, with its cause in every run"
    )
    ap.add_argument(
        "--identical",
        action="store_true",
        help="check that the second run's records equal the first's, field for field, apart from timings",
    )
    ap.add_argument(
        "--ignore",
        nargs="*",
        default=[],
        metavar="PATH",
        help="with --identical: dotted record fields to leave out (e.g. agent_config)",
    )
    args = ap.parse_args(argv)
    try:
        if args.identical:
            if len(args.out_dirs) != 2:
                raise ValueError("--identical compares exactly two runs")
            n, lines = identical(args.out_dirs[0], args.out_dirs[1], args.ignore)
            print("\n".join(lines) if lines else "")
            print(
                f"{n} episodes compared: {'identical' if not lines else f'{len(lines)} differences'} "
                f"(timings{' and ' + ', '.join(args.ignore) if args.ignore else ''} left out)"
            )
            return 0 if not lines else 1
        print(compare(args.out_dirs, paired=not args.all, outcomes=args.outcomes))
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
