"""The policy's state machine (agent.modes), one test per mode, on the Decision and the AgentRecord."""

import math
from dataclasses import replace

import numpy as np
import pytest

from agent.config import AgentConfig, PolicyConfig
from agent.events import Context, Event
from agent.modes import Decision, Mode
from agent.policy import ModIINAgent
from agent.types import Action, Pose2D
from sim.evaluation.compare import to_and_fro_runs
from tests.helpers.agent_runs import oracle_agent, run_decisions
from tests.helpers.agent_scenes import BoxWorld, room_walls, two_rooms


def test_look_around_then_explore_then_approach_then_stopped():
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.0, 1.5, -0.5), goal)  # the goal is hidden behind the wall
    steps = run_decisions(oracle_agent(world, look_around_turns=12), world)
    modes = [d.mode for d, _ in steps]
    # LOOK_AROUND: the first 12 steps turn left on the spot, counted in the event's numbers
    assert modes[:12] == [Mode.LOOK_AROUND] * 12
    assert all(d.action == Action.TURN_LEFT and d.candidate is None and d.plan is None for d, _ in steps[:12])
    assert steps[0][0].event == Event.LOOK_AROUND and dict(steps[0][0].facts) == {"turn": 1, "turns": 12}
    # EXPLORE: frontier targets with a plan, no candidate (the goal is in the other room)
    explore = [d for d, _ in steps if d.mode == Mode.EXPLORE]
    assert explore and all(d.target_kind == "frontier" and d.plan is not None and d.candidate is None for d in explore)
    # APPROACH: about a candidate, the goal as the target
    approach = [d for d, _ in steps if d.mode == Mode.APPROACH]
    assert approach and all(d.target_kind == "goal" and d.candidate is not None for d in approach)
    assert modes.index(Mode.EXPLORE) < modes.index(Mode.APPROACH)
    # STOPPED: a STOP about the candidate, last
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and last.action == Action.STOP and last.candidate is not None
    assert rec.mode == "stopped" and world.distance_to_goal() < 1.0


REJECTED_AT = 15  # the step by which the looks from the verify ring have rejected the goal (see the tests)


def _rejected_then_exhausted(last_resort: bool, max_steps: int = 600, **policy):
    """The goal only ever scores 60 (tau 100): a potential candidate, which the looks from the verify
    ring reject (only a detection confirms: ``verify_ring_tau_ratio`` 1); then exploration of the
    two small rooms runs out. The deadline is off unless asked for."""
    boxes, goal, decoy = two_rooms()
    world = BoxWorld(boxes, Pose2D(2.0, -1.0, 0.6), goal)
    pol = dict(
        look_around_turns=4,
        max_rescans=1,
        last_resort=last_resort,
        verify_ring_tau_ratio=1.0,
        last_resort_at_deadline=False,
        exhausted_recheck_frames=0,
        fresh_map_min_steps_left=0,
    )
    pol.update(policy)
    agent = _scored_agent(world, decoy, lambda d: 60.0, lambda d: 0.0, **pol)
    return world, run_decisions(agent, world, max_steps=max_steps)


def test_last_resort_goes_back_to_the_rejected_candidate_and_stops_there():
    world, steps = _rejected_then_exhausted(last_resort=True)
    modes = [d.mode for d, _ in steps]
    assert Mode.VERIFY in modes and Mode.LAST_RESORT in modes
    k = modes.index(Mode.LAST_RESORT)
    # it comes after the rejection and after exploration ran out (rescans spent)
    assert modes.index(Mode.VERIFY) < modes.index(Mode.RESCAN) < k
    rejected = [c for c in steps[k - 1][1].candidates if c.state == "rejected"]
    assert len(rejected) == 1
    tried = [d for d, _ in steps[k:] if d.mode == Mode.LAST_RESORT]
    assert all(d.candidate is not None and d.candidate.id == rejected[0].id and d.target_kind == "goal" for d in tried)
    assert all(d.has(Context.LAST_RESORT) for d in tried)
    last, rec = steps[-1]
    assert last.action == Action.STOP and last.mode == Mode.STOPPED and last.has(Context.LAST_RESORT)
    assert rec.event == Event.STOP_AT_GOAL.value and rec.context == (Context.LAST_RESORT.value,)
    assert rec.candidate_id == rejected[0].id and len(rec.goal_points_xyz) > 0
    assert world.distance_to_goal() < 1.0


