"""The candidate side of the Mod-IIN agent: going to a goal candidate, verifying it, giving it up,
and the last resort (the APPROACH, VERIFY and LAST_RESORT modes of ``agent.modes``).

``CandidateNavigator`` is a component with explicit inputs: each call takes the step's ``Scene``
(the observation, the map and the candidate memory, which a rejection changes) and the policy
state, and returns the ``Decision`` (None when the candidate was given up) and the next state.

* approach: plan to the stop region around the candidate (``agent.stop_region``: its core cells,
  in sight of them), turn to face it, stop;
* verify by approach: a potential candidate is looked at from a ring around it, outside the
  distance at which the level camera loses its top; a detection (or a look at
  ``verify_ring_tau_ratio`` x tau that adds points to it) confirms it, ``verify_views`` looks
  without one reject it (IEVE's explore-verify-exploit, Lei et al. CVPR 2024);
* rejection: blacklist its cells on the map (softly when it only ever had potential evidence),
  after dropping the collision marks once when it was unreachable (``unreachable_forgive``); a
  candidate that scored tau and is still unreachable first waits for a way (``no_way``) while
  the agent explores;
* the last resort: head for the best rejected candidate when exploration is exhausted, or when
  the step budget is running out (``last_resort_at_deadline``), and stop there;
* steering: the plan's first action, made safe by the motion memory (``agent.motion``), with
  the side-step out of turning to and fro.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from agent.candidates import CandidateMemory, GoalCandidate
from agent.config import PolicyConfig
from agent.events import Context, Event, event_facts
from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.modes import Decision, Mode, PolicyState, VerifyState
from agent.motion import blocked_here, move_key, safe_action
from agent.planner import DistanceField, FMMPlanner, Plan, PlanError, region_within
from agent.stop_region import in_sight, seen_side
from agent.stop_region import stop_cells as stop_cells_of
from agent.types import FORWARD_STEP_M, Action, Observation, Pose2D, wrap_angle

log = logging.getLogger("agent.policy")

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Scene:
    """What one step's candidate decisions read and change: the observation, the map (goal cells,
    blacklists, collision marks) and the candidate memory (rejections)."""

    obs: Observation
    grid: GridMap
    memory: CandidateMemory


Outcome = tuple[Decision | None, PolicyState]


class CandidateNavigator:
    """Approach, verify, reject, last resort and steering; holds only its configuration."""

    def __init__(self, config: PolicyConfig, planner: FMMPlanner, tau: float | None) -> None:
        self.config = config
        self.planner = planner
        self.tau = tau

    # --- steering --------------------------------------------------------------------

    def steer(self, scene: Scene, st: PolicyState, plan: Plan, field: DistanceField) -> tuple[Action, PolicyState]:
        """The plan's first action, made safe (``agent.motion.safe_action``); ``motion.side_step``
        says whether it is part of a side-step (under way, or its last step forward from the
        cell it began on)."""
        pose = scene.obs.pose
        before = st.motion.detour
        action, motion = safe_action(
            plan, pose, field, scene.grid, self.planner, st.motion, self.config.detour_after_turns
        )
        side = motion.detour is not None or (
            before is not None and action == Action.MOVE_FORWARD and before[:2] == move_key(scene.grid, pose)[:2]
        )
        return action, replace(st, motion=replace(motion, side_step=side))

    # --- giving a candidate up -----------------------------------------------------------

    def reject(self, scene: Scene, st: PolicyState, cand: Candidate, why: str) -> PolicyState:
        pose = scene.obs.pose
        log.info("rejecting goal candidate at %s (%s)", cand.centroid_xy_m, why)
        scene.memory.reject(cand, (pose.x_m, pose.y_m), scene.grid.ij_to_xy(cand.cells_ij), why)
        # A candidate that never scored tau was only potential: reject its sub-tau evidence, not
        # a later detection there (a rejected true goal would otherwise be lost for good)
        soft = self.tau is not None and cand.max_score < self.tau
        scene.grid.blacklist_cells(
            cand.cells_ij, self.config.reject_radius_m, layer="potential_blacklist" if soft else "blacklist"
        )
        a = st.approach
        return replace(
            st,
            approach=replace(a, best_distance_m=math.inf, stall_steps=0, unreachable_steps=0, collisions_forgiven=0),
            verify=None,
        )

    def _may_wait(self, scene: Scene, st: PolicyState, cand: Candidate) -> bool:
        """A candidate found unreachable waits for a way rather than being rejected when it scored
        tau (a rejection blacklists its cells for good: the goal there is lost), has not waited
        before, and is not a rejected one being tried again (the last resort)."""
        return (
            self.tau is not None
            and cand.max_score >= self.tau
            and cand.id not in st.waited
            and not scene.memory.was_rejected(cand.id)
        )

    def no_way(self, st: PolicyState, cand: Candidate) -> PolicyState:
        """The candidate waits for a way: the agent explores past it and heads for it again as soon
        as the map shows a way there (``ModIINAgent._no_way_yet``); when no frontier is left, it is
        approached once more and rejected if still unreachable. The way the map held may be a
        passage the robot could not get through (a collision mark across it, or a jamb drawn a few
        centimetres off); exploring may find another, or a rescan drops the marks."""
        log.info("goal candidate at %s: no way on the map yet, exploring for one", cand.centroid_xy_m)
        a = st.approach
        return replace(
            st,
            waiting=st.waiting | {cand.id},
            waited=st.waited | {cand.id},
            approach=replace(a, best_distance_m=math.inf, stall_steps=0, unreachable_steps=0),
            verify=None,
        )

    def forgive_before_reject(self, scene: Scene, st: PolicyState) -> tuple[bool, PolicyState]:
        """Before a candidate is given up as unreachable: drop the collision marks (as a rescan
        does; ``unreachable_forgive`` times per candidate) and try again. Each failed move near an
        object leaves a band as wide as the robot, inflated on every side, so a few of them can
        wall in a stop region the robot could reach (train-s1-0012-0: a TV scoring 121). The
        motion memory still refuses the very moves that failed. True when marks were dropped."""
        a = st.approach
        if a.collisions_forgiven >= self.config.unreachable_forgive or not scene.grid.layers.collision.any():
            return False, st
        scene.grid.forgive_collisions()
        log.info("goal candidate unreachable: collision marks dropped before giving it up")
        return True, replace(
            st, approach=replace(a, unreachable_steps=0, collisions_forgiven=a.collisions_forgiven + 1)
        )

    # --- the deadline and the last resort --------------------------------------------------

    def deadline_due(self, scene: Scene, st: PolicyState) -> tuple[bool, PolicyState]:
        """Whether the step budget is running out with a rejected candidate left
        (``last_resort_at_deadline``): the steps left are no more than the way to the best one
        needs (geodesic distance in forward steps, times ``deadline_path_factor``, plus
        ``deadline_margin_steps``). Once due, it stays due: the last resort then comes before
        exploration until no rejected candidate is left to try."""
        pc, grid, obs = self.config, scene.grid, scene.obs
        if not pc.last_resort_at_deadline or pc.step_budget <= 0:
            return False, st
        lr = st.last_resort
        if lr.deadline:
            return True, st
        left = pc.step_budget - obs.step
        if left > pc.deadline_window_steps:
            return False, st
        cid = scene.memory.best_rejected(exclude=lr.tried)
        if cid is None:
            return False, st
        cand = scene.memory.rejected_cluster(cid, grid.xy_to_ij)
        cells = np.zeros(grid.shape, bool)
        ok = grid.in_bounds(cand.cells_ij)
        cells[cand.cells_ij[ok, 0], cand.cells_ij[ok, 1]] = True
        near = region_within(cells, pc.stop_radius_m + pc.stop_radius_slack_m, grid.resolution_m)
        field = self.planner.distance_field(grid, obs.pose, extra_targets=near)
        d = float(np.min(field.distance_m, where=field.window(near), initial=np.inf))
        if not math.isfinite(d):
            return False, st
        need = math.ceil(d / FORWARD_STEP_M * pc.deadline_path_factor) + pc.deadline_margin_steps
        if left > need:
            return False, st
        log.info(
            "%d steps left, about %d needed to reach rejected candidate %d (%.1f m): the last resort now",
            left,
            need,
            cid,
            d,
        )
        return True, replace(st, last_resort=replace(lr, deadline=True))

    def last_resort(self, scene: Scene, st: PolicyState) -> Outcome:
        """LAST_RESORT: nothing is left to explore (or the budget is running out) and no candidate
        stands, so head for the rejected candidate with the best evidence and stop at it without
        verification (a rejected true goal scored just below tau is a better bet than wherever
        the robot is). Each rejected candidate is tried once, best first; None when none is left."""
        memory, grid = scene.memory, scene.grid
        while True:
            lr = st.last_resort
            cid = lr.candidate_id
            if cid is None:
                cid = memory.best_rejected(exclude=lr.tried)
                if cid is None:
                    return None, st
                st = replace(st, last_resort=replace(lr, candidate_id=cid, tried=lr.tried | {cid}))
                log.info(
                    "nothing left to explore: trying rejected candidate %d (best score %.1f) as the last resort",
                    cid,
                    memory.best_score_of(cid),
                )
            cand = memory.rejected_cluster(cid, grid.xy_to_ij)
            grid.set_goal_cells(cand.cells_ij)
            decision, st = self.approach(scene, st, cand)
            if decision is not None:
                mode = Mode.STOPPED if decision.action == Action.STOP else Mode.LAST_RESORT
                return replace(decision, mode=mode).within(Context.LAST_RESORT, score=memory.best_score_of(cid)), st
            grid.clear_goal()
            st = replace(st, last_resort=replace(st.last_resort, candidate_id=None))

    # --- approach ----------------------------------------------------------------------

    def _stop_region(
        self, grid: GridMap, cand: Candidate
    ) -> tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """The candidate's stop cells, its stop region (within the stop radius of them; with the
        core rule, in sight of them and on a side it was seen from) and that side's filter."""
        pc = self.config
        stop_cells = stop_cells_of(grid, cand, pc)

        def side(cells: np.ndarray) -> np.ndarray:  # stop only on a side it was seen from
            return seen_side(grid, cells, stop_cells, np.asarray(cand.seen_from_xy_m))

        region = region_within(stop_cells, pc.stop_radius_m, grid.resolution_m)
        if pc.stop_rule == "core":
            region = side(in_sight(grid, region, stop_cells))
        return stop_cells, region, side

    def _plan_to_stop(
        self, grid: GridMap, pose: Pose2D, stop_cells: np.ndarray, region: np.ndarray,
        side: Callable[[np.ndarray], np.ndarray],
    ) -> tuple[Plan, bool, DistanceField]:  # fmt: skip
        """A plan to the stop region, else (the region can be out of reach: a TV on a deep stand,
        the middle of a bed) to the reachable cells within the slack of it, nearest to the goal;
        with whether it is the latter, and the field. Raises PlanError when neither has a plan."""
        pc = self.config
        field = self.planner.distance_field(grid, pose, extra_targets=region)
        try:
            return self.planner.plan(grid, field, pose, region), False, field
        except PlanError:
            wider = side(region_within(stop_cells, pc.stop_radius_m + pc.stop_radius_slack_m, grid.resolution_m))
            return self.planner.plan(grid, field, pose, wider), True, field

    def has_way(self, scene: Scene, cand: Candidate) -> bool:
        """Whether the map shows a way to the candidate's stop region (or, as ``approach`` falls
        back to, the cells within the slack of it) from where the robot stands."""
        grid, pose = scene.grid, scene.obs.pose
        stop_cells, region, side = self._stop_region(grid, cand)
        if region[grid.cell_of(pose)]:
            return True
        try:
            self._plan_to_stop(grid, pose, stop_cells, region, side)
        except PlanError:
            return False
        return True

    def approach(self, scene: Scene, st: PolicyState, cand: Candidate) -> Outcome:
        """APPROACH the candidate's stop region, face it and stop; None when it was given up."""
        pc, grid, pose = self.config, scene.grid, scene.obs.pose
        stop_cells, region, side = self._stop_region(grid, cand)
        agent_ij = grid.cell_of(pose)
        # A forward step is 0.25 m: when the region is nearer than that and the way there is
        # blocked, this is as close as the robot gets (it still has to face the goal).
        near_enough = (st.approach.region_unreachable or blocked_here(grid, st.motion, pose)) and side(
            region_within(stop_cells, pc.stop_radius_m + max(FORWARD_STEP_M, pc.stop_radius_slack_m), grid.resolution_m)
        )[agent_ij]
        if region[agent_ij] or near_enough:
            return self._at_candidate(scene, cand), st
        st = replace(st, verify=None)

        def plan_stop() -> tuple[Plan, bool, DistanceField]:
            return self._plan_to_stop(grid, pose, stop_cells, region, side)

        try:
            found = plan_stop()
        except PlanError as exc:
            return self._no_plan(
                scene, st, cand, exc, "unreachable", lambda s: self.approach(scene, s, cand),
                Mode.APPROACH, Event.GOAL_NOT_REACHABLE_YET,
            )  # fmt: skip
        (plan, region_unreachable, field), st, note = self._past_marks(
            scene, st, cand.centroid_xy_m, found, plan_stop, lambda f: f[0].distance_m
        )
        # No progress towards the candidate for too long (blocked by what the map does not
        # show, or oscillating): give it up rather than spend the budget on it.
        a = replace(st.approach, region_unreachable=region_unreachable).after_plan(cand.centroid_xy_m, plan.distance_m)
        st = replace(st, approach=a)
        if a.stall_steps > pc.approach_patience_steps:
            return None, self.reject(scene, st, cand, f"no progress for {a.stall_steps} steps")
        action, st = self.steer(scene, st, plan, field)
        decision = Decision(action, Mode.APPROACH, Event.APPROACH, plan=plan, target_kind="goal", candidate=cand)
        return (decision if note is None else decision.within(Context.MARKS_DROPPED, **note)), st

    def _past_marks(
        self, scene: Scene, st: PolicyState, target_xy_m: tuple[float, float], found: T,
        replan: Callable[[], T], length_m: Callable[[T], float],
    ) -> tuple[T, PolicyState, dict[str, float] | None]:  # fmt: skip
        """The way ``found`` to the candidate at ``target_xy_m``, or a way without the collision
        marks when they made it a detour: it is more than ``detour_forgive_m`` longer than the
        shortest way the robot had to this candidate, and dropping the marks (``unreachable_forgive``
        times per candidate, counted with the drops before a rejection) gives back one at least
        that much shorter. A failed move in a doorway leaves a band across it (under slip a graze
        of the jamb is enough) and the plan then goes round the home (val-s0-0085-0 under
        ``stretch``: 1.8 m became 7.2 m, and 100 steps later the candidate, scored 233, was given
        up). Otherwise the marks are kept as they were. With the state and, when the marks were
        dropped, the numbers for ``Context.MARKS_DROPPED``."""
        pc, grid, a = self.config, scene.grid, st.approach
        was = length_m(found)
        if (
            pc.detour_forgive_m <= 0.0
            or a.collisions_forgiven >= pc.unreachable_forgive
            or a.target_xy_m is None
            or math.dist(a.target_xy_m, target_xy_m) > 0.5  # another candidate: its own count
            or was <= a.best_distance_m + pc.detour_forgive_m
            or not grid.layers.collision.any()
        ):
            return found, st, None
        marks = grid.layers.collision.copy()
        grid.forgive_collisions()
        try:
            shorter: T | None = replan()
        except PlanError:
            shorter = None
        if shorter is None or length_m(shorter) > was - pc.detour_forgive_m:
            grid.layers.collision |= marks
            return found, st, None
        now = length_m(shorter)
        log.info("collision marks dropped: the way to the candidate was %.1f m with them, %.1f m without", was, now)
        st = replace(st, approach=replace(a, collisions_forgiven=a.collisions_forgiven + 1))
        return shorter, st, {"was_m": round(was, 2), "now_m": round(now, 2)}

    def _no_plan(
        self, scene: Scene, st: PolicyState, cand: Candidate, exc: PlanError, why: str,
        retry: Callable[[PolicyState], Outcome], mode: Mode, event: Event,
    ) -> Outcome:  # fmt: skip
        """No plan to the candidate (or its verify ring) this step: after ``unreachable_goal_steps``
        in a row, drop the collision marks once and ``retry``, else reject it ("<why> for N steps");
        before that, keep turning: the map may open a way (a new view, a cleared collision)."""
        a = replace(st.approach, unreachable_steps=st.approach.unreachable_steps + 1)
        st = replace(st, approach=a)
        if a.unreachable_steps >= self.config.unreachable_goal_steps:
            forgiven, st = self.forgive_before_reject(scene, st)
            if forgiven:
                return retry(st)
            if mode == Mode.APPROACH and self._may_wait(scene, st, cand):
                return None, self.no_way(st, cand)
            return None, self.reject(scene, st, cand, f"{why} for {a.unreachable_steps} steps")
        planner_error = f"{exc.reason}: {exc}"
        return Decision(
            Action.TURN_LEFT, mode, event, target_kind="goal", candidate=cand, planner_error=planner_error
        ), st

    def _turn_to_face(self, pose: Pose2D, xy_m: tuple[float, float]) -> Action | None:
        """The turn towards ``xy_m`` (run frame), or None when it is within the facing tolerance."""
        err = wrap_angle(math.atan2(xy_m[1] - pose.y_m, xy_m[0] - pose.x_m) - pose.yaw_rad)
        if abs(err) <= math.radians(self.config.facing_tolerance_deg):
            return None
        return Action.TURN_LEFT if err > 0 else Action.TURN_RIGHT

    def _at_candidate(self, scene: Scene, cand: Candidate) -> Decision:
        """In the stop region: face the goal's nearest cell, then STOP."""
        pose = scene.obs.pose
        goal_xy = scene.grid.ij_to_xy(cand.cells_ij)
        k = int(np.argmin(np.hypot(goal_xy[:, 0] - pose.x_m, goal_xy[:, 1] - pose.y_m)))
        turn = self._turn_to_face(pose, (goal_xy[k, 0], goal_xy[k, 1]))
        if turn is not None:
            return Decision(turn, Mode.APPROACH, Event.FACE_GOAL, target_kind="goal", candidate=cand)
        return Decision(Action.STOP, Mode.STOPPED, Event.STOP_AT_GOAL, target_kind="goal", candidate=cand)

    # --- verify by approach ---------------------------------------------------------------

    def verify_by_approach(self, scene: Scene, st: PolicyState, cand: GoalCandidate) -> Outcome:
        """VERIFY a potential candidate by approach: go to the verify ring around it, face it and
        look; a detection from there confirms it (its state turns ``confirmed`` and the agent
        approaches to stop), ``verify_views`` looks without one reject it. The ring's inner
        radius keeps the candidate's top in the level camera's view (a low object vanishes below
        the image closer than about 1.3-1.9 m)."""
        pc, grid, obs = self.config, scene.grid, scene.obs
        pose = obs.pose
        cl = cand.cluster
        top_m = float(np.quantile(cl.points_xyz[:, 2], 0.9)) if len(cl.points_xyz) else 0.0
        half_vfov = math.atan2(0.5 * obs.intrinsics.height_px, obs.intrinsics.fy) - obs.camera_tilt_rad
        inner = (
            max(0.0, (obs.camera_height_m - top_m) / math.tan(half_vfov)) + pc.verify_min_margin_m
            if half_vfov > 0
            else 0.0
        )
        outer = max(pc.verify_distance_m, inner + 0.5)
        ring = region_within(grid.layers.goal, outer, grid.resolution_m) & ~region_within(
            grid.layers.goal, inner, grid.resolution_m
        )
        ring = seen_side(grid, ring, grid.layers.goal, np.asarray(cl.seen_from_xy_m))
        agent_ij = grid.cell_of(pose)
        v = st.verify
        if v is None or v.candidate_id != cl.id:
            v = VerifyState(candidate_id=cl.id)
        if ring[agent_ij]:
            return self._look_from_ring(scene, st, cand, ring, v)
        st = replace(st, verify=v)

        def plan_ring() -> tuple[Plan, DistanceField]:
            field = self.planner.distance_field(grid, pose, extra_targets=ring)
            return self.planner.plan(grid, field, pose, ring), field

        try:
            found = plan_ring()
        except PlanError as exc:
            return self._no_plan(
                scene, st, cl, exc, "verify ring unreachable", lambda s: self.verify_by_approach(scene, s, cand),
                Mode.VERIFY, Event.VERIFY_RING_NOT_REACHABLE_YET,
            )  # fmt: skip
        (plan, field), st, note = self._past_marks(
            scene, st, cl.centroid_xy_m, found, plan_ring, lambda f: f[0].distance_m
        )
        a = st.approach.after_plan(cl.centroid_xy_m, plan.distance_m)
        st = replace(st, approach=a)
        if a.stall_steps > pc.approach_patience_steps:
            return None, self.reject(scene, st, cl, f"no progress to the verify ring for {a.stall_steps} steps")
        action, st = self.steer(scene, st, plan, field)
        decision = Decision(action, Mode.VERIFY, Event.VERIFY_APPROACH, plan=plan, target_kind="goal", candidate=cl)
        return (decision if note is None else decision.within(Context.MARKS_DROPPED, **note)), st

    def _look_from_ring(
        self, scene: Scene, st: PolicyState, cand: GoalCandidate, ring: np.ndarray, v: VerifyState
    ) -> Outcome:
        """On the verify ring: face the candidate, then look (a new viewpoint each look)."""
        pc, grid, obs = self.config, scene.grid, scene.obs
        pose = obs.pose
        cl = cand.cluster
        turn = self._turn_to_face(pose, cl.centroid_xy_m)
        if turn is not None:
            return Decision(turn, Mode.VERIFY, Event.VERIFY_FACE, target_kind="goal", candidate=cl), replace(
                st, verify=v
            )
        look = next((w for w in cand.views if w.step == obs.step), None)
        if (
            pc.verify_ring_tau_ratio < 1.0
            and self.tau is not None
            and look is not None
            and look.score >= pc.verify_ring_tau_ratio * self.tau
        ):
            st = replace(st, ring_confirmed=st.ring_confirmed | {obs.step}, verify=None)
            decision, st = self.approach(scene, st, cl)
            return (None if decision is None else decision.within(Context.RING_CONFIRMED, score=look.score)), st
        if v.views >= pc.verify_views:
            return None, self.reject(scene, st, cl, f"not re-identified in {v.views} looks from the verify ring")
        st = replace(st, verify=replace(v, views=v.views + 1))
        look_no = event_facts(look=v.views + 1)
        # a new viewpoint each look: a step nearer while that stays in the ring, else a small
        # turn off and back onto the bearing
        here = np.array([pose.x_m, pose.y_m])
        ahead = here + FORWARD_STEP_M * np.array([math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)])
        a_ij = grid.xy_to_ij(ahead[None])[0]
        if grid.in_bounds(a_ij[None])[0] and ring[a_ij[0], a_ij[1]] and not blocked_here(grid, st.motion, pose):
            field = self.planner.distance_field(grid, pose)
            if self.planner.line_free(grid, field, here, ahead):
                return Decision(
                    Action.MOVE_FORWARD,
                    Mode.VERIFY,
                    Event.VERIFY_STEP_NEARER,
                    look_no,
                    target_kind="goal",
                    candidate=cl,
                ), st
        turn = Action.TURN_LEFT if v.views % 2 == 0 else Action.TURN_RIGHT
        return Decision(turn, Mode.VERIFY, Event.VERIFY_LOOK, look_no, target_kind="goal", candidate=cl), st
