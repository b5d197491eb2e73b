"""The Mod-IIN agent (Krantz et al., ICCV 2023): frontier exploration, keypoint re-identification,
goal localisation by projected matches, fast-marching navigation (DESIGN section 2).

Per step: map the depth frame; re-identify (score the frame against the goal image); on a
detection, lift the matched goal keypoints into 3D goal points; then decide, as an explicit
state machine (``agent.modes``: look around, explore, approach, verify, rescan, stop), one
frozen ``Decision`` that goes into the step's ``AgentRecord``.

Beyond the paper (DESIGN section 2, end), each a switch in ``PolicyConfig`` (or
``FrontierConfig``), all off by default so that each can be measured alone:

* a full look-around at the start (``look_around_turns``; on in both deployments);
* ``verify`` with ``verify_by="close_range"``: a candidate is stopped at only after a
  detection from within ``verify_range_m`` of it; at the stop point without one, the agent
  scans left and right and rejects (blacklists) the candidate when nothing confirms it;
* ``verify`` with ``verify_by="approach"``: a candidate without such a detection is
  *potential*; the agent goes to a ring around it (outside the distance at which the level
  camera loses the candidate's top), faces it and looks ``verify_views`` times; a detection
  confirms it, none rejects it (IEVE's explore-verify-exploit, Lei et al. CVPR 2024);
* candidate memory with potential evidence (``potential_tau_ratio`` < 1): frames scoring
  below tau but above the ratio add goal points too; the candidate they form is potential
  and is verified by approach (``agent.candidates``; every candidate, rejected ones
  included, is in the ``AgentRecord``);
* where to stop (``stop_rule="core"``): measured from the candidate's core cells rather than
  its nearest (possibly stray) one, and only where the map shows a line of sight to it; the
  core weighs each cell by the points in it (``stop_core_by="points"``);
* the view check at the stop (``stop_needs_view``): facing the candidate, its core points that
  fall in the frame are looked up in the depth image; when something else hides them all (a
  wall between the robot and an object against its other side) the spot is struck off, what
  hid them blocks the candidate's line of sight, and the approach goes on;
* exploration by information gain (``frontier.gain_weight_m``);
* the last resort (``last_resort``): when nothing is left to explore, head for the rejected
  candidate with the best evidence and stop there (LAST_RESORT), instead of stopping in place;
* the deadline over a weaker candidate (``deadline_over_weaker``): at the deadline, the last
  resort also comes before verifying a potential candidate whose evidence is below the best
  rejected one's;
* the second look (``exhausted_recheck_frames``): when nothing is left to explore and there is no
  candidate at all, the searching frames with the most descriptor pairs with the goal (kept in
  ``agent.shortlist``) are scored again with the full matcher and their matches localised as
  potential evidence, verified by approach like any other.

Going to a candidate, verifying it, giving it up and the last resort live in
``agent.approach`` (mixed in). Rejected and unreachable candidates are blacklisted on the map (``GridMap.blacklist_cells``),
so their points and later points there are ignored and exploration resumes.

Oracle ablations are injected callables (the agent never imports sim/):
``oracle_reid(obs) -> bool`` (goal visible), ``oracle_ego_mask(obs) -> (H, W) bool``
(ground-truth egocentric instance mask), ``goal_mask_fn(goal_image) -> (h, w) bool``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import Callable

import numpy as np

from agent.background import Pending
from agent.candidates import CandidateMemory, CandidateState, GoalCandidate, evaluate
from agent.config import AgentConfig
from agent.frontier import FrontierExplorer, frontier_mask
from agent.localisation import Candidate, GoalLocaliser
from agent.mapping import GridMap
from agent.motion import after_action, move_key, safe_action
from agent.approach import CandidateNavigation
from agent.modes import SECOND_LOOK, Decision, Mode, PolicyState, RescanState
from agent.planner import DistanceField, FMMPlanner, Plan, PlanError
from agent.reid.identifier import ReIdentifier, ReIDResult, resolve_tau
from agent.reid.base import Matcher
from agent.segmentation import GoalMaskFn, GoalSegmenter
from agent.shortlist import FrameShortlist
from agent.types import Action, AgentRecord, Observation, Pose2D

log = logging.getLogger(__name__)

OracleReID = Callable[[Observation], bool]
OracleEgoMask = Callable[[Observation], np.ndarray]

_EMPTY2 = np.zeros((0, 2), np.float32)
_EMPTY3 = np.zeros((0, 3), np.float32)


class ModIINAgent(CandidateNavigation):
    """Implements ``agent.types.Agent``."""

    def __init__(
        self,
        config: AgentConfig = AgentConfig(),
        *,
        matcher: Matcher | None = None,
        oracle_reid: OracleReID | None = None,
        oracle_ego_mask: OracleEgoMask | None = None,
        goal_mask_fn: GoalMaskFn | None = None,
    ) -> None:
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
        self.segmenter = GoalSegmenter(config.segmentation, goal_mask_fn) if pc.localisation_source == "goal_mask" else None
        self.planner = FMMPlanner(config.planner)
        self._record: AgentRecord | None = None
        self._decision: Decision | None = None
        self._goal_image: np.ndarray | None = None
        self._goal_mask: Pending | None = None
        self._side_step = False  # set by _safe: this step's action is part of a side-step

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
        self._goal_image = goal_image
        self.grid = GridMap(self.config.mapping)
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
        self._prev_pose: Pose2D | None = None
        self._prev_action: Action | None = None
        self._state = PolicyState(rescan=RescanState(rescans_left=self.config.policy.max_rescans))
        self._record = None
        self._decision = None

    def act(self, obs: Observation) -> Action:
        if self._goal_image is None:
            raise RuntimeError("reset(goal_image) first")
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        pc = self.config.policy

        # 1. mapping (with collision marks for forward moves that did not move the robot)
        t = time.perf_counter()
        if self._prev_pose is not None:
            self._set(motion=after_action(self._state.motion, self._prev_action))
            if self._prev_action == Action.MOVE_FORWARD and obs.pose.distance_to(self._prev_pose) < pc.collision_min_motion_m:
                self.grid.mark_collision(self._prev_pose)
                m = self._state.motion
                self._set(motion=replace(m, blocked=m.blocked | {move_key(self.grid, self._prev_pose)}))
            self.grid.mark_visited((self._prev_pose.x_m, self._prev_pose.y_m), (obs.pose.x_m, obs.pose.y_m))
        else:
            self.grid.mark_visited((obs.pose.x_m, obs.pose.y_m), (obs.pose.x_m, obs.pose.y_m))
        self.grid.update(obs)
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
        added = _EMPTY3
        potential = (not detected and pc.reid_source == "matcher" and pc.potential_tau_ratio < 1.0
                     and self.tau is not None and score >= pc.potential_tau_ratio * self.tau)
        if potential:
            self._localise(obs, result, score)
        elif searching and not detected and result is not None and pc.reid_source == "matcher":
            # kept for a second look should exploration end with nothing (``agent.shortlist``)
            self.shortlist.offer(obs, result.gate_score if result.gate_score is not None else score)
        if detected:
            added = self._localise(obs, result, score)
            if len(added):
                c = added[:, :2].mean(axis=0)
                if math.hypot(c[0] - obs.pose.x_m, c[1] - obs.pose.y_m) <= pc.verify_range_m:
                    self._set(confirmed_xy_m=self._state.confirmed_xy_m + ((float(c[0]), float(c[1])),))
        candidates = self._evaluate(self.localiser.candidates(self.grid, self.tau))
        timings["localisation"] = _ms(t)

        # 4. decision and planning
        t = time.perf_counter()
        self._candidates_changed = False
        broke = 0 < pc.oscillation_turns <= self._state.motion.alternating_turns
        if broke:
            self._break_oscillation()
        self._side_step = False
        decision = self._decide(obs, candidates)
        if broke:
            decision = replace(decision, reason=f"turn-in-place livelock broken; {decision.reason}")
        if self._side_step:
            decision = replace(decision, reason=f"side-step out of turning to and fro; {decision.reason}")
        timings["planning"] = _ms(t)

        action = decision.action
        self._prev_pose, self._prev_action = obs.pose, action
        self._set(mode=decision.mode, steps=self._state.steps + 1)
        self._decision = decision
        snap = None
        if pc.snapshot_every > 0 and (obs.step % pc.snapshot_every == 0 or action == Action.STOP):
            snap = self.grid.snapshot(frontier_mask(self.grid, self.config.frontier.min_cluster_cells))
        timings["total"] = _ms(t_start)  # includes the record's map snapshot
        plan, cand = decision.plan, decision.candidate
        robot_xy = (obs.pose.x_m, obs.pose.y_m)
        # the candidates as they stand after the decision (a rejection changes them)
        live = self._evaluate(self.localiser.candidates(self.grid, self.tau)) if self._candidates_changed else candidates
        self._record = AgentRecord(
            step=obs.step,
            action=action,
            pose=obs.pose,
            mode=decision.mode.value,
            reason=decision.reason,
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
        return action

    # --- state ---------------------------------------------------------------------

    def _set(self, **changes) -> None:
        self._state = replace(self._state, **changes)

    def _break_oscillation(self) -> None:
        """Turned to and fro ``oscillation_turns`` times (config.py says why): give up the frontier
        (as after no progress) and spend one rescan's forgiving."""
        if self._state.mode == Mode.EXPLORE:
            self.explorer.blacklist_target(self.grid, "to and fro")
        r = self._state.rescan
        self._set(motion=replace(self._state.motion, alternating_turns=0), rescan=replace(r, rescans_left=max(0, r.rescans_left - 1)))
        log.info("turned to and fro on the spot: frontier given up, %d rescans left", self._state.rescan.rescans_left)

    def _safe(self, plan: Plan, pose: Pose2D, field: DistanceField) -> Action:
        before = self._state.motion.detour
        action, motion = safe_action(plan, pose, field, self.grid, self.planner, self._state.motion,
                                     self.config.policy.detour_after_turns)
        self._set(motion=motion)
        # a side-step under way, or its last action (the step forward from the cell it began on)
        self._side_step = motion.detour is not None or (
            before is not None and action == Action.MOVE_FORWARD and before[:2] == move_key(self.grid, pose)[:2])
        return action

    # --- localisation and candidates ---------------------------------------------------

    def _localise(self, obs: Observation, result: ReIDResult | None, score: float) -> np.ndarray:
        if self.config.policy.localisation_source == "oracle":
            assert self.oracle_ego_mask is not None
            return self.localiser.add_mask_pixels(obs, np.asarray(self.oracle_ego_mask(obs), bool), score)
        assert result is not None and self.goal_mask is not None
        return self.localiser.add_matches(obs, result.goal_xy, result.obs_xy, self.goal_mask, score)

    @property
    def goal_mask(self) -> np.ndarray | None:
        """(h, w) bool mask of the goal instance in the goal image (waits for it the first time)."""
        return self._goal_mask.result() if self._goal_mask is not None else None

    def _evaluate(self, clusters: list[Candidate]) -> list[GoalCandidate]:
        """Clusters -> candidates with their evidence and state (``agent.candidates``)."""
        pc = self.config.policy
        tau = self.tau if self.tau is not None else 0.5  # the oracle's score is 1 or 0
        by_approach = pc.verify and pc.verify_by == "approach"
        return [evaluate(c, self.localiser, tau, pc.verify_range_m if by_approach else None, self._state.ring_confirmed)
                for c in clusters]

    def _pick(self, candidates: list[GoalCandidate]) -> GoalCandidate | None:
        """Confirmed candidates first; among them (or among the potential ones when none is
        confirmed) the largest cluster (the paper), or the best-scoring one."""
        if not candidates:
            return None
        pool = [c for c in candidates if c.state == CandidateState.CONFIRMED] or candidates
        if self.config.policy.rank_candidates_by == "score" or pool[0].state == CandidateState.POTENTIAL:
            return max(pool, key=lambda c: (c.best_score, c.cluster.n_points))
        return pool[0]

    # --- the state machine -----------------------------------------------------------

    def _decide(self, obs: Observation, candidates: list[GoalCandidate]) -> Decision:
        pc = self.config.policy
        picked = self._pick(candidates)
        if picked is None and self._state.steps < pc.look_around_turns:
            return Decision(Action.TURN_LEFT, Mode.LOOK_AROUND,
                            f"initial look-around {self._state.steps + 1}/{pc.look_around_turns}")
        if picked is not None and picked.state == CandidateState.POTENTIAL:
            decision = self._deadline_over(obs, picked)
            if decision is not None:
                return decision
        if picked is not None:
            self.grid.set_goal_cells(picked.cluster.cells_ij)
            if picked.state == CandidateState.POTENTIAL:
                decision = self._verify_by_approach(obs, picked)
            else:
                decision = self._approach(obs, picked.cluster)
            if decision is not None:
                return decision
            cands = self._evaluate(self.localiser.candidates(self.grid, self.tau))  # the candidate was rejected
            self.grid.clear_goal()
            if cands:
                return self._decide(obs, cands)
        else:
            self.grid.clear_goal()
        if self._deadline_due(obs):
            decision = self._last_resort(obs)
            if decision is not None:
                left = self.config.policy.step_budget - obs.step
                return replace(decision, reason=f"{left} steps of the budget left: {decision.reason}")
        return self._explore(obs)

    def _deadline_over(self, obs: Observation, picked: GoalCandidate) -> Decision | None:
        """``policy.deadline_over_weaker``: the last resort at the deadline before verifying
        ``picked`` (potential), when a rejected candidate left to try has better evidence."""
        pc = self.config.policy
        if not pc.deadline_over_weaker:
            return None
        lr = self._state.last_resort
        cid = lr.candidate_id if lr.candidate_id is not None else self.memory.best_rejected(exclude=lr.tried)
        if cid is None or self.memory.best_score_of(cid) <= picked.best_score or not self._deadline_due(obs):
            return None
        decision = self._last_resort(obs)
        tried = self._state.last_resort.candidate_id
        if decision is None or tried is None or self.memory.best_score_of(tried) <= picked.best_score:
            return None  # the rejected ones left to try are no better (those better were unreachable)
        left = pc.step_budget - obs.step
        return replace(decision, reason=f"{left} steps of the budget left, potential candidate weaker "
                                        f"(best score {picked.best_score:.1f}): {decision.reason}")

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
            action = self._safe(plan, pose, field)
            if action != plan.action and self._state.motion.blocked_repeats > 3:
                self.explorer.blacklist_target(grid, "blocked")
            return Decision(action, Mode.EXPLORE, f"frontier ({choice.reason})", plan=plan, target_kind="frontier",
                            planner_error=error)
        return self._rescan(obs, error)

    def _rescan(self, obs: Observation, error: str | None) -> Decision:
        # No reachable frontier. Collision marks are guesses (the blocked side of a move is
        # unknown) and a frontier given up as reached or stalled may still lead somewhere (a
        # doorway passed at an angle): forgive both and look around again before giving up.
        r = self._state.rescan
        if r.rescans_left > 0:
            if r.steps == 0:
                self.grid.forgive_collisions()
                self.grid.forgive_frontiers()
                self.explorer.reset()
                log.info("no reachable frontier: cleared collision marks and given-up frontiers, looking around again")
            steps = r.steps + 1
            if steps >= self.config.policy.look_around_turns or steps >= 12:
                r = RescanState(steps=0, rescans_left=r.rescans_left - 1)
            else:
                r = replace(r, steps=steps)
            self._set(rescan=r)
            return Decision(Action.TURN_LEFT, Mode.RESCAN, "no reachable frontier: looking around again",
                            planner_error=error or "no_frontier")
        if self.config.policy.last_resort:
            decision = self._last_resort(obs)
            if decision is not None:
                return decision
        decision = self._recheck(obs)
        if decision is not None:
            return decision
        # Nothing left to explore and no goal: a deliberate stop, reported as such.
        return Decision(Action.STOP, Mode.EXHAUSTED, "no reachable frontier and no goal candidate",
                        planner_error=error or "no_frontier")

    def _recheck(self, obs: Observation) -> Decision | None:
        """The second look when exhausted (``policy.exhausted_recheck_frames``): score the kept
        frames again with the full matcher, localise their matches whatever the score, and decide
        on the candidates they form (None: no candidate came of it, or already done)."""
        pc = self.config.policy
        if (self._state.rechecked or len(self.shortlist) == 0 or self.reid is None
                or pc.reid_source != "matcher" or pc.localisation_source != "goal_mask"):
            return None
        self._set(rechecked=True)
        self._candidates_changed = True  # the candidates change during this decision: the record re-reads them
        frames = self.shortlist.take()
        scored = [(kept, self.reid.compare(kept.rgb, use_gate=False)) for _, kept in frames
                  if self.localiser.view(kept.step) is None]
        floor = pc.exhausted_recheck_min_share * max((r.score for _, r in scored), default=0.0)
        scores = [r.score for kept, r in scored
                  if r.score > 0 and r.score >= floor and len(self._localise(kept, r, r.score))]
        found = f"{len(scores)} of the {len(frames)} frames kept added points" + (
            f" (best score {max(scores):.1f})" if scores else "")
        log.info("exploration exhausted with no candidate: second look, %s", found)
        cands = self._evaluate(self.localiser.candidates(self.grid, self.tau)) if scores else []
        if not cands:
            return None
        decision = self._decide(obs, cands)
        if decision.mode == Mode.EXHAUSTED:
            return None
        return replace(decision, reason=f"{SECOND_LOOK}: {found}; {decision.reason}")


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
