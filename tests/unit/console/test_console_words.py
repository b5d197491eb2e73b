"""Runs and steps in words."""

from __future__ import annotations

from console.words import distance_driven_m, duration_words, run_summary, step_words, timing_rows


def test_durations() -> None:
    assert duration_words(4.26) == "4.3 s" and duration_words(42) == "42 s"
    assert duration_words(214) == "3 min 34 s" and duration_words(3900) == "1 h 5 min" and duration_words(None) == ""


def _run(**kw):
    base = {"status": "finished", "n_steps": 82, "started_s": 100.0, "ended_s": 314.0, "target": {"category": "couch"}}
    return base | kw


def test_found_it() -> None:
    s = run_summary(_run(outcome="success", metrics={"ne_m": 0.41, "path_length_m": 6.04}))
    assert s["headline"] == "Found it" and s["tone"] == "good"
    assert s["sentence"] == "Found it: stopped 0.4 m from the couch after 82 steps, 6.0 m driven, 3 min 34 s."


def test_gave_up_and_budget_and_wrong_place() -> None:
    gave_up = run_summary(
        _run(
            outcome="failure",
            n_steps=640,
            metrics={"ne_m": 3.0},
            outcome_detail="the agent gave up (exhausted): no reachable frontier and no goal candidate",
        )
    )
    assert gave_up["headline"] == "Gave up"
    assert gave_up["sentence"].startswith("Gave up after 640 steps") and "no reachable frontier" in gave_up["sentence"]
    budget = run_summary(_run(outcome="failure", n_steps=1000, metrics={"max_steps_reached": True, "ne_m": 4.2}))
    assert budget["headline"] == "Ran out of steps" and "1000 steps" in budget["sentence"]
    wrong = run_summary(
        _run(
            outcome="failure",
            metrics={"ne_m": 2.26},
            outcome_detail="the agent stopped at what it took for the object: within stop radius",
        )
    )
    assert wrong["headline"] == "Wrong place" and "2.3 m from the couch" in wrong["sentence"]


def test_stopped_failed_unscored_active() -> None:
    assert run_summary(_run(status="stopped", outcome="stopped"))["sentence"].startswith(
        "Stopped by the operator after 82 steps"
    )
    failed = run_summary(
        _run(status="failed", outcome="error", outcome_detail="backend error (disconnected): no state for 1.2 s")
    )
    assert failed["headline"] == "Failed" and "disconnected" in failed["sentence"]
    unscored = run_summary(
        _run(
            outcome="unscored",
            target=None,
            outcome_detail="the agent stopped at what it took for the object: facing it",
        )
    )
    assert "Not scored" in unscored["sentence"] and "facing it" in unscored["sentence"]
    assert run_summary({"status": "running", "n_steps": 5})["sentence"] == "Running: 5 steps so far."


def test_steps_and_timings() -> None:
    words = step_words(
        {
            "step": 11,
            "mode": "explore",
            "reason": "frontier (nearest)",
            "action_name": "TURN_LEFT",
            "reid_score": 4.13,
            "reid_tau": 75.3,
        }
    )
    assert words == "Step 12: exploring (frontier (nearest)), turn left, match 4.1 of 75.3 needed"
    gated = step_words(
        {
            "step": 3,
            "mode": "explore",
            "action_name": "MOVE_FORWARD",
            "reid_score": 0.0,
            "reid_tau": 75.3,
            "reid_full_matcher": False,
            "reid_gate_score": 12.0,
        }
    )
    assert gated == "Step 4: exploring, forward, goal not in view (quick check 12)"
    exited = step_words(
        {
            "step": 4,
            "mode": "explore",
            "action_name": "TURN_RIGHT",
            "reid_score": 0.0,
            "reid_tau": 75.3,
            "reid_full_matcher": False,
            "reid_gate_score": 40.0,
            "reid_exit_score": 1.234,
        }
    )
    assert exited == "Step 5: exploring, turn right, goal not in view (early match 1.2)"
    assert distance_driven_m([{"x_m": 0, "y_m": 0}, {"x_m": 3, "y_m": 4}, {"x_m": 3, "y_m": 4}]) == 5.0
    rows = dict(timing_rows({"upload_to_first_action_s": 0.82, "mean_step_ms": 107.2, "total_s": 214}))
    assert rows == {"upload to first move": "0.8 s", "per step (mean)": "107 ms", "total": "3 min 34 s"}