def test_the_fresh_map_comes_only_when_the_last_resort_has_no_evidence_to_go_to():
    # the rejected goal scored 60 (tau 100): above the floor (0.15 x tau), so with the budget left
    # the last resort goes to it as before, action for action
    _, off = _rejected_then_exhausted(last_resort=True)
    _, strong = _rejected_then_exhausted(last_resort=True, fresh_map_min_steps_left=250)
    assert [d.action for d, _ in strong] == [d.action for d, _ in off]
    assert not any(d.has(Context.FRESH_MAP) for d, _ in strong)
    # the same run with the floor above 60: the rescans spent, the map is started again first;
    # when they are spent a second time the last resort goes to the goal as before
    world, weak = _rejected_then_exhausted(
        last_resort=True, fresh_map_min_steps_left=250, fresh_map_below_tau_ratio=0.7
    )
    modes = [d.mode for d, _ in weak]
    k = next(i for i, (d, _) in enumerate(weak) if d.has(Context.FRESH_MAP))
    assert modes[k - 1] == Mode.RESCAN and Mode.LAST_RESORT not in modes[:k] and Mode.VERIFY in modes[:k]
    assert Mode.RESCAN in modes[k + 4 :]
    assert modes.index(Mode.LAST_RESORT, k) > modes.index(Mode.RESCAN, k + 4)
    last, _ = weak[-1]
    assert last.action == Action.STOP and last.has(Context.LAST_RESORT) and world.distance_to_goal() < 1.0


def test_without_the_last_resort_the_same_run_stops_exhausted_where_it_stands():
    world, steps = _rejected_then_exhausted(last_resort=False)
    modes = [d.mode for d, _ in steps]
    assert Mode.LAST_RESORT not in modes and Mode.STOPPED not in modes
    assert steps[-1][0].mode == Mode.EXHAUSTED and steps[-1][0].action == Action.STOP


def test_the_last_resort_at_the_deadline_goes_back_before_the_budget_runs_out():
    # a budget of 100 steps: exploration would still be going when it runs out (step 65 is
    # where it ends with the budget unknown), so the run would end without a STOP
    world, steps = _rejected_then_exhausted(
        last_resort=False, max_steps=100, last_resort_at_deadline=True, step_budget=100
    )
    modes = [d.mode for d, _ in steps]
    assert Mode.LAST_RESORT in modes and Mode.RESCAN not in modes
    k = modes.index(Mode.LAST_RESORT)
    assert modes.index(Mode.VERIFY) < k and Mode.EXPLORE in modes[modes.index(Mode.VERIFY) : k]
    rejected = [c for c in steps[k - 1][1].candidates if c.state == "rejected"]
    assert len(rejected) == 1
    # from the step it was due on, the last resort comes before exploration, to the end
    assert all(d.mode in (Mode.LAST_RESORT, Mode.STOPPED) for d, _ in steps[k:])
    assert all(d.candidate is not None and d.candidate.id == rejected[0].id for d, _ in steps[k:])
    first = steps[k][0]
    assert first.has(Context.DEADLINE) and first.has(Context.LAST_RESORT)
    (deadline,) = [n for n in first.context if n.context == Context.DEADLINE]
    left = deadline.facts["steps_left"]
    assert left == 100 - k and 0 < left <= 100 - REJECTED_AT  # due after the rejection, before the end
    last, rec = steps[-1]
    assert last.action == Action.STOP and last.mode == Mode.STOPPED and last.has(Context.LAST_RESORT)
    assert len(steps) < 100 and world.distance_to_goal() < 1.0


def test_without_the_deadline_the_same_budget_runs_out_exploring():
    world, steps = _rejected_then_exhausted(
        last_resort=False, max_steps=60, last_resort_at_deadline=False, step_budget=60
    )
    modes = [d.mode for d, _ in steps]
    assert len(steps) == 60 and Mode.LAST_RESORT not in modes and steps[-1][0].action != Action.STOP
    assert world.distance_to_goal() > 1.0


def test_the_deadline_is_not_checked_before_its_window():
    # a budget of 1000 with the default window of 200: exploration ends (step 65) long before
    # the window opens, so the run is the run without the deadline, action for action
    on = _rejected_then_exhausted(last_resort=True, last_resort_at_deadline=True, step_budget=1000)[1]
    off = _rejected_then_exhausted(last_resort=True)[1]
    assert [d.action for d, _ in on] == [d.action for d, _ in off]
    assert [(d.event, d.context) for d, _ in on] == [(d.event, d.context) for d, _ in off]
    assert not any(d.has(Context.DEADLINE) for d, _ in on)


