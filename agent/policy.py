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
  candidate with the best evidence and stop there (LAST_RESORT), instead of stopping in place.

Rejected and unreachable candidates are blacklisted on the map (``GridMap.blacklist_cells``),
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
from agent.motion import after_action, blocked_here, move_key, safe_action
from agent.modes import SCAN_TURNS, ApproachState, Decision, Mode, PolicyState, RescanState, VerifyState
from agent.planner import DistanceField, FMMPlanner, Plan, PlanError, region_within
from agent.reid.identifier import ReIdentifier, ReIDResult, resolve_tau
from agent.reid.base import Matcher
from agent.segmentation import GoalMaskFn, GoalSegmenter
from agent.stop_region import cells_near, core_view, in_sight, stop_cells as stop_cells_of
from agent.types import FORWARD_STEP_M, Action, AgentRecord, Observation, Pose2D, wrap_angle

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
        self._rejected_now = False
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
        live = self._evaluate(self.localiser.candidates(self.grid, self.tau)) if self._rejected_now else candidates
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

    def _confirmed(self, cand: Candidate) -> bool:
        if not self.config.policy.verify:
            return True
        if not self._state.confirmed_xy_m:
            return False
        cells = self.grid.ij_to_xy(cand.cells_ij)
        conf = np.asarray(self._state.confirmed_xy_m)
        d = np.hypot(cells[:, None, 0] - conf[None, :, 0], cells[:, None, 1] - conf[None, :, 1])
        return bool(d.min() <= self.config.policy.verify_match_radius_m)

    def _reject(self, cand: Candidate, why: str, robot_xy_m: tuple[float, float]) -> None:
        log.info("rejecting goal candidate at %s (%s)", cand.centroid_xy_m, why)
        self.memory.reject(cand, robot_xy_m, self.grid.ij_to_xy(cand.cells_ij), why)
        self._rejected_now = True
        # A candidate that never scored tau was only potential: reject its sub-tau evidence, not
        # a later detection there (a rejected true goal would otherwise be lost for good)
        soft = self.config.policy.soft_reject_potential and self.tau is not None and cand.max_score < self.tau
        self.grid.blacklist_cells(cand.cells_ij, self.config.policy.reject_radius_m,
                                  layer="potential_blacklist" if soft else "blacklist")
        a = self._state.approach
        self._set(approach=replace(a, best_distance_m=math.inf, stall_steps=0, unreachable_steps=0, collisions_forgiven=0),
                  verify=None)

    def _forgive_before_reject(self) -> bool:
        """Before a candidate is given up as unreachable: drop the collision marks (as a rescan
        does; ``policy.unreachable_forgive`` times per candidate) and try again. Each failed move
        near an object leaves a band as wide as the robot, inflated on every side, so a few of them
        can wall in a stop region the robot could reach (train-s1-0012-0: a TV scoring 121).
        The motion memory still refuses the very moves that failed. True when marks were dropped."""
        a = self._state.approach
        if a.collisions_forgiven >= self.config.policy.unreachable_forgive or not self.grid.layers.collision.any():
            return False
        self.grid.forgive_collisions()
        self._set(approach=replace(a, unreachable_steps=0, collisions_forgiven=a.collisions_forgiven + 1))
        log.info("goal candidate unreachable: collision marks dropped before giving it up")
        return True

    # --- the state machine -----------------------------------------------------------

    def _decide(self, obs: Observation, candidates: list[GoalCandidate]) -> Decision:
        pc = self.config.policy
        picked = self._pick(candidates)
        if picked is None and self._state.steps < pc.look_around_turns:
            return Decision(Action.TURN_LEFT, Mode.LOOK_AROUND,
                            f"initial look-around {self._state.steps + 1}/{pc.look_around_turns}")
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

    def _deadline_due(self, obs: Observation) -> bool:
        """Whether the step budget is running out with a rejected candidate left
        (``policy.last_resort_at_deadline``): the steps left are no more than the way to the best
        one needs (geodesic distance in forward steps, times ``deadline_path_factor``, plus
        ``deadline_margin_steps``). Once due, it stays due: the last resort then comes before
        exploration until no rejected candidate is left to try."""
        pc = self.config.policy
        if not pc.last_resort_at_deadline or pc.step_budget <= 0:
            return False
        lr = self._state.last_resort
        if lr.deadline:
            return True
        left = pc.step_budget - obs.step
        if left > pc.deadline_window_steps:
            return False
        cid = self.memory.best_rejected(exclude=lr.tried)
        if cid is None:
            return False
        cand = self.memory.rejected_cluster(cid, self.grid.xy_to_ij)
        cells = np.zeros(self.grid.shape, bool)
        ok = self.grid.in_bounds(cand.cells_ij)
        cells[cand.cells_ij[ok, 0], cand.cells_ij[ok, 1]] = True
        near = region_within(cells, pc.stop_radius_m + pc.stop_radius_slack_m, self.grid.resolution_m)
        field = self.planner.distance_field(self.grid, obs.pose, extra_targets=near)
        d = float(np.min(field.distance_m, where=field.window(near), initial=np.inf))
        if not math.isfinite(d):
            return False
        need = math.ceil(d / FORWARD_STEP_M * pc.deadline_path_factor) + pc.deadline_margin_steps
        if left > need:
            return False
        log.info("%d steps left, about %d needed to reach rejected candidate %d (%.1f m): the last resort now",
                 left, need, cid, d)
        self._set(last_resort=replace(lr, deadline=True))
        return True

    def _approach(self, obs: Observation, cand: Candidate, trusted: bool = False) -> Decision | None:
        """APPROACH (and VERIFY at the stop point); None when the candidate was rejected.
        ``trusted``: stop at it without verification (the last resort)."""
        pc = self.config.policy
        grid, pose = self.grid, obs.pose
        stop_cells = self._stop_cells(cand)
        hidden = self._hidden_spots_mask(cand)
        region = region_within(stop_cells, pc.stop_radius_m, grid.resolution_m) & ~hidden
        if pc.stop_rule == "core":
            region = self._in_sight(region, stop_cells, cand.id)
        agent_ij = grid.cell_of(pose)
        # A forward step is 0.25 m: when the region is nearer than that and the way there is
        # blocked, this is as close as the robot gets (it still has to face the goal and verify).
        near_enough = (self._state.approach.region_unreachable or blocked_here(self.grid, self._state.motion, pose)) and (
            region_within(stop_cells, pc.stop_radius_m + max(FORWARD_STEP_M, pc.stop_radius_slack_m), grid.resolution_m)
            & ~hidden)[agent_ij]
        if region[agent_ij] or near_enough:
            return self._at_candidate(obs, cand, trusted)
        self._set(verify=None)
        field = self.planner.distance_field(grid, pose, extra_targets=region)
        a = self._state.approach
        try:
            try:
                plan = self.planner.plan(grid, field, pose, region)
                a = replace(a, region_unreachable=False)
            except PlanError:
                # The stop region can be out of reach (a TV on a deep stand, the middle of a
                # bed): head for the reachable cells nearest to the goal instead.
                wider = region_within(stop_cells, pc.stop_radius_m + pc.stop_radius_slack_m, grid.resolution_m) & ~hidden
                if pc.stop_rule == "core" and any(c == cand.id for c, _, _ in self._state.occluders):
                    wider = self._in_sight(wider, stop_cells, cand.id)  # after the view check struck a spot off
                plan = self.planner.plan(grid, field, pose, wider)
                a = replace(a, region_unreachable=True)
        except PlanError as exc:
            a = replace(a, unreachable_steps=a.unreachable_steps + 1)
            self._set(approach=a)
            if a.unreachable_steps >= pc.unreachable_goal_steps:
                if self._give_up_view(cand) or self._forgive_before_reject():
                    return self._approach(obs, cand, trusted)
                self._reject(cand, robot_xy_m=(pose.x_m, pose.y_m), why=f"unreachable for {a.unreachable_steps} steps")
                return None
            # keep looking around: the map may open a way (a new view, a cleared collision)
            return Decision(Action.TURN_LEFT, Mode.APPROACH, "goal not reachable yet", target_kind="goal",
                            candidate=cand, planner_error=f"{exc.reason}: {exc}")
        # No progress towards the candidate for too long (blocked by what the map does not
        # show, or oscillating): give it up rather than spend the budget on it.
        a = a.after_plan(cand.centroid_xy_m, plan.distance_m)
        self._set(approach=a)
        if a.stall_steps > pc.approach_patience_steps:
            if self._give_up_view(cand):
                return self._approach(obs, cand, trusted)
            self._reject(cand, robot_xy_m=(pose.x_m, pose.y_m), why=f"no progress for {a.stall_steps} steps")
            return None
        return Decision(self._safe(plan, pose, field), Mode.APPROACH, "navigating to the goal candidate", plan=plan,
                        target_kind="goal", candidate=cand)

    def _give_up_view(self, cand: Candidate) -> bool:
        """After the view check struck stop spots off ``cand``, no other spot could be reached:
        forget the struck spots and what hid it, and stop where the robot can, as without the
        check (a true goal behind a wall is not rejected for it). False when there is nothing
        to give up (the candidate is then rejected as before)."""
        if cand.id in self._state.view_given_up or not any(c == cand.id for c, _, _ in self._state.hidden_spots):
            return False
        log.info("no stop spot in view of goal candidate %s could be reached: stopping where the robot can", cand.id)
        st = self._state
        self._set(hidden_spots=tuple(sp for sp in st.hidden_spots if sp[0] != cand.id),
                  occluders=tuple(o for o in st.occluders if o[0] != cand.id),
                  view_given_up=st.view_given_up | {cand.id},
                  approach=replace(st.approach, best_distance_m=math.inf, stall_steps=0, unreachable_steps=0))
        return True

    def _hidden_spots_mask(self, cand: Candidate) -> np.ndarray:
        """(H, W) bool: the cells near the stop spots from which ``cand`` was found hidden."""
        return cells_near(self.grid, [(x, y) for c, x, y in self._state.hidden_spots if c == cand.id],
                          self.config.policy.stop_view_spot_radius_m)

    def _occluder_mask(self, cand_id: int) -> np.ndarray:
        """(H, W) bool: cells of what hid candidate ``cand_id`` from a stop spot (grown a little:
        a line of sight slips between the frame's sparse points)."""
        return cells_near(self.grid, [(x, y) for c, x, y in self._state.occluders if c == cand_id],
                          self.config.policy.stop_view_occluder_m)

    def _stop_cells(self, cand: Candidate) -> np.ndarray:
        """(H, W) bool: the cells the stop region is measured from (``agent.stop_region``)."""
        return stop_cells_of(self.grid, cand, self.config.policy)

    def _in_sight(self, region: np.ndarray, target: np.ndarray, cand_id: int | None = None) -> np.ndarray:
        """``agent.stop_region.in_sight``, with what was seen to hide candidate ``cand_id``."""
        occluder = self._occluder_mask(cand_id) if cand_id is not None else None
        return in_sight(self.grid, region, target, occluder)

    def _verify_by_approach(self, obs: Observation, cand: GoalCandidate) -> Decision | None:
        """VERIFY a potential candidate by approach (IEVE's explore-verify-exploit): go to the
        verify ring around it, face it and look; a detection from there confirms it (its state
        turns ``confirmed`` and the agent approaches to stop), ``verify_views`` looks without one
        reject it. The ring's inner radius keeps the candidate's top in the level camera's view
        (a low object vanishes below the image closer than about 1.3-1.9 m)."""
        pc = self.config.policy
        grid, pose = self.grid, obs.pose
        cl = cand.cluster
        robot_xy = (pose.x_m, pose.y_m)
        top_m = float(np.quantile(cl.points_xyz[:, 2], 0.9)) if len(cl.points_xyz) else 0.0
        half_vfov = math.atan2(0.5 * obs.intrinsics.height_px, obs.intrinsics.fy) - obs.camera_tilt_rad
        inner = max(0.0, (obs.camera_height_m - top_m) / math.tan(half_vfov)) + pc.verify_min_margin_m if half_vfov > 0 else 0.0
        outer = max(pc.verify_distance_m, inner + 0.5)
        ring = region_within(grid.layers.goal, outer, grid.resolution_m) & ~region_within(grid.layers.goal, inner, grid.resolution_m)
        agent_ij = grid.cell_of(pose)
        v = self._state.verify
        if v is None or v.candidate_id != cl.id:
            v = VerifyState(candidate_id=cl.id)
        if ring[agent_ij]:
            bearing = math.atan2(cl.centroid_xy_m[1] - pose.y_m, cl.centroid_xy_m[0] - pose.x_m)
            err = wrap_angle(bearing - pose.yaw_rad)
            if abs(err) > math.radians(pc.facing_tolerance_deg):
                self._set(verify=v)
                return Decision(Action.TURN_LEFT if err > 0 else Action.TURN_RIGHT, Mode.VERIFY,
                                "verify: turning to look at the potential candidate", target_kind="goal", candidate=cl)
            look = next((w for w in cand.views if w.step == obs.step), None)
            if (pc.verify_ring_tau_ratio < 1.0 and self.tau is not None and look is not None
                    and look.score >= pc.verify_ring_tau_ratio * self.tau):
                self._set(ring_confirmed=self._state.ring_confirmed | {obs.step}, verify=None)
                decision = self._approach(obs, cl)
                return None if decision is None else replace(
                    decision, reason=f"re-identified from the verify ring (score {look.score:.0f}); {decision.reason}")
            if v.views >= pc.verify_views:
                self._reject(cl, robot_xy_m=robot_xy, why=f"not re-identified in {v.views} looks from the verify ring")
                return None
            self._set(verify=replace(v, views=v.views + 1))
            # a new viewpoint each look: a step nearer while that stays in the ring, else a
            # small turn off and back onto the bearing
            ahead = np.array(robot_xy) + FORWARD_STEP_M * np.array([math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)])
            a_ij = grid.xy_to_ij(ahead[None])[0]
            if grid.in_bounds(a_ij[None])[0] and ring[a_ij[0], a_ij[1]] and not blocked_here(self.grid, self._state.motion, pose):
                field = self.planner.distance_field(grid, pose)
                if self.planner.line_free(grid, field, np.array(robot_xy), ahead):
                    return Decision(Action.MOVE_FORWARD, Mode.VERIFY, f"verify: look {v.views + 1}, stepping nearer",
                                    target_kind="goal", candidate=cl)
            turn = Action.TURN_LEFT if v.views % 2 == 0 else Action.TURN_RIGHT
            return Decision(turn, Mode.VERIFY, f"verify: look {v.views + 1}", target_kind="goal", candidate=cl)
        self._set(verify=v)
        field = self.planner.distance_field(grid, pose, extra_targets=ring)
        a = self._state.approach
        try:
            plan = self.planner.plan(grid, field, pose, ring)
        except PlanError as exc:
            a = replace(a, unreachable_steps=a.unreachable_steps + 1)
            self._set(approach=a)
            if a.unreachable_steps >= pc.unreachable_goal_steps:
                if self._forgive_before_reject():
                    return self._verify_by_approach(obs, cand)
                self._reject(cl, robot_xy_m=robot_xy, why=f"verify ring unreachable for {a.unreachable_steps} steps")
                return None
            return Decision(Action.TURN_LEFT, Mode.VERIFY, "verify ring not reachable yet", target_kind="goal",
                            candidate=cl, planner_error=f"{exc.reason}: {exc}")
        a = a.after_plan(cl.centroid_xy_m, plan.distance_m)
        self._set(approach=a)
        if a.stall_steps > pc.approach_patience_steps:
            self._reject(cl, robot_xy_m=robot_xy, why=f"no progress to the verify ring for {a.stall_steps} steps")
            return None
        return Decision(self._safe(plan, pose, field), Mode.VERIFY, "verify: approaching the potential candidate",
                        plan=plan, target_kind="goal", candidate=cl)

    def _at_candidate(self, obs: Observation, cand: Candidate, trusted: bool = False) -> Decision | None:
        """In the stop region: VERIFY (scan for a confirming re-match), face the goal, STOP."""
        pc = self.config.policy
        pose = obs.pose
        goal_xy = self.grid.ij_to_xy(cand.cells_ij)
        k = int(np.argmin(np.hypot(goal_xy[:, 0] - pose.x_m, goal_xy[:, 1] - pose.y_m)))
        bearing = math.atan2(goal_xy[k, 1] - pose.y_m, goal_xy[k, 0] - pose.x_m)
        confirmed = trusted or self._confirmed(cand)
        verify = self._state.verify
        if verify is not None and not confirmed:
            if verify.scan_index >= len(SCAN_TURNS) or verify.scan_index >= pc.verify_scan_steps:
                self._reject(cand, robot_xy_m=(pose.x_m, pose.y_m), why="no close-range re-identification")
                return None
            self._set(verify=VerifyState(verify.scan_index + 1))
            return Decision(SCAN_TURNS[verify.scan_index], Mode.VERIFY, "scanning for a close-range match",
                            target_kind="goal", candidate=cand)
        err = wrap_angle(bearing - pose.yaw_rad)
        if abs(err) > math.radians(pc.facing_tolerance_deg):
            return Decision(Action.TURN_LEFT if err > 0 else Action.TURN_RIGHT, Mode.APPROACH,
                            "at the goal: turning to face it", target_kind="goal", candidate=cand)
        if confirmed:
            # the view check runs at every stop (its figures go into the reason, so that a run
            # without it shows where it would have acted); it acts only with stop_needs_view
            n_in, n_seen, occluder = core_view(self.grid, cand, obs, pc)
            if occluder is not None and pc.stop_needs_view and cand.id not in self._state.view_given_up:
                spots = tuple(sp for sp in self._state.hidden_spots if sp[0] == cand.id)
                if len(spots) < pc.stop_view_max_spots:
                    cells = np.unique(self.grid.xy_to_ij(occluder), axis=0)
                    found = tuple((cand.id, float(x), float(y)) for x, y in self.grid.ij_to_xy(cells))
                    self._set(hidden_spots=self._state.hidden_spots + ((cand.id, pose.x_m, pose.y_m),),
                              occluders=self._state.occluders + found)
                    log.info("goal candidate %s hidden from %.2f, %.2f: looking for another stop spot",
                             cand.id, pose.x_m, pose.y_m)
                    d = self._approach(obs, cand, trusted)
                    n = len(spots) + 1
                    return d if d is None else replace(d, reason=f"the goal is hidden from here ({n}): {d.reason}")
            why = ("the last resort" if trusted else "re-identified at close range" if pc.verify
                   else "close-range verification off")
            view = f"{n_seen} of {n_in} core points in the frame seen" + (", hidden" if occluder is not None else "")
            return Decision(Action.STOP, Mode.STOPPED, f"within stop radius, facing the goal ({why}; {view})",
                            target_kind="goal", candidate=cand)
        self._set(verify=VerifyState(0))
        return self._at_candidate(obs, cand)

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
        # Nothing left to explore and no goal: a deliberate stop, reported as such.
        return Decision(Action.STOP, Mode.EXHAUSTED, "no reachable frontier and no goal candidate",
                        planner_error=error or "no_frontier")

    def _last_resort(self, obs: Observation) -> Decision | None:
        """LAST_RESORT: nothing is left to explore and no candidate stands, so head for the
        rejected candidate with the best evidence and stop at it without verification (a
        rejected true goal scored just below tau is a better bet than wherever the robot is).
        Each rejected candidate is tried once, best first; None when none is left (EXHAUSTED)."""
        while True:
            lr = self._state.last_resort
            cid = lr.candidate_id
            if cid is None:
                cid = self.memory.best_rejected(exclude=lr.tried)
                if cid is None:
                    return None
                lr = replace(lr, candidate_id=cid, tried=lr.tried | {cid})
                self._set(last_resort=lr)
                log.info("nothing left to explore: trying rejected candidate %d (best score %.1f) as the last resort",
                         cid, self.memory.best_score_of(cid))
            cand = self.memory.rejected_cluster(cid, self.grid.xy_to_ij)
            self.grid.set_goal_cells(cand.cells_ij)
            decision = self._approach(obs, cand, trusted=True)
            if decision is not None:
                mode = Mode.STOPPED if decision.action == Action.STOP else Mode.LAST_RESORT
                score = self.memory.best_score_of(cid)
                return replace(decision, mode=mode,
                               reason=f"last resort (rejected candidate, best score {score:.1f}): {decision.reason}")
            self.grid.clear_goal()
            self._set(last_resort=replace(self._state.last_resort, candidate_id=None))


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3
