"""A run and its steps in words for people (the pages and the viewer say the same thing).

The numbers stay available (metrics, timings) for a compact table; these sentences say
what happened: "Found it: stopped 0.4 m from the couch after 82 steps, 6.0 m driven,
3 min 34 s."
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

# The agent's modes (agent.modes.Mode) as an operator would say them.
MODE_WORDS: dict[str, str] = {
    "look_around": "looking around",
    "explore": "exploring",
    "approach": "driving to the object",
    "verify": "checking the object up close",
    "rescan": "looking around again",
    "stopped": "stopped at the object",
    "exhausted": "gave up",
    "last_resort": "going back to the best candidate left",
}

ACTION_WORDS: dict[str, str] = {
    "STOP": "stop",
    "MOVE_FORWARD": "forward",
    "TURN_LEFT": "turn left",
    "TURN_RIGHT": "turn right",
}

STATUS_WORDS: dict[str, str] = {
    "pending": "Starting",
    "running": "Running",
    "stopping": "Stopping",
    "finished": "Finished",
    "stopped": "Stopped",
    "failed": "Failed",
    "interrupted": "Interrupted",
}


def mode_words(mode: str | None) -> str:
    if not mode:
        return ""
    return MODE_WORDS.get(mode, mode.replace("_", " "))


def action_words(name: str | None) -> str:
    if not name:
        return ""
    return ACTION_WORDS.get(name, name.replace("_", " ").lower())


def duration_words(seconds: float | None) -> str:
    """42 s, 3 min 34 s, 1 h 5 min."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return ""
    s = int(round(seconds))
    if s < 60:
        return f"{seconds:.1f} s" if seconds < 10 else f"{s} s"
    m, s = divmod(s, 60)
    if m < 60:
        return f"{m} min {s} s" if s else f"{m} min"
    h, m = divmod(m, 60)
    return f"{h} h {m} min" if m else f"{h} h"


def size_words(n_bytes: int) -> str:
    """25 MB, 20 kB, 100 bytes (binary multiples, as the limits are set)."""
    for unit, size in (("MB", 2**20), ("kB", 2**10)):
        if n_bytes >= size:
            value = n_bytes / size
            return f"{value:.0f} {unit}" if value >= 10 or value == int(value) else f"{value:.1f} {unit}"
    return f"{n_bytes} bytes"


def distance_driven_m(steps: Iterable[Mapping[str, Any]]) -> float:
    """Sum of the position changes between consecutive steps (start-relative poses)."""
    total, last = 0.0, None
    for s in steps:
        x, y = s.get("x_m"), s.get("y_m")
        if x is None or y is None:
            continue
        if last is not None:
            total += math.hypot(x - last[0], y - last[1])
        last = (x, y)
    return total


def _steps(n: int) -> str:
    return f"{n} step" if n == 1 else f"{n} steps"


def run_summary(run: Mapping[str, Any], driven_m: float | None = None) -> dict[str, str]:
    """``{"headline", "sentence", "tone", "detail"}`` for a run row (console.store).

    The page shows the headline, then the sentence: the sentence never repeats the headline.
    tone: good | bad | neutral | active. ``detail``: the run's technical account (the agent's
    reason, the backend's note), for a disclosure beside the plain words."""
    status = run.get("status") or ""
    outcome = run.get("outcome") or ""
    detail = run.get("outcome_detail") or ""
    n = int(run.get("n_steps") or 0)
    metrics = run.get("metrics") or {}
    target = run.get("target") or {}
    what = target.get("category") or "the object"
    if what != "the object":
        what = f"the {what}"
    started, ended = run.get("started_s"), run.get("ended_s")
    took = duration_words(ended - started) if started and ended else ""
    if driven_m is None and isinstance(metrics.get("path_length_m"), (int, float)):
        driven_m = float(metrics["path_length_m"])
    extras = [_steps(n)]
    if driven_m is not None:
        extras.append(f"{driven_m:.1f} m driven")
    if took:
        extras.append(took)
    tail = f"after {extras[0]}" + ("".join(f", {e}" for e in extras[1:]))

    def said(headline: str, sentence: str, tone: str) -> dict[str, str]:
        return {"headline": headline, "sentence": sentence, "tone": tone, "detail": detail}

    if status in ("pending", "running", "stopping"):
        return said(STATUS_WORDS[status], f"{_steps(n).capitalize()} so far.", "active")
    if status == "failed":
        return said("Failed", f"An error ended the run {tail}: {detail or 'no reason was given'}.", "bad")
    if status == "interrupted":
        return said("Interrupted", f"The console stopped while the run was active, {tail}.", "bad")
    if status == "stopped" or outcome == "stopped":
        return said("Stopped", f"The operator stopped the run {tail}.", "neutral")
    ne = metrics.get("ne_m")
    # ne_m is the distance to the nearest place the object is seen from (sim.metrics), not to the object
    near = f" ({ne:.1f} m from the nearest viewpoint of {what})" if isinstance(ne, (int, float)) else ""
    budget = bool(metrics.get("max_steps_reached")) or "budget" in detail
    gave_up = "gave up" in detail or "exhausted" in detail  # the console's own prefix (console.manager)
    scored = "" if outcome in ("success", "failure") else " Not scored: the object's true position is unknown."
    tone = "neutral" if scored else "bad"
    if outcome == "success":
        return said("Found it", f"Stopped at {what} {tail}{near}.", "good")
    if budget:
        sentence = f"The whole budget of {_steps(n)} was used without stopping at {what}"
        return said("Ran out of steps", sentence + "".join(f", {e}" for e in extras[1:]) + "." + scored, tone)
    if gave_up:
        return said("Gave up", f"Nowhere left to explore and no candidate for {what}, {tail}.{scored}", tone)
    if outcome == "failure":
        return said("Wrong place", f"Stopped, but not close enough to {what}, {tail}{near}.", "bad")
    return said("Stopped at what it took for the object", f"It stopped by itself {tail}.{scored}", "neutral")


