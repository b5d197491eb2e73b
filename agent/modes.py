"""The policy's state machine: its modes, the state each mode keeps, and the decision of a step.

The Mod-IIN agent (``agent.policy``) is in exactly one ``Mode`` per step:

    LOOK_AROUND --(start turns done)--> EXPLORE <-----------(candidate rejected)-----------+
                                          |                                               |
              +--(confirmed candidate)----+----(potential candidate)--> VERIFY -----------+
              v                                                           |
          APPROACH <--------------------(confirmed from the verify ring)--+
              |
          STOPPED (in the stop region, facing the candidate)

    EXPLORE --(no reachable frontier)--> RESCAN --(rescans spent)--> EXHAUSTED (a STOP)
       ^                                                |
       +--LOOK_AROUND <--(rescans spent, budget left, --+  (policy.fresh_map_min_steps_left, once;
                          no candidate worth the last   |   after the second look)
                          resort: the map started again)|
       |                       (policy.last_resort, a rejected candidate left)
       |                                                v
       +--(the step budget runs out, ----------> LAST_RESORT --(in its stop region)--> STOPPED
           policy.last_resort_at_deadline)

Each mode's memory is a small frozen dataclass; the agent replaces it (``dataclasses.replace``)
rather than mutating counters, and every step ends in one frozen ``Decision`` that goes into
the ``AgentRecord`` (mode, event and context, the reason written from them, plan, target,
candidate, planner error).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from agent.events import Context, Event, Note, event_facts, sentence
from agent.localisation import Candidate
from agent.planner import Plan
from agent.types import Action


class Mode(str, enum.Enum):
    LOOK_AROUND = "look_around"  # the initial full turn
    EXPLORE = "explore"  # heading for a frontier
    APPROACH = "approach"  # heading for a goal candidate (or turning to face it)
    VERIFY = "verify"  # confirming a potential candidate: approaching its verify ring and looking at it
    RESCAN = "rescan"  # no reachable frontier: forgive and look around again
    STOPPED = "stopped"  # STOP at a (confirmed) candidate
    EXHAUSTED = "exhausted"  # STOP: nothing left to explore and no candidate
    LAST_RESORT = "last_resort"  # nothing left to explore: heading for the best rejected candidate

    def __str__(self) -> str:  # records and logs show the plain name
        return self.value


@dataclass(frozen=True, slots=True, eq=False)
class Decision:
    """What the policy decided this step and why (immutable; goes into the ``AgentRecord``).

    event and facts: what the robot does, with its numbers; context: the notes it was decided in
    (``agent.events``); ``reason`` is the sentence written from them. target_kind: ``"goal"``
    (a candidate), ``"frontier"`` or None; candidate: the goal candidate the decision is about
    (None in EXPLORE/RESCAN/EXHAUSTED/LOOK_AROUND); planner_error: ``"<reason>: <message>"`` of a
    failed plan this step, if any."""

    action: Action
    mode: Mode
    event: Event
    facts: Mapping[str, Any] = field(default_factory=event_facts)
    context: tuple[Note, ...] = ()
    plan: Plan | None = None
    target_kind: str | None = None
    candidate: Candidate | None = None
    planner_error: str | None = None

    @property
    def reason(self) -> str:
        return sentence(self.event, self.facts, self.context)

    def within(self, context: Context, **facts: Any) -> Decision:
        """This decision, taken in ``context`` (with its numbers)."""
        return replace(self, context=(Note.of(context, **facts), *self.context))

    def has(self, context: Context) -> bool:
        return any(n.context == context for n in self.context)


@dataclass(frozen=True, slots=True)
class ApproachState:
    """Progress towards the candidate being approached (kept across modes, keyed by its centroid)."""

    target_xy_m: tuple[float, float] | None = None
    best_distance_m: float = math.inf
    stall_steps: int = 0  # steps without getting 5 cm nearer
    unreachable_steps: int = 0  # consecutive steps without a plan to it
    region_unreachable: bool = False  # the stop region itself could not be planned to: the slack applies
    collisions_forgiven: int = 0  # times the collision marks were dropped before giving it up as unreachable

    def after_plan(self, candidate_xy_m: tuple[float, float], distance_m: float) -> ApproachState:
        """The state after a plan of ``distance_m`` to the candidate at ``candidate_xy_m``: a new
        candidate (centroid moved over 0.5 m) restarts the count; getting 5 cm nearer than ever
        resets the stall, anything else adds a stalled step."""
        a = replace(self, unreachable_steps=0)
        if a.target_xy_m is None or math.dist(a.target_xy_m, candidate_xy_m) > 0.5:
            a = replace(a, target_xy_m=candidate_xy_m, best_distance_m=math.inf, stall_steps=0, collisions_forgiven=0)
        if distance_m < a.best_distance_m - 0.05:
            return replace(a, best_distance_m=distance_m, stall_steps=0)
        return replace(a, stall_steps=a.stall_steps + 1)


@dataclass(frozen=True, slots=True)
class VerifyState:
    """Looking at a potential candidate (``candidate_id``) from the verify ring: ``views`` looks so far."""

    candidate_id: int | None = None
    views: int = 0


@dataclass(frozen=True, slots=True)
class RescanState:
    steps: int = 0  # turns of the current rescan
    rescans_left: int = 3
    # where the robot stood when a rescan last forgave the collision marks and given-up frontiers,
    # and how many failed moves the motion memory held then
    forgiven_at: tuple[float, float] | None = None
    forgiven_failed_moves: int = 0


@dataclass(frozen=True, slots=True)
class MotionState:
    """Failed forward moves, as (global cell i, cell j, heading bin), and how often the plan asked
    for one of them since the robot last moved forward."""

    blocked: frozenset[tuple[int, int, int]] = frozenset()
    blocked_repeats: int = 0  # moves refused since the robot last moved forward
    # the run of alternating turns (left, right, left, ...) that ended with the last action
    alternating_turns: int = 0
    last_action: Action | None = None
    # a side-step out of a to-and-fro run: (global cell i, cell j, heading bin) to step forward
    # on from that cell (``motion.detour``); None: no detour under way
    detour: tuple[int, int, int] | None = None
    # this step's action is part of a side-step (set when steering, cleared at each step's start)
    side_step: bool = False


@dataclass(frozen=True, slots=True)
class PolicyState:
    """The whole policy memory of a run (besides the map, the localiser and the frontier tracker)."""

    mode: Mode = Mode.LOOK_AROUND
    steps: int = 0  # acts so far
    approach: ApproachState = field(default_factory=ApproachState)
    verify: VerifyState | None = None  # None: not verifying
    rescan: RescanState = field(default_factory=RescanState)
    motion: MotionState = field(default_factory=MotionState)
    ring_confirmed: frozenset[int] = frozenset()  # steps whose look from the verify ring confirmed a candidate
    last_resort: LastResortState = field(default_factory=lambda: LastResortState())
    rechecked: bool = False  # the second look at the best frames when exhausted was taken
    # candidates that scored tau, found unreachable: explored past until the map shows a way to
    # them (``waiting``, by id), each once (``waited``); agent.approach.CandidateNavigator.no_way
    waiting: frozenset[int] = frozenset()
    waited: frozenset[int] = frozenset()
    # the step at which the map was started again (``policy.fresh_map_min_steps_left``; once a
    # run), the look-around after it counted from there; None: not started again
    fresh_map_step: int | None = None
    fresh_map_dropped: int = 0  # obstacle cells the fresh map dropped


@dataclass(frozen=True, slots=True)
class LastResortState:
    """The rejected candidate being tried as the last resort (``candidate_id``) and those
    already tried (each once: one that is rejected again is not tried a second time)."""

    candidate_id: int | None = None
    tried: frozenset[int] = frozenset()
    # the step budget is running out (``policy.last_resort_at_deadline``): from that step on the
    # last resort comes before exploration
    deadline: bool = False