def test_approach_turns_to_face_before_stopping():
    boxes, goal, _ = two_rooms()
    # in room B, within the stop radius of the goal but facing away from it
    world = BoxWorld(boxes, Pose2D(3.7, 0.6, math.pi), goal)
    steps = run_decisions(oracle_agent(world, look_around_turns=12), world, max_steps=40)
    facing = [d for d, _ in steps if d.event == Event.FACE_GOAL]
    assert steps[-1][0].mode == Mode.STOPPED
    assert all(d.mode == Mode.APPROACH and d.action in (Action.TURN_LEFT, Action.TURN_RIGHT) for d in facing)


def _closed_room(**policy):
    world = BoxWorld(room_walls(-1.0, -1.0, 1.0, 1.0) + [(5, 5, 5.5, 5.5, 0.5)], Pose2D(), goal_box=4)
    return run_decisions(oracle_agent(world, look_around_turns=4, max_rescans=2, **policy), world, max_steps=100)


def test_rescan_then_exhausted():
    steps = _closed_room(fresh_map_min_steps_left=0)
    modes = [d.mode for d, _ in steps]
    assert modes.count(Mode.RESCAN) == 2 * 4  # two rescans of look_around_turns turns each
    assert all(d.action == Action.TURN_LEFT and d.planner_error for d, _ in steps if d.mode == Mode.RESCAN)
    last, rec = steps[-1]
    assert last.mode == Mode.EXHAUSTED and last.action == Action.STOP and last.planner_error
    assert rec.mode == "exhausted"
    assert not any(d.has(Context.FRESH_MAP) for d, _ in steps)


def test_rescans_spent_with_budget_left_start_the_map_again_once():
    # the default (fresh_map_min_steps_left 250 of the 1,000-step budget): when the rescans are
    # spent, the map is started again and looked around in, once; the second time they are
    # spent the run ends as before
    steps = _closed_room()
    modes = [d.mode for d, _ in steps]
    first_end = modes.index(Mode.RESCAN) + 2 * 4
    assert modes[first_end - 8 : first_end] == [Mode.RESCAN] * 8
    fresh = steps[first_end : first_end + 4]
    assert [d.mode for d, _ in fresh] == [Mode.LOOK_AROUND] * 4
    assert all(d.action == Action.TURN_LEFT and d.has(Context.FRESH_MAP) for d, _ in fresh)
    assert [dict(d.facts)["turn"] for d, _ in fresh] == [1, 2, 3, 4]
    (note,) = fresh[0][0].context
    assert note.facts["steps_left"] == 1000 - first_end and note.facts["dropped"] > 50  # the room's walls
    assert fresh[0][1].reason.startswith(f"nothing left to explore with {1000 - first_end} steps left: map started")
    # the map of that step was forgotten: none of the closed room's wall cells is left
    assert not fresh[0][1].map.obstacle.any() and fresh[-1][1].map.obstacle.any()  # and drawn again
    assert sum(d.has(Context.FRESH_MAP) for d, _ in steps) == 4
    assert modes[first_end + 4 :].count(Mode.RESCAN) >= 2 * 4
    assert steps[-1][0].mode == Mode.EXHAUSTED


def test_a_fresh_map_needs_the_steps_to_use_it():
    # with fewer steps left than fresh_map_min_steps_left the run ends as without it
    off = _closed_room(fresh_map_min_steps_left=0)
    short = _closed_room(step_budget=120, fresh_map_min_steps_left=110)
    assert [d.action for d, _ in short] == [d.action for d, _ in off]


