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

``--from-step N`` splices the last resort at the deadline (``policy.last_resort_at_deadline``): it
checks only in the last ``deadline_window_steps`` of the budget, so it cannot act before step N
(1000 - 200 = 800 by default), and the base episodes that ended by then are untouched.

``--oscillation N`` splices the turn-in-place guard (``policy.oscillation_turns: N``) instead: it
acts only after N alternating turns in a row, so the base episodes without such a run are
untouched, and a re-run must repeat its base up to the action that completed the run.

``--rejected`` splices a change that acts only in place of a candidate's rejection
(``policy.unreachable_forgive``): the base episodes that rejected no candidate are untouched, and
a re-run must repeat its base up to the first step with any re-identification score (no candidate
exists before it).

``--in-mode MODE`` splices a change that acts only in one mode of the policy (a look from the
verify ring: ``--in-mode verify``, ``policy.verify_ring_tau_ratio``): the base episodes that spent
no step in that mode (the record's ``modes`` count) are untouched, and a re-run must repeat its
base up to the first step with any re-identification score (no candidate, so no verification,
exists before it).

``--event EVENT`` (repeatable; ``EVENT:N``: at least N steps with it) splices a change that acts
only at a step with one of these events (going nearer when the map shows no way, tried and removed,
docs/experiments/go-nearer.md: ``--event goal_not_reachable_yet --event
verify_ring_not_reachable_yet --event rescan:12``): the base episodes without such a step are
untouched, and a re-run must repeat its base up to its first re-identification score (a
candidate's events), or is only checked to be the same episode when the base had a search event
(a rescan can come before any score).

``--collided`` (with ``--event``) narrows it to the base episodes that also had a forward move
that did not move the robot (the agent's own collision test, on its estimated pose): a change that
acts only while a collision mark is on the map (dropping the marks that made the way to a
candidate a detour, ``policy.detour_forgive_m``: ``--event approach --event verify_approach
--collided``); a re-run must repeat its base up to the later of its first re-identification score
and its first failed move.

``--list`` prints the base episodes where the change acts (the ids to re-run with
``imgnav eval --episode-ids``) instead of splicing: ``splice BASE --list --oscillation 4``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.evaluation.runner import RECORDS, SUMMARY, _json_safe, read_records

# events of the search (no goal candidate needed): they can come before any score
SEARCH_EVENTS = frozenset({"look_around", "frontier", "rescan", "exhausted"})


@dataclass(frozen=True, slots=True)
class ActsAt:
    """Where a change can first act in a base episode.

    ``ended_in``: at the base's final step, when the episode ended in that final mode (the last
    resort acts where the base stopped ``exhausted``). ``oscillation``: at the step after the
    base's first run of that many alternating turns (left, right, left, ... on the spot; the
    turn-in-place guard counts the same run of the agent's own actions). ``from_step``: at any
    step from that one on, in the base episodes that went on past it (the last resort at the
    deadline checks only in the last ``deadline_window_steps`` of the budget)."""

    ended_in: str | None = None
    oscillation: int | None = None
    from_step: int | None = None
    rejected: bool = False
    in_mode: str | None = None
    # ... at least this many steps in it (the rescans spent: rescan, 3 x 12; docs/experiments/fresh-map.md)
    in_mode_steps: int = 1
    # where the base's steps include one of these events (the record's ``events`` count;
    # ``EVENT:N``: at least N such steps): going nearer when the map shows no way (tried and
    # removed, docs/experiments/go-nearer.md) acted only where the base had no plan to a candidate
    # (goal_not_reachable_yet, verify_ring_not_reachable_yet) or had done a whole rescan (rescan:12)
    events: tuple[str, ...] = ()
    # ... and only after a forward move that did not move the robot (a collision mark is on the map)
    collided: bool = False

    def untouched(self, rec: dict[str, Any]) -> int | None:
        """How many of the base's leading actions the change cannot alter (None: it never acts)."""
        actions = (rec.get("trajectory") or {}).get("actions") or []
        if self.from_step is not None:
            return self.from_step if len(actions) > self.from_step else None
        if self.oscillation is not None:
            k = first_oscillation(actions, self.oscillation)
            return None if k is None else k + 1
        if self.rejected:
            return first_score_step(rec) if rejected_any(rec) else None
        if self.in_mode is not None:
            spent = ((rec.get("modiin") or {}).get("modes") or {}).get(self.in_mode) or 0
            return first_score_step(rec) if spent >= max(self.in_mode_steps, 1) else None
        if self.events:
            counts = (rec.get("modiin") or {}).get("events") or {}
            had = [e for e, n in map(_event_count, self.events) if (counts.get(e) or 0) >= n]
            if not had:
                return None
            # a candidate's events come after a score; a search event (a rescan) may come first
            n = 0 if any(e in SEARCH_EVENTS for e in had) else first_score_step(rec)
            if self.collided:
                k = first_failed_move(rec)
                return None if k is None else max(n, k + 1)
            return n
        if (rec.get("modiin") or {}).get("final_mode") != self.ended_in:
            return None
        return max(len(actions) - 1, 0)

    def why_not(self, rec: dict[str, Any]) -> str:
        if self.from_step is not None:
            return f"the base ended within its first {self.from_step} steps"
        if self.oscillation is not None:
            return f"the base never turned to and fro {self.oscillation} times in a row"
        if self.rejected:
            return "the base rejected no candidate"
        if self.in_mode is not None:
            if self.in_mode_steps > 1:
                return f"the base spent fewer than {self.in_mode_steps} steps in mode {self.in_mode!r}"
            return f"the base spent no step in mode {self.in_mode!r}"
        if self.events:
            also = " after a failed forward move" if self.collided else ""
            return f"the base had no step with event {' or '.join(self.events)}{also}"
        return f"the base ended in {(rec.get('modiin') or {}).get('final_mode')!r}, not {self.ended_in!r}"


def _event_count(spec: str) -> tuple[str, int]:
    """``EVENT`` or ``EVENT:N`` (at least N steps with it) as (event, N)."""
    name, _, n = spec.partition(":")
    return name, int(n) if n else 1


def rejected_any(rec: dict[str, Any]) -> bool:
    """Whether the base episode's record lists a rejected goal candidate."""
    return any(c.get("state") == "rejected" for c in (rec.get("modiin") or {}).get("candidates") or [])


def first_score_step(rec: dict[str, Any]) -> int:
    """The first step whose re-identification score was above zero (the record's per-step trace):
    no goal candidate, so no rejection, can exist before it. 0 when the trace is missing."""
    scores = ((rec.get("modiin") or {}).get("trace") or {}).get("reid_score") or []
    return next((k for k, v in enumerate(scores) if v and v > 0), 0)


def first_failed_move(rec: dict[str, Any]) -> int | None:
    """Index of the base's first forward move after which its estimated pose (the agent's own
    collision test, ``policy.collision_min_motion_m``; the true pose when no estimate is recorded)
    had moved less than 5 cm, or None."""
    from agent.types import Action

    t = rec.get("trajectory") or {}
    poses = t.get("poses_estimate_world") or t.get("poses_world") or []
    for k, a in enumerate(t.get("actions") or []):
        act = Action[a] if isinstance(a, str) else Action(int(a))
        if act == Action.MOVE_FORWARD and k + 1 < len(poses):
            (x0, y0, *_), (x1, y1, *_) = poses[k], poses[k + 1]
            if ((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5 < 0.05:
                return k
    return None


def _turn(a: Any) -> int:
    """+1 for a left turn, -1 for a right turn, 0 otherwise (actions as ints or names)."""
    from agent.types import Action

    act = Action[a] if isinstance(a, str) else Action(int(a))
    return {Action.TURN_LEFT: 1, Action.TURN_RIGHT: -1}.get(act, 0)


def first_oscillation(actions: Sequence[Any], n: int) -> int | None:
    """Index of the action that completes the first run of ``n`` alternating turns, or None."""
    run, prev = 0, 0
    for k, a in enumerate(actions):
        t = _turn(a)
        run = 0 if t == 0 else (run + 1 if prev == -t else 1)
        prev = t
        if run >= n:
            return k
    return None


def same_until(base: dict[str, Any], rerun: dict[str, Any], n_actions: int, tol_m: float = 1e-6) -> str | None:
    """None when ``rerun`` took the base's first ``n_actions`` actions from the same poses, else why not."""
    bt, rt = base.get("trajectory") or {}, rerun.get("trajectory") or {}
    bp, rp = bt.get("poses_world") or [], rt.get("poses_world") or []
    ba, ra = bt.get("actions") or [], rt.get("actions") or []
    if not ba:
        return "the base record has no trajectory"
    if len(ra) < n_actions or len(rp) < n_actions + 1:
        return f"the re-run is shorter ({len(ra)} steps) than the base's {n_actions} before the change acts"
    if ra[:n_actions] != ba[:n_actions]:
        k = next(i for i, (a, b) in enumerate(zip(ra, ba)) if a != b)
        return f"actions differ at step {k} ({ba[k]} in the base, {ra[k]} in the re-run)"
    for i in range(min(n_actions + 1, len(bp))):
        if any(abs(float(x) - float(y)) > tol_m for x, y in zip(bp[i], rp[i])):
            return f"poses differ before step {i}"
    return None


def same_until_base_end(base: dict[str, Any], rerun: dict[str, Any], tol_m: float = 1e-6) -> str | None:
    """None when ``rerun`` repeats ``base``'s trajectory up to the base's final action, else why not."""
    return same_until(base, rerun, max(len((base.get("trajectory") or {}).get("actions") or []) - 1, 0), tol_m)


def _acts_at(acts_at: ActsAt | str) -> ActsAt:
    return ActsAt(ended_in=acts_at) if isinstance(acts_at, str) else acts_at


def splice(base: list[dict[str, Any]], rerun: list[dict[str, Any]], acts_at: ActsAt | str) -> list[dict[str, Any]]:
    """The base records with the re-run's in place (base order); ValueError when a check fails.
    ``acts_at``: an ``ActsAt``, or a final mode (``ActsAt(ended_in=...)``)."""
    acts_at = _acts_at(acts_at)
    by_id = {r["episode_id"]: r for r in base}
    problems = []
    for r in rerun:
        b = by_id.get(r["episode_id"])
        if b is None:
            problems.append(f"{r['episode_id']}: not in the base")
            continue
        n = acts_at.untouched(b)
        if n is None:
            problems.append(f"{r['episode_id']}: {acts_at.why_not(b)}")
            continue
        why = same_until(b, r, n)
        if why:
            problems.append(f"{r['episode_id']}: {why}")
    if problems:
        raise ValueError("cannot splice: " + "; ".join(problems))
    new = {r["episode_id"]: r for r in rerun}
    return [new.get(b["episode_id"], b) for b in base]


def missing_reruns(base: list[dict[str, Any]], rerun: list[dict[str, Any]], acts_at: ActsAt | str) -> list[str]:
    """Base episodes where the change acts that have no re-run (the splice would keep them as they were)."""
    acts_at = _acts_at(acts_at)
    have = {r["episode_id"] for r in rerun}
    return [b["episode_id"] for b in base if acts_at.untouched(b) is not None and b["episode_id"] not in have]


def summarize(records: list[dict[str, Any]], base: str, rerun: str) -> dict[str, Any]:
    """summary.json of the spliced records (the metrics and the agent's own summary, as ``imgnav eval``)."""
    from sim.evaluation.registry import get_spec
    from sim.metrics import aggregate

    summary = aggregate([{**r, "ne": float(r["ne"])} for r in records])
    agents = sorted({str(r.get("agent")) for r in records})
    summary.update(
        {
            "agent": agents[0] if len(agents) == 1 else agents,
            "spliced_from": {"base": base, "rerun": rerun},
            "errors": sum(1 for r in records if r.get("error")),
        }
    )
    spec = get_spec(agents[0]) if len(agents) == 1 else None
    if spec is not None and spec.summarize:
        summary.update(dict(spec.summarize(records)))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base", help="imgnav eval output directory of the base variant")
    p.add_argument("rerun", nargs="?", help="imgnav eval output directory of the re-run episodes (the changed variant)")
    p.add_argument("--out")
    p.add_argument("--list", action="store_true", help="print the base episodes where the change acts and stop")
    p.add_argument("--ended-in", default="exhausted", help="the base episodes' final mode from which the change acts")
    p.add_argument(
        "--oscillation",
        type=int,
        default=None,
        metavar="N",
        help="instead: the change acts after the base's first N alternating turns on the spot",
    )
    p.add_argument(
        "--from-step",
        type=int,
        default=None,
        metavar="N",
        help="instead: the change can act only from step N on, in base episodes longer than N steps "
        "(the last resort at the deadline: step_budget - deadline_window_steps, 800)",
    )
    p.add_argument(
        "--rejected",
        action="store_true",
        help="instead: the change acts only where the base rejected a goal candidate (policy.unreachable_forgive)",
    )
    p.add_argument(
        "--in-mode",
        default=None,
        metavar="MODE",
        help="instead: the change acts only where the base spent a step in MODE "
        "(a look from the verify ring, policy.verify_ring_tau_ratio: verify)",
    )
    p.add_argument(
        "--in-mode-steps",
        type=int,
        default=1,
        metavar="N",
        help="with --in-mode: at least N steps in MODE (a change that acts once the rescans are spent: "
        "rescan, max_rescans x look_around_turns = 36)",
    )
    p.add_argument(
        "--event",
        action="append",
        default=[],
        metavar="EVENT",
        help="instead: the change acts only where the base had a step with EVENT (repeatable: any of them; "
        "EVENT:N: at least N steps with it; going nearer when the map shows no way: goal_not_reachable_yet, "
        "verify_ring_not_reachable_yet, rescan:12)",
    )
    p.add_argument(
        "--collided",
        action="store_true",
        help="with --event: only where the base also had a forward move that did not move the robot "
        "(dropping collision marks that made a detour, policy.detour_forgive_m: --event approach "
        "--event verify_approach --collided)",
    )
    args = p.parse_args(argv)
    if args.collided and not args.event:
        p.error("--collided goes with --event")
    if args.event:
        acts_at = ActsAt(events=tuple(args.event), collided=args.collided)
    elif args.from_step is not None:
        acts_at = ActsAt(from_step=args.from_step)
    elif args.rejected:
        acts_at = ActsAt(rejected=True)
    elif args.in_mode:
        acts_at = ActsAt(in_mode=args.in_mode, in_mode_steps=args.in_mode_steps)
    elif args.oscillation:
        acts_at = ActsAt(oscillation=args.oscillation)
    else:
        acts_at = ActsAt(ended_in=args.ended_in)
    if args.list:
        ids = missing_reruns(read_records(Path(args.base)), [], acts_at)
        print(" ".join(ids))
        return 0
    if args.rerun is None or args.out is None:
        p.error("RERUN and --out are required (or --list)")
    base, rerun = read_records(Path(args.base)), read_records(Path(args.rerun))
    missing = missing_reruns(base, rerun, acts_at)
    if missing:
        print(
            f"error: {len(missing)} base episode(s) where the change acts have no re-run: {', '.join(missing[:6])}",
            file=sys.stderr,
        )
        return 2
    try:
        records = splice(base, rerun, acts_at)
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
