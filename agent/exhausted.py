"""What the Mod-IIN agent does when no frontier is reachable (``agent.policy.ModIINAgent``):
the rescans (forgive and look around again), then, once they are spent, the fresh map, the last
resort, the second look and the exhausted stop, in that order of preference
(docs/experiments/rescan-nothing-learnt.md, fresh-map-no-evidence.md, last-resort.md).

Functions of the agent (its map, memories and state), called by ``ModIINAgent._explore``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import TYPE_CHECKING

from agent.events import Context, Event
from agent.modes import Decision, Mode, RescanState
from agent.types import FORWARD_STEP_M, Action, Observation

if TYPE_CHECKING:
    from agent.policy import ModIINAgent

log = logging.getLogger("agent.policy")  # the policy's decisions, in the policy's log


def rescan(agent: ModIINAgent, obs: Observation, error: str | None) -> Decision:
    """No frontier is reachable (``error``: the planner's last complaint): a rescan turn, or once
    the rescans are spent the fresh map, the last resort, the second look or the exhausted stop."""
    # No reachable frontier. Collision marks are guesses (the blocked side of a move is
    # unknown) and a frontier given up as reached or stalled may still lead somewhere (a
    # doorway passed at an angle): forgive both and look around again before giving up.
    #
    # Forgiving again teaches nothing when nothing was learnt since the last forgiving: the
    # robot stands where it stood then and no forward move failed that had not failed before.
    # The same frontier comes back through the same move the motion memory refuses;
    # exploration takes over after one turn, the rescan is never counted, and the robot turns
    # there until its budget ends (actuation noise alone, train-s1-0008-0: 700 steps;
    # docs/experiments/rescan-nothing-learnt.md). Then the rescan looks around as the map is,
    # and is counted when its turns are done unless new frontiers come into view. A robot that
    # moved half a step or more, or found a new way blocked, forgives again: that is how a
    # robot with noisy moves squeezes through a gap it clipped (each failed move is new once,
    # so this is bounded).
    if agent._state.waiting:
        # no frontier left to find a way by: the waiting candidates are approached once more
        # (and rejected if still unreachable: each waits once)
        log.info("no reachable frontier: the candidates waiting for a way are tried again")
        agent._set(waiting=frozenset())
    r = agent._state.rescan
    if r.rescans_left > 0:
        if r.steps == 0:
            here = (obs.pose.x_m, obs.pose.y_m)
            failed = len(agent._state.motion.blocked)
            agent.explorer.reset()
            if (
                r.forgiven_at is None
                or math.dist(here, r.forgiven_at) >= FORWARD_STEP_M / 2
                or failed > r.forgiven_failed_moves
            ):
                agent.grid.forgive_collisions()
                agent.grid.forgive_frontiers()
                r = replace(r, forgiven_at=here, forgiven_failed_moves=failed)
                log.info("no reachable frontier: cleared collision marks and given-up frontiers, looking around again")
            else:
                log.info(
                    "no reachable frontier, nothing learnt since the last forgiving: looking around again as it is"
                )
            if agent._explored_carried:
                # what earlier goals looked over was not looked over for this one (agent.memory)
                agent.grid.layers.explored[:] = False
                agent._explored_carried = False
                log.info("no reachable frontier: forgot the explored area carried from earlier goals")
        steps = r.steps + 1
        if steps >= agent.config.policy.look_around_turns or steps >= 12:
            r = replace(r, steps=0, rescans_left=r.rescans_left - 1)
        else:
            r = replace(r, steps=steps)
        agent._set(rescan=r)
        return Decision(Action.TURN_LEFT, Mode.RESCAN, Event.RESCAN, planner_error=error or "no_frontier")
    if fresh_map_due(agent, obs):
        # nothing worth going to: the second look first (the kept frames may hold the goal),
        # then the map begun again
        decision = recheck(agent, obs) or fresh_map(agent, obs)
        if decision is not None:
            return decision
    if agent.config.policy.last_resort:
        decision, agent._state = agent.nav.last_resort(agent._scene(obs), agent._state)
        if decision is not None:
            return decision
    decision = recheck(agent, obs)
    if decision is not None:
        return decision
    # Nothing left to explore and no goal: a deliberate stop, reported as such.
    return Decision(Action.STOP, Mode.EXHAUSTED, Event.EXHAUSTED, planner_error=error or "no_frontier")


def recheck(agent: ModIINAgent, obs: Observation) -> Decision | None:
    """The second look when exhausted (``policy.exhausted_recheck_frames``): score the kept
    frames again with the full matcher, localise their matches whatever the score, and decide
    on the candidates they form (None: no candidate came of it, or already done)."""
    pc = agent.config.policy
    if (
        agent._state.rechecked
        or len(agent.shortlist) == 0
        or agent.reid is None
        or pc.reid_source != "matcher"
        or pc.localisation_source != "goal_mask"
    ):
        return None
    agent._set(rechecked=True)
    frames = agent.shortlist.take()
    scored = [
        (kept, agent.reid.compare(kept.rgb, use_gate=False))
        for _, kept in frames
        if agent.localiser.view(kept.step) is None
    ]
    scores = [r.score for kept, r in scored if r.score > 0 and len(agent._localise(kept, r, r.score))]
    best = max(scores) if scores else None
    log.info(
        "exploration exhausted with no candidate: second look, %d of the %d frames kept added points",
        len(scores),
        len(frames),
    )
    cands = agent._evaluate(agent.localiser.candidates(agent.grid, agent.tau)) if scores else []
    if not cands:
        return None
    decision = agent._decide(obs, cands)
    if decision.mode == Mode.EXHAUSTED:
        return None
    return decision.within(Context.SECOND_LOOK, added=len(scores), kept=len(frames), best=best)


def fresh_map_due(agent: ModIINAgent, obs: Observation) -> bool:
    """The rescans are spent: is the map to be started again (``policy.fresh_map_min_steps_left``)?
    Once a run, with the steps to use it, and only when the last resort has nothing worth
    going to: no rejected candidate left to try scores ``fresh_map_below_tau_ratio`` x tau."""
    pc, st = agent.config.policy, agent._state
    if (
        pc.fresh_map_min_steps_left <= 0
        or st.fresh_map_step is not None
        or pc.step_budget - obs.step < pc.fresh_map_min_steps_left
    ):
        return False
    if not pc.last_resort:
        return True
    lr = st.last_resort
    cid = agent.memory.last_resort_next(lr.candidate_id, lr.tried)
    floor = pc.fresh_map_below_tau_ratio * agent.tau if agent.tau is not None else 0.0
    return cid is None or agent.memory.best_score_of(cid) < floor


def fresh_map(agent: ModIINAgent, obs: Observation) -> Decision | None:
    """Start the map again and look around (``fresh_map_due``; None: no look-around turns)."""
    pc = agent.config.policy
    dropped = agent.grid.start_again()
    agent.explorer.reset()
    agent._explored_carried = False
    agent._set(
        rescan=RescanState(rescans_left=pc.max_rescans),
        fresh_map_step=agent._state.steps,
        fresh_map_dropped=dropped,
    )
    log.info(
        "no reachable frontier after %d rescans, %d steps left: map started again (%d obstacle cells dropped)",
        pc.max_rescans,
        pc.step_budget - obs.step,
        dropped,
    )
    return agent._look_around(obs)