def test_a_fresh_map_opens_a_door_closed_by_walls_drawn_off():
    """two_rooms with the door closed on the map by a wall that is not there (as a wall drawn again
    at a drifted heading leaves, and seen only from afar the obstacle evidence never clears): the
    phantom is put back at every step until the map is started again. Without the fresh map the
    robot ends exhausted in room A; with it, it drives through the door and stops at the goal."""
    boxes, goal, _ = two_rooms()
    start = Pose2D(-1.0, 1.5, -0.5)  # in room A, the goal hidden behind the wall
    c, s = math.cos(start.yaw_rad), math.sin(start.yaw_rad)
    door = np.array([[1.05 - start.x_m, y - start.y_m] for y in np.arange(-0.5, 0.51, 0.025)])
    door_run = door @ np.array([[c, -s], [s, c]])  # world -> the run frame (start-relative)

    def phantom(agent):
        if agent._state.fresh_map_step is not None:
            return
        ij = agent.grid.xy_to_ij(door_run)
        ok = agent.grid.in_bounds(ij)
        agent.grid.layers.obstacle[ij[ok, 0], ij[ok, 1]] = True
        agent.grid.layers.obstacle_evidence[ij[ok, 0], ij[ok, 1]] = 3

    runs = {}
    for on in (0, 250):
        world = BoxWorld(boxes, start, goal)
        agent = oracle_agent(world, look_around_turns=12, fresh_map_min_steps_left=on)
        runs[on] = (world, run_decisions(agent, world, max_steps=600, before_step=phantom))
    world, steps = runs[0]
    assert steps[-1][0].mode == Mode.EXHAUSTED and world.distance_to_goal() > 1.0
    assert not any(d.mode == Mode.APPROACH for d, _ in steps)
    world, steps = runs[250]
    k = next(i for i, (d, _) in enumerate(steps) if d.has(Context.FRESH_MAP))
    assert steps[k - 1][0].mode == Mode.RESCAN and not any(d.mode == Mode.APPROACH for d, _ in steps[:k])
    assert steps[-1][0].mode == Mode.STOPPED and world.distance_to_goal() < 1.0


def test_mode_names_are_the_record_strings():
    assert [m.value for m in Mode] == [
        "look_around",
        "explore",
        "approach",
        "verify",
        "rescan",
        "stopped",
        "exhausted",
        "last_resort",
    ]
    assert str(Mode.VERIFY) == "verify"


def test_decision_is_frozen():
    import dataclasses

    d = Decision(Action.STOP, Mode.STOPPED, Event.STOP_AT_GOAL)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.event = Event.EXHAUSTED  # type: ignore[misc]
    assert d.within(Context.LAST_RESORT, score=1.0) is not d and d.context == ()


def test_candidates_are_in_the_record():
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
    steps = run_decisions(oracle_agent(world), world)
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED
    (info,) = [c for c in rec.candidates if c.id == rec.candidate_id]
    assert info.state == "confirmed" and info.n_views >= 1 and info.best_score == 1.0
    assert info.distance_m < 2.0 and rec.candidate_id == last.candidate.id


def test_verify_by_approach_confirms_a_goal_first_seen_from_afar():
    """The goal scores 60 from afar (potential) and 200 from within 2.6 m: the agent goes to the
    verify ring, a look from there is a detection, and the candidate is confirmed and stopped at
    (only a detection confirms here: ``verify_ring_tau_ratio`` 1)."""
    boxes, goal, decoy = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)  # sees the goal through the door, ~5 m away
    agent = _scored_agent(world, decoy, lambda d: 200.0 if d < 2.6 else 60.0, lambda d: 0.0, verify_ring_tau_ratio=1.0)
    steps = run_decisions(agent, world, max_steps=300)
    verify = [d for d, _ in steps if d.mode == Mode.VERIFY]
    assert verify and verify[0].event == Event.VERIFY_APPROACH
    # potential while verifying, then confirmed
    assert any(c.state == "potential" for _, r in steps for c in r.candidates)
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert [c.state for c in rec.candidates if c.id == rec.candidate_id] == ["confirmed"]


def test_stop_rule_core_stops_in_sight_of_the_goal():
    boxes, goal, _ = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
    steps = run_decisions(oracle_agent(world, stop_rule="core", stop_radius_m=0.6), world)
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 0.8


def _kerb_world():
    """two_rooms' door blocked by a kerb too low for the map's obstacle band (the robot hits it,
    the camera's points stay below 0.10 m): the goal room cannot be reached."""
    walls = room_walls(-3.0, -2.0, 5.0, 2.0)
    walls += [(1.0, -2.0, 1.1, -0.45, 2.5), (1.0, 0.45, 1.1, 2.0, 2.5)]
    boxes = walls + [(0.9, -0.45, 1.2, 0.45, 0.05), (4.0, 1.0, 4.6, 1.6, 0.6)]
    return BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), len(boxes) - 1)


def _longest_to_and_fro(steps) -> int:
    return max(to_and_fro_runs([int(d.action) for d, _ in steps]), default=1)


