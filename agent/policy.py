"""The Mod-IIN agent (Krantz et al., ICCV 2023): frontier exploration, keypoint re-identification,
goal localisation by projected matches, fast-marching navigation (docs/architecture.md section 2).

Per step: map the depth frame; re-identify (score the frame against the goal image); on a
detection, lift the matched goal keypoints into 3D goal points; then decide, as an explicit
state machine (``agent.modes``: look around, explore, approach, verify, rescan, stop), one
frozen ``Decision`` that goes into the step's ``AgentRecord``.

Beyond the paper (docs/architecture.md section 2, end; the evidence for each is in
docs/experiments/), each with its setting in ``PolicyConfig``:

* a full look-around at the start (``look_around_turns``);
* candidate memory with potential evidence (``potential_tau_ratio``): frames scoring below tau
  but above the ratio add goal points too; the candidate they form is potential and is
  verified by approach from a ring around it (``agent.approach``; IEVE's explore-verify-exploit,
  Lei et al. CVPR 2024), where a look at ``verify_ring_tau_ratio`` x tau confirms it;
* where to stop (``stop_rule="core"``): measured from the candidate's core cells rather than
  its nearest (possibly stray) one, and only where the map shows a line of sight to it;
* the last resort (``last_resort``): when nothing is left to explore, head for the rejected
  candidate with the best evidence and stop there, instead of stopping in place; also at the
  deadline (``last_resort_at_deadline``), and then before verifying a weaker potential candidate
  (``deadline_over_weaker``);
* the side-step out of turning to and fro (``detour_after_turns``);
* a fresh map when exploration runs out early with nothing worth going to
  (``fresh_map_min_steps_left``, ``fresh_map_below_tau_ratio``): the rescans spent with budget
  left and no rejected candidate scoring above what different objects score, the second look
  is taken, then the map's geometry is forgotten (walls drawn off by a drifting pose and noisy
  depth close doorways for good) and the robot looks around and explores again, once;
* the second look (``exhausted_recheck_frames``): when nothing is left to explore and there is no
  candidate at all, the searching frames with the most descriptor pairs with the goal (kept in
  ``agent.shortlist``) are scored again with the full matcher and their matches localised as
  potential evidence, verified by approach like any other.

The candidate side (approach, verify, reject, last resort, steering) is a component,
``agent.approach.CandidateNavigator``: it takes the step's scene and the policy state and returns
the decision and the next state. Rejected and unreachable candidates are blacklisted on the map
(``GridMap.blacklist_cells``), so their points and later points there are ignored and
exploration resumes.

The memory of a home (``agent.memory.HomeMemory``, issue 31): an agent made with
``home_memory=`` keeps the map across goals, offers every searching frame to the memory as a
keyframe, and at ``reset`` scores the new goal against the remembered keyframes first, so that
a goal seen before becomes a candidate before the first step. Without one (the default) each
``reset`` starts from nothing, as in the paper.

Oracle ablations are injected callables (the agent never imports sim/):
``oracle_reid(obs) -> bool`` (goal visible), ``oracle_ego_mask(obs) -> (H, W) bool``
(ground-truth egocentric instance mask), ``goal_mask_fn(goal_image) -> (h, w) bool``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from agent.alignment import Alignment, agrees
from agent.approach import CandidateNavigator, Scene
from agent.background import Pending
from agent.candidates import CandidateMemory, CandidateState, GoalCandidate, evaluate
from agent.config import AgentConfig
from agent.events import Context, Event, event_facts
from agent.exhausted import rescan
from agent.frontier import FrontierExplorer, frontier_mask
from agent.localisation import Candidate, GoalLocaliser
from agent.mapping import GridMap
from agent.memory import HomeMemory
from agent.modes import Decision, Mode, PolicyState, RescanState
from agent.motion import after_action, move_key
from agent.planner import FMMPlanner, Plan, PlanError
from agent.reid.base import Matcher
from agent.reid.identifier import ReIdentifier, ReIDResult, resolve_tau
from agent.segmentation import GoalMaskFn, GoalSegmenter
from agent.shortlist import FrameShortlist
from agent.types import Action, AgentRecord, Observation, Pose2D

log = logging.getLogger(__name__)

OracleReID = Callable[[Observation], bool]
OracleEgoMask = Callable[[Observation], np.ndarray]

_EMPTY2 = np.zeros((0, 2), np.float32)
_EMPTY3 = np.zeros((0, 3), np.float32)


class ModIINAgent:
    """Implements ``agent.types.Agent``."""

    def __init__(
        self,
        config: AgentConfig = AgentConfig(),
        *,
        matcher: Matcher | None = None,
        oracle_reid: OracleReID | None = None,
        oracle_ego_mask: OracleEgoMask | None = None,
        goal_mask_fn: GoalMaskFn | None = None,
        home_memory: HomeMemory | None = None,
    ) -> None:
        """``home_memory``: the memory of the home this agent works in (``agent.memory``); each
        ``reset`` is then the next goal in that home. It may also be set (or changed) between
        goals as the attribute ``home_memory``; None: every goal starts from nothing."""
        pc = config.policy
        if pc.reid_source == "oracle" and oracle_reid is None:
            raise ValueError("policy.reid_source 'oracle' needs an injected oracle_reid callable")
        if pc.localisation_source == "oracle" and oracle_ego_mask is None:
            raise ValueError("policy.localisation_source 'oracle' needs an injected oracle_ego_mask callable")
        self.config = config
        self.oracle_reid = oracle_reid
        self.oracle_ego_mask = oracle_ego_mask
        needs_matcher = pc.reid_source == "matcher" or pc.localisation_source == "goal_mask"
        self.tau = resolve_tau(config.reid) if pc.reid_source == "matcher" else None
        # potential evidence (frames above potential_tau_ratio x tau) must get past the gate too
        floor = pc.potential_tau_ratio if pc.reid_source == "matcher" and pc.potential_tau_ratio < 1.0 else 1.0
        self.reid = ReIdentifier(config.reid, matcher, min_score_ratio=floor) if needs_matcher else None
        self.segmenter = (
            GoalSegmenter(config.segmentation, goal_mask_fn) if pc.localisation_source == "goal_mask" else None
        )
        self.planner = FMMPlanner(config.planner)
        self.nav = CandidateNavigator(pc, self.planner, self.tau)
        self._record: AgentRecord | None = None
        self._decision: Decision | None = None
        self._goal_image: np.ndarray | None = None
        self._goal_mask: Pending | None = None
        self.home_memory = home_memory

    # --- Agent protocol -------------------------------------------------------------

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record

    @property
    def last_decision(self) -> Decision | None:
        return self._decision

    @property
    def mode(self) -> Mode:
        return self._state.mode

    def reset(self, goal_image: np.ndarray) -> None:
        """Start a goal: from nothing, or (with ``home_memory``) in the remembered map, with the
        goal scored against the remembered keyframes before the first step."""
        self._goal_image = goal_image
        home = self.home_memory
        if home is None:
            self.grid = GridMap(self.config.mapping)
        else:
            self.grid = home.begin_goal(self.config.mapping, self.reid.matcher.name if self.reid is not None else None)
        self.explorer = FrontierExplorer(self.config.frontier)
        self.localiser = GoalLocaliser(self.config.localisation)
        self.memory = CandidateMemory()
        self.shortlist = FrameShortlist(self.config.policy.exhausted_recheck_frames)
        if self.reid is not None:
            self.reid.set_goal(goal_image)
        # The goal-image mask is needed only at the first detection (localisation), not for
        # the first action: GrabCut (0.1-0.5 s) runs beside the first steps, on a thread of its
        # own (OpenCV releases the GIL); the first localisation waits for it. Same mask, same
        # decisions, shorter start.
        self._goal_mask = Pending(self.segmenter.mask, goal_image) if self.segmenter is not None else None
        self._prev_pose: Pose2D | None = None  # aligned (agent.alignment)
        self._prev_estimate: Pose2D | None = None  # as received
        self._alignment: Alignment | None = None  # the last frame's proposal (agent.alignment)
        self._prev_action: Action | None = None
        self._state = PolicyState(rescan=RescanState(rescans_left=self.config.policy.max_rescans))
        self._record = None
        self._decision = None
        # the explored area of earlier goals (``agent.memory``), forgotten at the first rescan
        self._explored_carried = home is not None and bool(self.grid.layers.explored.any())
        if home is not None:
            self._recall(home)

    def act(self, obs: Observation) -> Action:
        if self._goal_image is None:
            raise RuntimeError("reset(goal_image) first")
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        pc = self.config.policy

        # 1. mapping (with collision marks for forward moves that did not move the robot)
        t = time.perf_counter()
        if self._prev_pose is None and self.home_memory is not None:
            self.home_memory.check_start(obs.pose)
        # the frame aligned to the map: from here on the agent's pose is the aligned one, except
        # that whether a move moved the robot is judged on the estimates (odometry)
        estimate = obs.pose
        frame = self.grid.lift(obs)
        if self.config.alignment.enabled:
            t_align = time.perf_counter()
            aligned = self.grid.align(frame, self.config.alignment)
            if agrees(self._alignment, aligned, self.config.alignment):
                obs = replace(obs, pose=aligned.pose)
            self._alignment = aligned
            timings["align"] = _ms(t_align)
        if self._prev_pose is not None:
            assert self._prev_action is not None and self._prev_estimate is not None  # set with the pose
            self._set(motion=after_action(self._state.motion, self._prev_action))
            if (
                self._prev_action == Action.MOVE_FORWARD
                and estimate.distance_to(self._prev_estimate) < pc.collision_min_motion_m
            ):
                self.grid.mark_collision(self._prev_pose)
                m = self._state.motion
                self._set(motion=replace(m, blocked=m.blocked | {move_key(self.grid, self._prev_pose)}))
            self.grid.mark_visited((self._prev_pose.x_m, self._prev_pose.y_m), (obs.pose.x_m, obs.pose.y_m))
        else:
            self.grid.mark_visited((obs.pose.x_m, obs.pose.y_m), (obs.pose.x_m, obs.pose.y_m))
        self.grid.update(obs, frame)
        timings["mapping"] = _ms(t)

        # 2. re-identification
        t = time.perf_counter()
        # The gate only while searching: near a candidate (approaching or verifying it) every
        # frame gets the full matcher, because close views of a large object share few
        # mutually-nearest descriptors with the goal photo (train: a frame scoring 141 with a
        # gate score of 23, the object covering half the image) and those frames decide.
        searching = self._state.mode in (Mode.LOOK_AROUND, Mode.EXPLORE, Mode.RESCAN)
        result = self.reid.compare(obs.rgb, use_gate=searching) if self.reid is not None else None
        if pc.reid_source == "oracle":
            assert self.oracle_reid is not None
            detected = bool(self.oracle_reid(obs))
            score = 1.0 if detected else 0.0
        else:
            assert result is not None and self.tau is not None
            score = result.score
            detected = score >= self.tau
        timings["reid"] = _ms(t)
        if result is not None:
            timings["reid_extract"] = result.extract_ms
            timings["reid_match"] = result.match_ms
            timings["reid_gate"] = result.gate_ms

        # 3. localisation
        t = time.perf_counter()
        potential = (
            not detected
            and pc.reid_source == "matcher"
            and pc.potential_tau_ratio < 1.0
            and self.tau is not None
            and score >= pc.potential_tau_ratio * self.tau
        )
        if potential or detected:
            self._localise(obs, result, score)
        elif searching and result is not None and pc.reid_source == "matcher":
            # kept for a second look should exploration end with nothing (``agent.shortlist``)
            self.shortlist.offer(obs, result.gate_score if result.gate_score is not None else score)
        candidates = self._evaluate(self.localiser.candidates(self.grid, self.tau))
        timings["localisation"] = _ms(t)
        if self.home_memory is not None and searching and result is not None and result.features is not None:
            # a keyframe for later goals: the features just extracted, each keypoint's 3D point
            t = time.perf_counter()
            feats = result.features
            assert self.reid is not None  # it made the features
            points = self.localiser.keypoint_points(obs, feats.keypoints_xy)
            self.home_memory.offer(
                obs, feats, points, self.reid.matcher.name, self.config.localisation.min_points_per_frame
            )
            timings["memory"] = _ms(t)

        # 4. decision and planning
        t = time.perf_counter()
        rejections, rechecked = self.memory.rejections, self._state.rechecked
        self._set(motion=replace(self._state.motion, side_step=False))
        decision = self._decide(obs, candidates)
        if self._state.motion.side_step:
            decision = decision.within(Context.SIDE_STEP)
        timings["planning"] = _ms(t)

        action = decision.action
        self._prev_pose, self._prev_estimate, self._prev_action = obs.pose, estimate, action
        self._set(mode=decision.mode, steps=self._state.steps + 1)
        self._decision = decision
        snap = None
        if pc.snapshot_every > 0 and (obs.step % pc.snapshot_every == 0 or action == Action.STOP):
            snap = self.grid.snapshot(frontier_mask(self.grid, self.config.frontier.min_cluster_cells))
        timings["total"] = _ms(t_start)  # includes the record's map snapshot
        plan, cand = decision.plan, decision.candidate
        robot_xy = (obs.pose.x_m, obs.pose.y_m)
        # the candidates as they stand after the decision (a rejection or the second look changes them)
        changed = self.memory.rejections != rejections or self._state.rechecked != rechecked
        live = self._evaluate(self.localiser.candidates(self.grid, self.tau)) if changed else candidates
        self._record = AgentRecord(
            step=obs.step,
            action=action,
            pose=obs.pose,
            mode=decision.mode.value,
            reason=decision.reason,
            event=decision.event.value,
            context=tuple(n.context.value for n in decision.context),
            reid_score=score,
            reid_tau=self.tau,
            reid_full_matcher=result.full_matcher if result is not None else None,
            reid_gate_score=result.gate_score if result is not None else None,
            reid_exit_score=result.exit_score if result is not None else None,
            goal_detected=detected,
            matches_goal_xy=result.goal_xy.astype(np.float32) if result is not None else _EMPTY2,
            matches_obs_xy=result.obs_xy.astype(np.float32) if result is not None else _EMPTY2,
            goal_points_xyz=cand.points_xyz if cand is not None else _EMPTY3,
            target_xy_m=plan.target_xy_m if plan is not None else None,
            target_kind=decision.target_kind,
            plan_xy_m=plan.path_xy_m if plan is not None else _EMPTY2,
            map=snap,
            timings_ms=timings,
            planner_error=decision.planner_error,
            candidates=self.memory.infos(live, robot_xy),
            candidate_id=cand.id if cand is not None else None,
        )
        if self.home_memory is not None:
            self.home_memory.note(self._record)
        return action

    # --- state ---------------------------------------------------------------------

    def _set(self, **changes) -> None:
        self._state = replace(self._state, **changes)

    def _scene(self, obs: Observation) -> Scene:
        return Scene(obs, self.grid, self.memory)

    # --- localisation and candidates ---------------------------------------------------

    def _localise(self, obs: Observation, result: ReIDResult | None, score: float) -> np.ndarray:
        if self.config.policy.localisation_source == "oracle":
            assert self.oracle_ego_mask is not None
            return self.localiser.add_mask_pixels(obs, np.asarray(self.oracle_ego_mask(obs), bool), score)
        assert result is not None and self.goal_mask is not None
        return self.localiser.add_matches(obs, result.goal_xy, result.obs_xy, self.goal_mask, score)

    def _recall(self, home: HomeMemory) -> None:
        """The new goal against the memory (``HomeMemory.localise``): remembered keyframes scoring
        at least the potential-evidence threshold (tau without it) add goal points as a live frame
        does, and the candidates they form are decided on like any. Such a candidate also skips the
        look-around (``_decide`` looks around only while there is no candidate): the look-around
        is there to find the goal near the start before committing to a frontier, and a
        remembered candidate already says where to go; live frames on the way confirm or reject
        it, and a rejection with look-around turns left resumes it. When memory gives nothing,
        the goal starts with the look-around, as without memory."""
        pc = self.config.policy
        if (
            self.reid is None
            or self.tau is None
            or pc.reid_source != "matcher"
            or pc.localisation_source != "goal_mask"
        ):
            return
        ratio = pc.potential_tau_ratio if pc.potential_tau_ratio < 1.0 else 1.0
        mask = self._goal_mask
        assert mask is not None  # goal_mask localisation has a segmenter
        home.localise(
            self.reid,
            self.localiser,
            mask.result,
            top_k=self.config.memory.recall_keyframes,
            min_score=ratio * self.tau,
        )

    @property
    def goal_mask(self) -> np.ndarray | None:
        """(h, w) bool mask of the goal instance in the goal image (waits for it the first time)."""
        return self._goal_mask.result() if self._goal_mask is not None else None

    def _evaluate(self, clusters: list[Candidate]) -> list[GoalCandidate]:
        """Clusters -> candidates with their evidence and state (``agent.candidates``)."""
        tau = self.tau if self.tau is not None else 0.5  # the oracle's score is 1 or 0
        return [evaluate(c, self.localiser, tau, self._state.ring_confirmed) for c in clusters]

    @staticmethod
    def _pick(candidates: list[GoalCandidate]) -> GoalCandidate | None:
        """Confirmed candidates first, the largest cluster among them (the paper); when none is
        confirmed, the potential one with the best score."""
        if not candidates:
            return None
        pool = [c for c in candidates if c.state == CandidateState.CONFIRMED] or candidates
        if pool[0].state == CandidateState.POTENTIAL:
            return max(pool, key=lambda c: (c.best_score, c.cluster.n_points))
        return pool[0]

    # --- the state machine -----------------------------------------------------------

    def _no_way_yet(
        self, obs: Observation, candidates: list[GoalCandidate]
    ) -> tuple[list[GoalCandidate], float | None]:
        """The candidates without those still waiting for a way on the map (``CandidateNavigator.no_way``;
        one that has a way now is taken back), and the best score among those left waiting (None:
        none)."""
        waiting = self._state.waiting
        if not waiting:
            return candidates, None
        keep, still, best = [], set(), None
        for c in candidates:
            if c.cluster.id in waiting and not self.nav.has_way(self._scene(obs), c.cluster):
                still.add(c.cluster.id)
                best = max(best or 0.0, float(c.best_score))
                continue
            if c.cluster.id in waiting:
                log.info("goal candidate at %s: a way on the map now", c.cluster.centroid_xy_m)
            keep.append(c)
        self._set(waiting=frozenset(still))  # ids no longer among the candidates are dropped
        return keep, best

    def _decide(self, obs: Observation, candidates: list[GoalCandidate]) -> Decision:
        pc = self.config.policy
        candidates, no_way_score = self._no_way_yet(obs, candidates)
        picked = self._pick(candidates)
        if picked is None:
            decision = self._look_around(obs)
            if decision is not None:
                return decision
        if picked is not None and picked.state == CandidateState.POTENTIAL:
            decision = self._deadline_over(obs, picked)
            if decision is not None:
                return decision
        if picked is not None:
            self.grid.set_goal_cells(picked.cluster.cells_ij)
            if picked.state == CandidateState.POTENTIAL:
                decision, self._state = self.nav.verify_by_approach(self._scene(obs), self._state, picked)
            else:
                decision, self._state = self.nav.approach(self._scene(obs), self._state, picked.cluster)
            if decision is not None:
                if picked.remembered_only and not decision.has(Context.RING_CONFIRMED):
                    # said, not acted on: a stop here rests on what the memory saw (docs/experiments/memory.md)
                    decision = decision.within(Context.FROM_MEMORY, score=picked.best_score)
                return decision
            cands = self._evaluate(self.localiser.candidates(self.grid, self.tau))  # the candidate was rejected
            self.grid.clear_goal()
            if cands:
                return self._decide(obs, cands)
        else:
            self.grid.clear_goal()
        due, self._state = self.nav.deadline_due(self._scene(obs), self._state)
        if due:
            decision, self._state = self.nav.last_resort(self._scene(obs), self._state)
            if decision is not None:
                return decision.within(Context.DEADLINE, steps_left=pc.step_budget - obs.step)
        decision = self._explore(obs)
        if no_way_score is not None and decision.mode == Mode.EXPLORE:
            return decision.within(Context.NO_WAY_YET, score=no_way_score)
        return decision

    def _look_around(self, obs: Observation) -> Decision | None:
        """A turn of the look-around at the start, or after the map was started again (None: its
        turns are done)."""
        pc, st = self.config.policy, self._state
        turn = st.steps - (st.fresh_map_step or 0)
        if turn >= pc.look_around_turns:
            return None
        decision = Decision(
            Action.TURN_LEFT,
            Mode.LOOK_AROUND,
            Event.LOOK_AROUND,
            event_facts(turn=turn + 1, turns=pc.look_around_turns),
        )
        if st.fresh_map_step is None:
            return decision
        steps_left = pc.step_budget - obs.step + turn
        return decision.within(Context.FRESH_MAP, steps_left=steps_left, dropped=st.fresh_map_dropped)

    def _deadline_over(self, obs: Observation, picked: GoalCandidate) -> Decision | None:
        """``policy.deadline_over_weaker``: the last resort at the deadline before verifying
        ``picked`` (potential), when a rejected candidate left to try has better evidence."""
        pc = self.config.policy
        if not pc.deadline_over_weaker:
            return None
        lr = self._state.last_resort
        cid = self.memory.last_resort_next(lr.candidate_id, lr.tried)
        if cid is None or self.memory.best_score_of(cid) <= picked.best_score:
            return None
        due, self._state = self.nav.deadline_due(self._scene(obs), self._state)
        if not due:
            return None
        decision, self._state = self.nav.last_resort(self._scene(obs), self._state)
        tried = self._state.last_resort.candidate_id
        if decision is None or tried is None or self.memory.best_score_of(tried) <= picked.best_score:
            return None  # the rejected ones left to try are no better (those better were unreachable)
        return decision.within(
            Context.DEADLINE_OVER_WEAKER, steps_left=pc.step_budget - obs.step, score=picked.best_score
        )

    def _explore(self, obs: Observation) -> Decision:
        """EXPLORE the nearest frontier; RESCAN when none is reachable; EXHAUSTED at the end."""
        grid, pose = self.grid, obs.pose
        front = frontier_mask(grid, self.config.frontier.min_cluster_cells)
        field = self.planner.distance_field(grid, pose)
        error = None
        for _ in range(3):
            choice = self.explorer.choose(grid, field, front)
            if choice is None:
                break
            target = np.zeros(grid.shape, bool)
            target[choice.target_ij] = True
            try:
                plan: Plan = self.planner.plan(grid, field, pose, target)
            except PlanError as exc:
                error = f"{exc.reason}: {exc}"
                self.explorer.blacklist_target(grid, exc.reason)
                front = frontier_mask(grid, self.config.frontier.min_cluster_cells)
                continue
            self._set(rescan=replace(self._state.rescan, steps=0))
            action, self._state = self.nav.steer(self._scene(obs), self._state, plan, field)
            if action != plan.action and self._state.motion.blocked_repeats > 3:
                self.explorer.blacklist_target(grid, "blocked")
            return Decision(
                action,
                Mode.EXPLORE,
                Event.FRONTIER,
                event_facts(choice=choice.reason),
                plan=plan,
                target_kind="frontier",
                planner_error=error,
            )
        return rescan(self, obs, error)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