def timing_rows(timings: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The run's timings as (label, value with unit) for a compact table."""
    rows = []
    labels = [
        ("upload_to_first_action_s", "upload to first move", "s"),
        ("open_s", "preparing robot and agent", "s"),
        ("reset_s", "first observation", "s"),
        ("mean_step_ms", "per step (mean)", "ms"),
        ("artifacts_s", "writing the files", "s"),
        ("total_s", "total", "s"),
    ]
    for key, label, unit in labels:
        v = timings.get(key)
        if isinstance(v, (int, float)) and math.isfinite(v):
            rows.append((label, f"{v:.0f} ms" if unit == "ms" else duration_words(v)))
    return rows


# What a step does (agent.events.Event values) and what it was decided in (agent.events.Context
# values), as an operator would say them. The agent's own reason is the technical line (step_detail).
EVENT_WORDS: dict[str, str] = {
    "look_around": "looking around",
    "frontier": "exploring",
    "rescan": "nowhere new to explore: looking around again",
    "exhausted": "nowhere left to explore and no candidate: giving up",
    "approach": "driving to the object",
    "goal_not_reachable_yet": "turning to find a way to the object",
    "face_goal": "at the object, turning to face it",
    "stop_at_goal": "at the object and facing it: stopping",
    "verify_approach": "driving closer to check a possible match",
    "verify_ring_not_reachable_yet": "turning to find a way to check a possible match",
    "verify_face": "turning to look at a possible match",
    "verify_look": "checking a possible match up close",
    "verify_step_nearer": "checking a possible match, stepping nearer",
}

CONTEXT_WORDS: dict[str, str] = {
    "side_step": "stepping aside after turning to and fro",
    "fresh_map": "nowhere left to explore: map started afresh",
    "second_look": "a second look at the views kept",
    "deadline": "few steps left",
    "deadline_over_weaker": "few steps left",
    "last_resort": "back to the best candidate left",
    "ring_confirmed": "recognised from nearby",
    "no_way_yet": "no way to the object yet, looking for one",
    "from_memory": "known from memory only, not seen again in this run",
    "marks_dropped": "trying again where a move failed: the way round is much longer",
}


def doing_words(step: Mapping[str, Any]) -> str:
    """What the robot is doing at a step, in plain words: its event (and contexts) when the
    record has them, else its mode (older runs)."""
    event = step.get("event")
    text = EVENT_WORDS.get(event, "") if isinstance(event, str) else ""
    if not text:
        return mode_words(step.get("mode")) or "acting"
    contexts = [CONTEXT_WORDS[c] for c in step.get("context") or () if c in CONTEXT_WORDS]
    if contexts:
        text += f" ({'; '.join(dict.fromkeys(contexts))})"
    return text


def step_words(step: Mapping[str, Any]) -> str:
    """One step as a sentence for the operator: "Step 12: exploring, turn left, match 4.1 of 75.3
    needed". The agent's technical reason is ``step_detail``."""
    parts = [f"Step {int(step.get('step', 0)) + 1}: {doing_words(step)}"]
    action = step.get("action_name")
    if action:
        parts.append(action_words(action))
    score, tau = step.get("reid_score"), step.get("reid_tau")
    if step.get("reid_full_matcher") is False:
        parts.append("goal not in view")  # a cheap first check saw too little of the goal photo
    elif isinstance(score, (int, float)):
        parts.append(f"match {score:.1f}" + (f" of {tau:.1f} needed" if isinstance(tau, (int, float)) else ""))
    return ", ".join(parts)


def step_detail(step: Mapping[str, Any]) -> str:
    """The technical line behind a step's words: the agent's reason, its event and contexts, and
    which stage of re-identification answered."""
    parts = []
    if step.get("reason"):
        parts.append(f"agent: {step['reason']}")
    if step.get("event"):
        ctx = ", ".join(step.get("context") or ())
        parts.append(f"event {step['event']}" + (f" in {ctx}" if ctx else ""))
    gate, exit_score = step.get("reid_gate_score"), step.get("reid_exit_score")
    if step.get("reid_full_matcher") is False and isinstance(exit_score, (int, float)):
        parts.append(f"re-ID: early exit at {exit_score:.1f}")
    elif step.get("reid_full_matcher") is False and isinstance(gate, (int, float)):
        parts.append(f"re-ID: gate score {gate:.0f}, matcher not run")
    elif isinstance(step.get("reid_score"), (int, float)):
        parts.append(f"re-ID: score {step['reid_score']:.2f}, tau {step.get('reid_tau')}")
    return "; ".join(parts)