def _closed_room_rescans(caplog, before_step=None):
    """A closed room without the goal: no frontier is ever reachable, so the run is its look-around
    and then three rescans on the spot it ends on. Returns the steps and how many rescans forgave
    the marks and how many looked around as the map was."""
    world = BoxWorld(room_walls(-1.0, -1.0, 1.0, 1.0) + [(5, 5, 5.5, 5.5, 0.5)], Pose2D(), goal_box=4)
    with caplog.at_level("INFO", logger="agent.policy"):
        agent = oracle_agent(world, look_around_turns=4, max_rescans=3, fresh_map_min_steps_left=0)
        steps = run_decisions(agent, world, 100, before_step)
    forgave = caplog.text.count("cleared collision marks and given-up frontiers")
    kept = caplog.text.count("nothing learnt since the last forgiving")
    caplog.clear()
    return steps, forgave, kept


def test_a_rescan_forgives_again_only_when_something_was_learnt_since(caplog):
    # Forgiving again where nothing was learnt brings back the plan that failed (the robot turned
    # on one spot for 700 steps): the second and third rescans here look around as the map is.
    steps, forgave, kept = _closed_room_rescans(caplog)
    assert [d.mode for d, _ in steps].count(Mode.RESCAN) == 3 * 4 and steps[-1][0].mode == Mode.EXHAUSTED
    assert (forgave, kept) == (1, 2)

    # A forward move that failed from a (cell, heading) the memory had not seen is something learnt:
    # the rescan after it forgives again (how a robot with noisy moves squeezes through a gap).
    def fail_a_new_move_before_the_second_rescan(agent):
        st = agent._state
        if st.mode == Mode.RESCAN and st.rescan.rescans_left == 2 and st.rescan.steps == 0 and not added:
            agent._set(motion=replace(st.motion, blocked=st.motion.blocked | {(999, 999, 0)}))
            added.append(True)

    added: list[bool] = []
    steps, forgave, kept = _closed_room_rescans(caplog, fail_a_new_move_before_the_second_rescan)
    assert added and (forgave, kept) == (2, 1)


def test_the_side_step_gets_out_of_turning_to_and_fro():
    # The robot's first failed move at the kerb has its mark forgiven at once (as a rescan would):
    # the plan points through the door again, the motion memory refuses the move that failed there,
    # the refusal turns away, the plan turns back. Without the side-step: to and fro on the spot
    # until the approach gives the goal up.
    def forgive_the_first_failure(agent):
        if agent._state.motion.blocked and not forgiven:
            agent.grid.forgive_collisions()
            forgiven.append(True)

    forgiven: list[bool] = []
    world = _kerb_world()
    # (the collision marks are kept otherwise: policy.detour_forgive_m would drop them, its own test below)
    steps = run_decisions(
        oracle_agent(world, detour_after_turns=0, detour_forgive_m=0.0), world, 300, forgive_the_first_failure
    )
    assert forgiven and _longest_to_and_fro(steps) >= 15
    assert not any(d.has(Context.SIDE_STEP) for d, _ in steps)
    # With it (policy.detour_after_turns: 4, the default): after the 4th turn to and fro the agent
    # turns to a free heading and steps forward once, without re-planning in between; the record
    # says so. (The goal room stays out of reach: the kerb spans the door.)
    forgiven = []
    world = _kerb_world()
    steps = run_decisions(oracle_agent(world, detour_forgive_m=0.0), world, 300, forgive_the_first_failure)
    side = [k for k, (d, r) in enumerate(steps) if d.has(Context.SIDE_STEP) and r.context[:1] == ("side_step",)]
    assert forgiven and len(side) >= 2
    # each side-step is turns (all the same way) and then one forward move
    runs, cur = [], [side[0]]
    for k in side[1:]:
        if k == cur[-1] + 1:
            cur.append(k)
        else:
            runs.append(cur)
            cur = [k]
    runs.append(cur)
    for run in runs:
        actions = [steps[k][0].action for k in run]
        assert actions[-1] == Action.MOVE_FORWARD or run[-1] == len(steps) - 1
        assert len(set(actions[:-1])) <= 1 and Action.MOVE_FORWARD not in actions[:-1]
        # it began after a run of 4 turns to and fro
        before = [steps[k][0].action for k in range(run[0] - 4, run[0])]
        assert set(before) == {Action.TURN_LEFT, Action.TURN_RIGHT}
        assert all(a != b for a, b in zip(before, before[1:]))
    assert _longest_to_and_fro(steps) < 10


