"""The decision's typed events and the sentence written from them (agent.events)."""

import pytest

from agent.events import CONTEXT_ORDER, Context, Event, Note, event_facts, sentence
from agent.modes import Decision, Mode
from agent.types import Action


def test_every_event_and_context_has_a_sentence():
    facts = {"turn": 1, "turns": 12, "choice": "new", "look": 3}
    for event in Event:
        assert sentence(event, facts, ()).strip()
    notes = {
        Context.SECOND_LOOK: dict(added=2, kept=16, best=31.25),
        Context.DEADLINE: dict(steps_left=40),
        Context.DEADLINE_OVER_WEAKER: dict(steps_left=40, score=5.0),
        Context.LAST_RESORT: dict(score=61.0),
        Context.RING_CONFIRMED: dict(score=60.0),
        Context.NO_WAY_YET: dict(score=120.0),
        Context.FROM_MEMORY: dict(score=133.6),
        Context.SIDE_STEP: {},
        Context.FRESH_MAP: dict(steps_left=640, dropped=1234),
        Context.MARKS_DROPPED: dict(was_m=7.2, now_m=1.8),
    }
    assert set(notes) == set(Context)
    for ctx, f in notes.items():
        assert sentence(Event.APPROACH, {}, (Note.of(ctx, **f),)).endswith("navigating to the goal candidate")


def test_contexts_enclose_each_other_in_a_fixed_order_whatever_order_they_were_added_in():
    base = Decision(Action.STOP, Mode.STOPPED, Event.STOP_AT_GOAL)
    inner_first = base.within(Context.LAST_RESORT, score=61.04).within(Context.DEADLINE, steps_left=41)
    outer_first = base.within(Context.DEADLINE, steps_left=41).within(Context.LAST_RESORT, score=61.04)
    want = "41 steps of the budget left: last resort (rejected candidate, best score 61.0): within stop radius, facing the goal"
    assert inner_first.reason == outer_first.reason == want
    side = Decision(Action.MOVE_FORWARD, Mode.APPROACH, Event.APPROACH).within(Context.RING_CONFIRMED, score=60.0)
    side = side.within(Context.SIDE_STEP)
    assert (
        side.reason == "side-step out of turning to and fro; re-identified from the verify ring (score 60); "
        "navigating to the goal candidate"
    )
    assert CONTEXT_ORDER[0] == Context.SIDE_STEP and side.has(Context.RING_CONFIRMED) and not side.has(Context.DEADLINE)


def test_the_second_look_says_what_it_found():
    d = Decision(Action.TURN_LEFT, Mode.VERIFY, Event.VERIFY_LOOK, event_facts(look=2))
    d = d.within(Context.SECOND_LOOK, added=3, kept=16, best=12.345)
    assert d.reason == (
        "exhausted, second look with the full matcher: 3 of the 16 frames kept added points "
        "(best score 12.3); verify: look 2"
    )


def test_facts_are_read_only():
    d = Decision(Action.TURN_LEFT, Mode.LOOK_AROUND, Event.LOOK_AROUND, event_facts(turn=1, turns=12))
    assert d.reason == "initial look-around 1/12"
    with pytest.raises(TypeError):
        d.facts["turn"] = 2  # type: ignore[index]
