"""Going to a goal candidate, verifying it and giving it up: the APPROACH, VERIFY and LAST_RESORT
modes of the Mod-IIN agent's state machine (``agent.policy.ModIINAgent`` mixes this in).

* approach: plan to the stop region around the candidate (``agent.stop_region``: its core cells,
  in sight of them), turn to face it, stop (with the close-range check when ``verify`` is on);
* verify by approach: a potential candidate is looked at from a ring around it, outside the
  distance at which the level camera loses its top; a detection (or, with
  ``verify_ring_tau_ratio`` < 1, a look at that share of tau that adds points to it) confirms
  it, ``verify_views`` looks without one reject it;
* rejection: blacklist its cells on the map (softly when it only ever had potential evidence),
  after dropping the collision marks once when it was unreachable (``unreachable_forgive``);
* the last resort: head for the best rejected candidate when exploration is exhausted, or when
  the step budget is running out (``last_resort_at_deadline``), and stop there.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Callable

import numpy as np

from agent.candidates import CandidateMemory, GoalCandidate
from agent.config import AgentConfig
from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.motion import blocked_here
from agent.modes import SCAN_TURNS, Decision, Mode, PolicyState, VerifyState
from agent.planner import DistanceField, FMMPlanner, Plan, PlanError, region_within
from agent.stop_region import cells_near, core_view, in_sight, stop_cells as stop_cells_of
from agent.types import FORWARD_STEP_M, Action, Observation, Pose2D, wrap_angle

log = logging.getLogger("agent.policy")


class CandidateNavigation:
    """The candidate side of ``ModIINAgent``: what it needs from the agent is declared here."""

    config: AgentConfig
    grid: GridMap
    planner: FMMPlanner
    memory: CandidateMemory
    tau: float | None
    _state: PolicyState
    _candidates_changed: bool
    _set: Callable[..., None]  # replaces fields of the policy state
    _safe: Callable[[Plan, Pose2D, DistanceField], Action]  # the plan's first action, made safe

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
        self._candidates_changed = True
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