def _walled_in_run(scored: bool = False, again: bool = False, max_steps: int = 300, **policy):
    """two_rooms from inside room B: the goal is seen at the first step. Then a ring of collision
    marks 1.6 m around the candidate (as failed moves near an object leave, train-s1-0012-0)
    walls in every spot within the stop radius; the marks are guesses, the space is free.
    ``scored``: the goal scores 200 against tau 100 (a confirmed candidate), else the oracle.
    ``again``: the ring is put back whenever the marks were dropped."""
    boxes, goal, decoy = two_rooms()
    world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
    if scored:
        agent = _scored_agent(world, decoy, lambda d: 200.0, lambda d: 0.0, **policy)
    else:
        agent = oracle_agent(world, **policy)
    obs = world.observe()
    agent.reset(obs.goal_image)
    out, centre = [], None
    for _ in range(max_steps):
        action = agent.act(obs)
        d = agent.last_decision
        if not out:
            assert d.mode == Mode.APPROACH and d.candidate is not None
            centre = d.candidate.centroid_xy_m
        if not out or (again and not agent.grid.layers.collision.any()):
            cx, cy = centre
            for k in range(32):
                t = 2 * math.pi * k / 32
                agent.grid.mark_collision(Pose2D(cx + 1.6 * math.cos(t), cy + 1.6 * math.sin(t), t + math.pi))
        out.append((d, agent.last_record))
        world.apply(action)
        if action == Action.STOP:
            break
        obs = world.observe()
    return world, out


def test_collision_marks_are_dropped_before_a_candidate_is_given_up_as_unreachable():
    # Off (and no last resort to come back to it): after 10 steps without a plan the true goal is
    # rejected, and the run ends exhausted far from it
    world, steps = _walled_in_run(unreachable_forgive=0, last_resort=False)
    last, rec = steps[-1]
    assert [(c.state, c.why) for c in rec.candidates] == [("rejected", "unreachable for 10 steps")]
    assert last.mode == Mode.EXHAUSTED and world.distance_to_goal() > 1.0
    # policy.unreachable_forgive: 1 (the default): the marks are dropped once instead, and the
    # agent stops at it
    world, steps = _walled_in_run()
    last, rec = steps[-1]
    assert [c.state for c in rec.candidates] == ["confirmed"]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert any(d.event == Event.GOAL_NOT_REACHABLE_YET for d, _ in steps)  # it was walled in first


def test_a_candidate_that_scored_tau_waits_for_a_way_instead_of_being_given_up():
    """The same walls of collision marks, the goal scoring 200 against tau 100 (no forgiving
    before a rejection, no last resort): after 10 steps without a plan the candidate is not
    rejected (its cells would be blacklisted for good) but waits while the agent explores; with
    no frontier left the rescan drops the marks, the candidate is approached again and reached."""
    world, steps = _walled_in_run(scored=True, unreachable_forgive=0, last_resort=False)
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert all(c.state != "rejected" for _, r in steps for c in r.candidates)
    first = next(i for i, (d, _) in enumerate(steps) if d.event == Event.GOAL_NOT_REACHABLE_YET)
    waiting = [i for i, (d, _) in enumerate(steps) if d.has(Context.NO_WAY_YET)]
    # 10 steps without a plan (the 10th turns to the look-around's last turns, as after a
    # rejection), then exploring past it, saying why
    no_plan = [i for i, (d, _) in enumerate(steps[: waiting[0]]) if d.event == Event.GOAL_NOT_REACHABLE_YET]
    assert no_plan == list(range(first, first + 9))
    assert all(steps[i][0].mode == Mode.LOOK_AROUND for i in range(first + 9, waiting[0]))
    assert all(steps[i][0].mode == Mode.EXPLORE for i in waiting)
    assert [n.facts["score"] for n in steps[waiting[0]][0].context if n.context == Context.NO_WAY_YET] == [200.0]
    assert (
        "no way on the map yet to the goal candidate (best score 200.0): exploring for one"
        in steps[waiting[0]][1].reason
    )
    # the wait ends with the frontiers: a rescan (which drops the marks), then the approach
    end = next(i for i in range(waiting[-1] + 1, len(steps)) if steps[i][0].mode != Mode.EXPLORE)
    assert steps[end][0].mode == Mode.RESCAN
    assert any(d.mode == Mode.APPROACH and d.plan is not None for d, _ in steps[end:])


def test_a_waiting_candidate_still_unreachable_when_the_frontiers_run_out_is_rejected():
    """Each candidate waits once: the collision marks are put back after every rescan, so when the
    frontiers run out it is approached once more and, still walled in, rejected."""
    world, steps = _walled_in_run(scored=True, again=True, max_steps=600, unreachable_forgive=0, last_resort=False)
    assert any(d.has(Context.NO_WAY_YET) for d, _ in steps)
    rejected = [c for c in steps[-1][1].candidates if c.state == "rejected"]
    assert [c.why for c in rejected] == ["unreachable for 10 steps"]
    assert world.distance_to_goal() > 1.0


