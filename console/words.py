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
    """``{"headline", "sentence", "tone"}`` for a run row (console.store). tone: good | bad | neutral | active."""
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
    agent_why = _agent_reason(detail)

    if status in ("pending", "running", "stopping"):
        return {
            "headline": STATUS_WORDS[status],
            "sentence": f"{STATUS_WORDS[status]}: {_steps(n)} so far.",
            "tone": "active",
        }
    if status == "failed":
        return {
            "headline": "Failed",
            "sentence": f"Failed {tail}: {detail or 'an error ended the run'}.",
            "tone": "bad",
        }
    if status == "interrupted":
        return {
            "headline": "Interrupted",
            "sentence": f"Interrupted {tail}: the console stopped while the run was active.",
            "tone": "bad",
        }
    if status == "stopped" or outcome == "stopped":
        return {"headline": "Stopped", "sentence": f"Stopped by the operator {tail}.", "tone": "neutral"}
    ne = metrics.get("ne_m")
    if outcome == "success":
        near = f" {ne:.1f} m from {what}" if isinstance(ne, (int, float)) else f" at {what}"
        return {"headline": "Found it", "sentence": f"Found it: stopped{near} {tail}.", "tone": "good"}
    budget = bool(metrics.get("max_steps_reached")) or "budget" in detail
    if outcome == "failure":
        if budget:
            sentence = f"Ran out of steps: the whole budget of {_steps(n)} was used without finding {what}"
            sentence += "".join(f", {e}" for e in extras[1:]) + "."
            return {"headline": "Ran out of steps", "sentence": sentence, "tone": "bad"}
        if "gave up" in detail or "exhausted" in detail:
            return {
                "headline": "Gave up",
                "sentence": f"Gave up {tail}: {agent_why or 'nothing left to explore'}.",
                "tone": "bad",
            }
        far = f" {ne:.1f} m from {what}" if isinstance(ne, (int, float)) else ""
        why = f" ({agent_why})" if agent_why else ""
        return {
            "headline": "Wrong place",
            "sentence": f"Stopped{far}, not close enough to it, {tail}{why}.",
            "tone": "bad",
        }
    # unscored: the target is unknown (a real home, or a photo of something the simulator cannot name)
    if budget:
        return {
            "headline": "Ran out of steps",
            "sentence": f"Ran out of steps {tail} without stopping (not scored).",
            "tone": "neutral",
        }
    if "gave up" in detail or "exhausted" in detail:
        return {
            "headline": "Gave up",
            "sentence": f"Gave up {tail}: {agent_why or 'nothing left to explore'} (not scored).",
            "tone": "neutral",
        }
    why = f": {agent_why}" if agent_why else ""
    return {
        "headline": "Stopped at what it took for the object",
        "sentence": f"Stopped at what it took for the object {tail}{why}. Not scored: the goal's true position is unknown.",
        "tone": "neutral",
    }


def _agent_reason(detail: str) -> str:
    """The agent's own words in an outcome detail ("the agent gave up (exhausted): no reachable
    frontier ..." -> "no reachable frontier ...")."""
    first = detail.split("; ")[0]
    if first.startswith("the agent") and ": " in first:
        return first.split(": ", 1)[1]
    return ""


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


def step_words(step: Mapping[str, Any]) -> str:
    """One step as a sentence: "Step 12: exploring (frontier ...), turn left; match 4.1 of 75.3"."""
    parts = [f"Step {int(step.get('step', 0)) + 1}: {mode_words(step.get('mode')) or 'acting'}"]
    if step.get("reason"):
        parts[0] += f" ({step['reason']})"
    action = step.get("action_name")
    if action:
        parts.append(action_words(action))
    score, tau = step.get("reid_score"), step.get("reid_tau")
    gate, exit_score = step.get("reid_gate_score"), step.get("reid_exit_score")
    if step.get("reid_full_matcher") is False and isinstance(exit_score, (int, float)):
        # the matcher's first layers already matched too little of the goal photo to go on
        parts.append(f"goal not in view (early match {exit_score:.1f})")
    elif step.get("reid_full_matcher") is False and isinstance(gate, (int, float)):
        # the cheap first stage saw too little in common with the goal photo to run the matcher
        parts.append(f"goal not in view (quick check {gate:.0f})")
    elif isinstance(score, (int, float)):
        parts.append(f"match {score:.1f}" + (f" of {tau:.1f} needed" if isinstance(tau, (int, float)) else ""))
    return ", ".join(parts)
