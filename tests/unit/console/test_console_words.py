"""Runs and steps in words."""

from __future__ import annotations

from console.words import distance_driven_m, duration_words, run_summary, step_detail, step_words, timing_rows


def test_durations() -> None:
    assert duration_words(4.26) == "4.3 s" and duration_words(42) == "42 s"
    assert duration_words(214) == "3 min 34 s" and duration_words(3900) == "1 h 5 min" and duration_words(None) == ""


def _run(**kw):
    base = {"status": "finished", "n_steps": 82, "started_s": 100.0, "ended_s": 314.0, "target": {"category": "couch"}}
    return base | kw


def test_found_it() -> None:
    s = run_summary(_run(outcome="success", metrics={"ne_m": 0.41, "path_length_m": 6.04}))
    assert s["headline"] == "Found it" and s["tone"] == "good"
    # the sentence follows the headline on the pages: it does not repeat it (issue 33: "Found it Found it")
    assert s["sentence"] == (
        "Stopped at the couch after 82 steps, 6.0 m driven, 3 min 34 s (0.4 m from the nearest viewpoint of the couch)."
    )


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
    assert gave_up["sentence"].startswith("Nowhere left to explore") and "after 640 steps" in gave_up["sentence"]
    # the agent's own words are the technical detail, not the sentence
    assert "frontier" not in gave_up["sentence"] and "no reachable frontier" in gave_up["detail"]
    budget = run_summary(_run(outcome="failure", n_steps=1000, metrics={"max_steps_reached": True, "ne_m": 4.2}))
    assert budget["headline"] == "Ran out of steps" and "1000 steps" in budget["sentence"]
    wrong = run_summary(
        _run(
            outcome="failure",
            metrics={"ne_m": 2.26},
            outcome_detail="the agent stopped at what it took for the object: within stop radius",
        )
    )
    for s in (gave_up, budget, wrong):
        assert not s["sentence"].lower().startswith(s["headline"].lower()), s
    assert wrong["headline"] == "Wrong place" and "2.3 m from the nearest viewpoint of the couch" in wrong["sentence"]
    assert "stop radius" not in wrong["sentence"] and "stop radius" in wrong["detail"]


def test_stopped_failed_unscored_active() -> None:
    assert run_summary(_run(status="stopped", outcome="stopped"))["sentence"].startswith(
        "The operator stopped the run after 82 steps"
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
    assert "Not scored" in unscored["sentence"] and "facing it" in unscored["detail"]
    assert run_summary({"status": "running", "n_steps": 5})["sentence"] == "5 steps so far."
    stopped = run_summary(_run(status="stopped", outcome="stopped"))
    for s in (failed, unscored, stopped):  # never "Found it Found it", "Stopped Stopped by ..."
        assert not s["sentence"].lower().startswith(s["headline"].lower()), s


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
    assert words == "Step 12: exploring, turn left, match 4.1 of 75.3 needed"  # older records: the mode
    planned = {
        "step": 69,
        "mode": "approach",
        "event": "stop_at_goal",
        "context": ["last_resort"],
        "action_name": "STOP",
    }
    planned |= {"reason": "within stop radius, facing the goal (close-range verification off; 96 of 96 core points)"}
    assert step_words(planned) == (
        "Step 70: at the object and facing it: stopping (back to the best candidate left), stop"
    )
    assert "verification" in step_detail(planned) and "stop_at_goal in last_resort" in step_detail(planned)
    gated_step = {
        "step": 3,
        "mode": "explore",
        "action_name": "MOVE_FORWARD",
        "reid_score": 0.0,
        "reid_tau": 75.3,
        "reid_full_matcher": False,
        "reid_gate_score": 12.0,
    }
    gated = step_words(gated_step)
    assert gated == "Step 4: exploring, forward, goal not in view" and "gate score 12" in step_detail(gated_step)
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
    assert exited == "Step 5: exploring, turn right, goal not in view"
    assert distance_driven_m([{"x_m": 0, "y_m": 0}, {"x_m": 3, "y_m": 4}, {"x_m": 3, "y_m": 4}]) == 5.0
    rows = dict(timing_rows({"upload_to_first_action_s": 0.82, "mean_step_ms": 107.2, "total_s": 214}))
    assert rows == {"upload to first move": "0.8 s", "per step (mean)": "107 ms", "total": "3 min 34 s"}


def test_every_event_and_context_of_the_agent_has_words_for_the_operator() -> None:
    from agent.events import Context, Event
    from console.words import CONTEXT_WORDS, EVENT_WORDS

    assert set(EVENT_WORDS) == {e.value for e in Event}
    assert set(CONTEXT_WORDS) == {c.value for c in Context}
    step = {"step": 40, "event": "frontier", "context": ["no_way_yet"], "action_name": "MOVE_FORWARD"}
    assert step_words(step).startswith("Step 41: exploring (no way to the object yet, looking for one)")
    stop = {"step": 22, "event": "stop_at_goal", "context": ["from_memory"], "action_name": "STOP"}
    assert step_words(stop).startswith(
        "Step 23: at the object and facing it: stopping (known from memory only, not seen again in this run)"
    )