def _scored_agent(world, decoy, goal_score, decoy_score, **policy):
    """The matcher's scores scripted (tau 100): the goal scores ``goal_score(distance)`` where it is
    in view, the decoy ``decoy_score(distance)``; localisation from the true masks."""
    from agent.reid.base import Matches
    from agent.reid.identifier import ReIDConfig, ReIDResult
    from tests.helpers.agent_runs import NoMatcher

    pol = dict(reid_source="matcher", localisation_source="oracle", potential_tau_ratio=0.5)
    pol.update(policy)
    agent = ModIINAgent(
        AgentConfig(reid=ReIDConfig(tau=100.0, gate=False), policy=PolicyConfig(**pol)),
        matcher=NoMatcher(),
        oracle_ego_mask=lambda obs: world.goal_mask(obs) if world.goal_visible(obs) else world._ids == decoy,
    )
    x0, y0, x1, y1, _ = world.boxes[decoy]

    def compare(rgb, use_gate=True):
        if world.goal_visible(None):
            score = goal_score(world.distance_to_goal())
        elif np.count_nonzero(world._ids == decoy) >= 20:
            d = math.hypot(
                world.pose.x_m - min(max(world.pose.x_m, x0), x1), world.pose.y_m - min(max(world.pose.y_m, y0), y1)
            )
            score = decoy_score(d)
        else:
            score = 0.0
        empty = np.zeros((0, 2), np.float32)
        return ReIDResult(score, Matches.empty(), empty, empty, 0.0, 0.0)

    agent.reid.compare = compare
    return agent


def test_a_look_from_the_verify_ring_at_half_tau_confirms_the_candidate():
    """The goal only ever scores 60 (tau/2 <= 60 < tau): a potential candidate. A look from the
    verify ring at tau/2 confirms it; without the switch the looks reject it."""
    boxes, goal, decoy = two_rooms()

    def run_with(ratio):
        world = BoxWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal)
        agent = _scored_agent(world, decoy, lambda d: 60.0, lambda d: 0.0, verify_ring_tau_ratio=ratio)
        return run_decisions(agent, world, max_steps=400), world

    steps, world = run_with(0.5)
    confirmed = [d for d, _ in steps if d.has(Context.RING_CONFIRMED)]
    assert len(confirmed) == 1 and confirmed[0].mode == Mode.APPROACH
    assert [n.facts["score"] for n in confirmed[0].context] == [60.0]
    # it was potential up to that look, confirmed from then on, and the robot stops at it
    first = next(i for i, (d, _) in enumerate(steps) if d is confirmed[0])
    assert any(c.state == "potential" for c in steps[first - 1][1].candidates)
    assert not any(d.event in (Event.VERIFY_LOOK, Event.VERIFY_STEP_NEARER) for d, _ in steps[first:])
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert [c.state for c in rec.candidates if c.id == rec.candidate_id] == ["confirmed"]

    steps, _ = run_with(1.0)
    assert not any(d.has(Context.RING_CONFIRMED) for d, _ in steps)
    assert any(c.why == "not re-identified in 8 looks from the verify ring" for _, r in steps for c in r.candidates)


def test_a_decoy_that_scores_low_from_the_verify_ring_is_still_rejected():
    """The decoy scores 60 from afar but 10 from within 2.6 m; the goal scores 200 (a detection)."""
    boxes, goal, decoy = two_rooms()
    world = BoxWorld(boxes, Pose2D(0.0, -1.0, math.pi * 0.75), goal)
    agent = _scored_agent(world, decoy, lambda d: 200.0, lambda d: 60.0 if d > 2.6 else 10.0, verify_ring_tau_ratio=0.5)
    steps = run_decisions(agent, world, max_steps=600)
    assert any(d.mode == Mode.VERIFY for d, _ in steps)
    assert not any(d.has(Context.RING_CONFIRMED) for d, _ in steps)
    last, rec = steps[-1]
    assert any(
        c.state == "rejected" and c.why == "not re-identified in 8 looks from the verify ring" for c in rec.candidates
    )
    assert last.mode == Mode.STOPPED and world.distance_to_goal() < 1.0


