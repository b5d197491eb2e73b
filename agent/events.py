"""What the policy decided, as typed events; the prose reason is written from them.

Every step's ``Decision`` (``agent.modes``) names one ``Event`` (what the robot does this step,
with its numbers) and the ``Context`` it was decided in (the last resort, the deadline, the
second look, a look from the verify ring, a side-step), each with its own numbers. Failure
attribution, splice and tests read these; the sentence in ``AgentRecord.reason`` is written here,
for people, and nothing parses it.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any


class Event(str, enum.Enum):
    """What the robot does this step (``AgentRecord.event``)."""

    LOOK_AROUND = "look_around"  # the initial full turn; facts: turn, turns
    FRONTIER = "frontier"  # heading for a frontier; facts: choice ("new", "kept")
    RESCAN = "rescan"  # no reachable frontier: forgiving and looking around again
    EXHAUSTED = "exhausted"  # STOP: nothing left to explore and no candidate
    APPROACH = "approach"  # heading for the candidate's stop region
    GOAL_NOT_REACHABLE_YET = "goal_not_reachable_yet"  # no plan to it yet: turning to see more
    FACE_GOAL = "face_goal"  # in the stop region, turning to face it
    STOP_AT_GOAL = "stop_at_goal"  # STOP: in the stop region, facing it
    VERIFY_APPROACH = "verify_approach"  # heading for the verify ring around a potential candidate
    VERIFY_RING_NOT_REACHABLE_YET = "verify_ring_not_reachable_yet"
    VERIFY_FACE = "verify_face"  # on the ring, turning to look at the candidate
    VERIFY_LOOK = "verify_look"  # a look from the ring; facts: look
    VERIFY_STEP_NEARER = "verify_step_nearer"  # a look, stepping nearer on the ring; facts: look


class Context(str, enum.Enum):
    """Why the step's event happened where it did (``AgentRecord.context``), outermost first."""

    SIDE_STEP = "side_step"  # a step of the side-step out of turning to and fro
    # exploration ran out with budget left: the map was started again; facts: steps_left, dropped
    FRESH_MAP = "fresh_map"
    SECOND_LOOK = "second_look"  # exhausted: the kept frames scored again; facts: added, kept, best
    DEADLINE = "deadline"  # the step budget is running out; facts: steps_left
    DEADLINE_OVER_WEAKER = "deadline_over_weaker"  # ... before a weaker potential candidate; facts: steps_left, score
    LAST_RESORT = "last_resort"  # heading for the best rejected candidate; facts: score
    RING_CONFIRMED = "ring_confirmed"  # a look from the verify ring at tau x ratio confirmed it; facts: score
    NO_WAY_YET = "no_way_yet"  # a candidate that scored tau has no way on the map: exploring for one; facts: score
    # the candidate rests on remembered views only (the memory of the home), none of this goal's own
    # frames added to it; facts: score (its best, a remembered view's)
    FROM_MEMORY = "from_memory"
    # collision marks dropped: they had made the way to the candidate a detour; facts: was_m, now_m
    MARKS_DROPPED = "marks_dropped"


# The order in which contexts enclose each other (outermost first): the second look decides
# afresh (it may end at the deadline), the deadline takes the last resort, the last resort
# approaches (a candidate confirmed from the ring is approached too).
CONTEXT_ORDER = tuple(Context)

_EVENT_TEXT: dict[Event, str] = {
    Event.LOOK_AROUND: "initial look-around {turn}/{turns}",
    Event.FRONTIER: "frontier ({choice})",
    Event.RESCAN: "no reachable frontier: looking around again",
    Event.EXHAUSTED: "no reachable frontier and no goal candidate",
    Event.APPROACH: "navigating to the goal candidate",
    Event.GOAL_NOT_REACHABLE_YET: "goal not reachable yet",
    Event.FACE_GOAL: "at the goal: turning to face it",
    Event.STOP_AT_GOAL: "within stop radius, facing the goal",
    Event.VERIFY_APPROACH: "verify: approaching the potential candidate",
    Event.VERIFY_RING_NOT_REACHABLE_YET: "verify ring not reachable yet",
    Event.VERIFY_FACE: "verify: turning to look at the potential candidate",
    Event.VERIFY_LOOK: "verify: look {look}",
    Event.VERIFY_STEP_NEARER: "verify: look {look}, stepping nearer",
}

_CONTEXT_TEXT: dict[Context, str] = {
    Context.SIDE_STEP: "side-step out of turning to and fro; {inner}",
    Context.FRESH_MAP: "nothing left to explore with {steps_left} steps left: map started again "
    "({dropped} obstacle cells dropped); {inner}",
    Context.SECOND_LOOK: "exhausted, second look with the full matcher: {added} of the {kept} frames kept added "
    "points{best_text}; {inner}",
    Context.DEADLINE: "{steps_left} steps of the budget left: {inner}",
    Context.DEADLINE_OVER_WEAKER: "{steps_left} steps of the budget left, potential candidate weaker "
    "(best score {score:.1f}): {inner}",
    Context.LAST_RESORT: "last resort (rejected candidate, best score {score:.1f}): {inner}",
    Context.RING_CONFIRMED: "re-identified from the verify ring (score {score:.0f}); {inner}",
    Context.NO_WAY_YET: "no way on the map yet to the goal candidate (best score {score:.1f}): exploring for one; "
    "{inner}",
    Context.FROM_MEMORY: "goal candidate from the memory of the home only (best score {score:.1f}), not seen live "
    "in this run: {inner}",
    Context.MARKS_DROPPED: "collision marks dropped: they made the way {was_m:.1f} m, without them {now_m:.1f} m; "
    "{inner}",
}


def _frozen(facts: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(dict(facts or {}))


@dataclass(frozen=True, slots=True)
class Note:
    """A context with its numbers (``facts``: a read-only mapping of plain values)."""

    context: Context
    facts: Mapping[str, Any] = field(default_factory=lambda: _frozen(None))

    @staticmethod
    def of(context: Context, **facts: Any) -> Note:
        return Note(context, _frozen(facts))


def event_facts(**facts: Any) -> Mapping[str, Any]:
    return _frozen(facts)


def sentence(event: Event, facts: Mapping[str, Any], notes: tuple[Note, ...]) -> str:
    """The reason, for people: the event's sentence inside its contexts' (in ``CONTEXT_ORDER``)."""
    text = _EVENT_TEXT[event].format(**facts)
    for note in sorted(notes, key=lambda n: CONTEXT_ORDER.index(n.context), reverse=True):
        f = dict(note.facts)
        if note.context == Context.SECOND_LOOK:
            best = f.get("best")
            f["best_text"] = f" (best score {best:.1f})" if best is not None else ""
        text = _CONTEXT_TEXT[note.context].format(inner=text, **f)
    return text
