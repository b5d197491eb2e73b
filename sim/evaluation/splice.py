"""Splice re-run episodes into an evaluation: a variant that can change only some episodes.

    python -m sim.evaluation.splice BASE RERUN --out OUT [--ended-in exhausted]

Some changes act only from a point that ends a base episode: ``policy.last_resort`` changes
nothing before the step at which the base agent stopped as ``exhausted``, so every other
episode runs identically and only the exhausted ones need running again (``imgnav eval
--episode-ids``). This writes OUT/episodes.jsonl (and summary.json): the base's records with
RERUN's records in place of the episodes RERUN holds, after checking the claim on each of them:

* the base episode ended in ``--ended-in`` (its ``modiin.final_mode``), and
* the re-run repeats the base's trajectory up to that end (the same poses before each of the
  base's steps and the same actions before its final one), so the two agents decided alike
  until the point where the change acts.

A re-run that fails a check is an error (nothing is written): the splice would not be the
variant's result.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

from sim.evaluation.runner import RECORDS, SUMMARY, _json_safe, read_records


def same_until_base_end(base: dict[str, Any], rerun: dict[str, Any], tol_m: float = 1e-6) -> str | None:
    """None when ``rerun`` repeats ``base``'s trajectory up to the base's final action, else why not."""
    bt, rt = base.get("trajectory") or {}, rerun.get("trajectory") or {}
    bp, rp = bt.get("poses_world") or [], rt.get("poses_world") or []
    ba, ra = bt.get("actions") or [], rt.get("actions") or []
    n = len(ba)
    if n == 0:
        return "the base record has no trajectory"
    if len(ra) < n - 1 or len(rp) < n:
        return f"the re-run is shorter ({len(ra)} steps) than the base's {n - 1} before its end"
    if ra[: n - 1] != ba[: n - 1]:
        k = next(i for i, (a, b) in enumerate(zip(ra, ba)) if a != b)
        return f"actions differ at step {k} ({ba[k]} in the base, {ra[k]} in the re-run)"
    for i in range(n):
        if any(abs(float(x) - float(y)) > tol_m for x, y in zip(bp[i], rp[i])):
            return f"poses differ before step {i}"
    return None


def splice(base: list[dict[str, Any]], rerun: list[dict[str, Any]], ended_in: str) -> list[dict[str, Any]]:
    """The base records with the re-run's in place (base order); ValueError when a check fails."""
    by_id = {r["episode_id"]: r for r in base}
    problems = []
    for r in rerun:
        b = by_id.get(r["episode_id"])
        if b is None:
            problems.append(f"{r['episode_id']}: not in the base")
            continue
        final = (b.get("modiin") or {}).get("final_mode")
        if final != ended_in:
            problems.append(f"{r['episode_id']}: the base ended in {final!r}, not {ended_in!r}")
            continue
        why = same_until_base_end(b, r)
        if why:
            problems.append(f"{r['episode_id']}: {why}")
    if problems:
        raise ValueError("cannot splice: " + "; ".join(problems))
    new = {r["episode_id"]: r for r in rerun}
    return [new.get(b["episode_id"], b) for b in base]


def missing_reruns(base: list[dict[str, Any]], rerun: list[dict[str, Any]], ended_in: str) -> list[str]:
    """Base episodes that ended in ``ended_in`` and have no re-run (the splice would keep them as they were)."""
    have = {r["episode_id"] for r in rerun}
    return [b["episode_id"] for b in base
            if (b.get("modiin") or {}).get("final_mode") == ended_in and b["episode_id"] not in have]


def summarize(records: list[dict[str, Any]], base: str, rerun: str) -> dict[str, Any]:
    """summary.json of the spliced records (the metrics and the agent's own summary, as ``imgnav eval``)."""
    from sim.evaluation.registry import get_spec
    from sim.metrics import aggregate

    summary = aggregate([{**r, "ne": float(r["ne"])} for r in records])
    agents = sorted({str(r.get("agent")) for r in records})
    summary.update({"agent": agents[0] if len(agents) == 1 else agents, "spliced_from": {"base": base, "rerun": rerun},
                    "errors": sum(1 for r in records if r.get("error"))})
    spec = get_spec(agents[0]) if len(agents) == 1 else None
    if spec is not None and spec.summarize:
        summary.update(dict(spec.summarize(records)))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base", help="imgnav eval output directory of the base variant")
    p.add_argument("rerun", help="imgnav eval output directory of the re-run episodes (the changed variant)")
    p.add_argument("--out", required=True)
    p.add_argument("--ended-in", default="exhausted", help="the base episodes' final mode from which the change acts")
    args = p.parse_args(argv)
    base, rerun = read_records(Path(args.base)), read_records(Path(args.rerun))
    missing = missing_reruns(base, rerun, args.ended_in)
    if missing:
        print(f"error: {len(missing)} base episode(s) ended in {args.ended_in!r} without a re-run: "
              f"{', '.join(missing[:6])}", file=sys.stderr)
        return 2
    try:
        records = splice(base, rerun, args.ended_in)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / RECORDS).write_text("".join(json.dumps(r) + "\n" for r in records))
    (out / SUMMARY).write_text(json.dumps(_json_safe(summarize(records, args.base, args.rerun)), indent=1) + "\n")
    print(f"wrote {out / RECORDS}: {len(records)} episodes, {len(rerun)} of them re-run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