def _two_doors():
    """Room A (x -2..2.5) and room B (x 2.6..6), y -4..4, joined by a door at y in [-0.45, 0.45]
    and another at y in [3.0, 3.9]; the goal (a 0.6 m cube) in room B, seen through the near door
    from the start. The way through the near door is about 4 m, round by the far one over 7 m.
    ``low_kerb``: a kerb across the near door that the camera's map does not show (too low) but
    that stops the robot. Returns (world, the near door's x)."""
    walls = room_walls(-2.0, -4.0, 6.0, 4.0)
    walls += [(2.5, -4.0, 2.6, -0.45, 2.5), (2.5, 0.45, 2.6, 3.0, 2.5), (2.5, 3.9, 2.6, 4.0, 2.5)]
    goal = (4.5, -0.3, 5.1, 0.3, 0.6)
    return walls + [goal], len(walls)


def _through_a_marked_door(again: bool = False, kerb: bool = False, **policy):
    """A run in _two_doors where, after two steps of the approach, a failed move's collision marks
    close the near door (the marks are guesses: the door is open), put back whenever they were
    dropped when ``again``; ``kerb``: the door is closed for real by a kerb below the map's
    obstacle height, so the robot's own failed moves mark it. Returns (world, steps, crossings):
    where the true path crossed the wall between the rooms (the y of each crossing)."""
    boxes, goal = _two_doors()
    if kerb:
        boxes = boxes + [(2.45, -0.45, 2.65, 0.45, 0.02)]  # BoxWorld stops the robot; too low to map
    world = BoxWorld(boxes, Pose2D(0.0, 0.0, 0.0), goal)
    agent = oracle_agent(world, **policy)
    approach_steps = []

    def marks(agent) -> None:
        d = agent.last_decision
        if d is not None and d.mode == Mode.APPROACH:
            approach_steps.append(d)
        if kerb or len(approach_steps) < 2:
            return
        if len(approach_steps) == 2 or (again and not agent.grid.layers.collision.any()):
            r = agent.config.mapping.robot_radius_m
            for y in (-0.4, -0.2, 0.0, 0.2, 0.4):
                agent.grid.mark_collision(Pose2D(2.5 - r - 0.02, y, 0.0))

    path = []

    def track(agent) -> None:
        path.append(world.pose)
        marks(agent)

    steps = run_decisions(agent, world, max_steps=400, before_step=track)
    path.append(world.pose)
    crossings = [0.5 * (p.y_m + q.y_m) for p, q in zip(path, path[1:]) if (p.x_m < 2.55) != (q.x_m < 2.55)]
    return world, steps, crossings


def test_collision_marks_that_make_the_way_a_detour_are_dropped():
    # Off: the marks close the near door and the robot goes round by the far one
    world, steps, crossings = _through_a_marked_door(detour_forgive_m=0.0)
    assert steps[-1][0].mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert crossings and all(3.0 < y < 3.9 for y in crossings)
    assert not any(d.has(Context.MARKS_DROPPED) for d, _ in steps)
    detour = len(steps)
    # policy.detour_forgive_m: 2.0 (the default): the way grew by more than 2 m, the marks are
    # dropped (once), the robot goes through the near door, saying why
    world, steps, crossings = _through_a_marked_door()
    assert steps[-1][0].mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert crossings and all(abs(y) < 0.45 for y in crossings)
    dropped = [(d, rec) for d, rec in steps if d.has(Context.MARKS_DROPPED)]
    assert len(dropped) == 1
    (note,) = [n for n in dropped[0][0].context if n.context == Context.MARKS_DROPPED]
    assert note.facts["was_m"] > note.facts["now_m"] + 2.0 and note.facts["now_m"] < 4.0
    assert dropped[0][1].reason.startswith("collision marks dropped: they made the way")
    assert len(steps) < detour - 8


def test_marks_are_dropped_once_per_candidate():
    # the marks come back after the drop: the robot then goes round by the far door
    world, steps, crossings = _through_a_marked_door(again=True)
    assert sum(d.has(Context.MARKS_DROPPED) for d, _ in steps) == 1
    assert steps[-1][0].mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert crossings and all(3.0 < y < 3.9 for y in crossings)


def test_a_door_really_closed_is_tried_once_then_gone_round():
    # a kerb the map does not show: the robot's own failed moves mark the door; the marks are
    # dropped once, the door fails again, and the robot goes round by the far door
    world, steps, crossings = _through_a_marked_door(kerb=True)
    assert sum(d.has(Context.MARKS_DROPPED) for d, _ in steps) == 1
    assert steps[-1][0].mode == Mode.STOPPED and world.distance_to_goal() < 1.0
    assert crossings and all(3.0 < y < 3.9 for y in crossings)
