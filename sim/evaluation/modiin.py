"""``imgnav eval --agent modiin``: the Mod-IIN agent and its Table 2 ablations (Krantz et al. 2023).

    imgnav eval --episodes data/episodes/val --agent modiin --modiin-reid conf --modiin-loc mask \\
        --limit 100 --workers 2 --out runs/modiin-val

Variants (rows of the paper's Table 2 that exist here):

* ``--modiin-reid``: ``conf`` (Keypoint-Conf), ``count`` (Keypoint-Match), ``oracle`` (the goal
  is detected when at least ``--modiin-oracle-min-px`` of its pixels are in view).
* ``--modiin-loc``: ``mask`` (matched keypoints inside a GrabCut mask of the goal image; the
  paper used a detector's mask), ``crop`` (the central crop, "Crop-Projected"), ``oracle``
  (the ground-truth egocentric instance mask is projected), ``goalmask-oracle`` (keypoints
  inside the ground-truth goal-image mask; measures the segmentation alone).

Every failed episode is attributed to one of the paper's failure classes from the agent's
records and the simulator's ground truth (see ``Attribution``); the distribution goes into
summary.json (``failure_causes``), with the paper-layout Markdown row (``table_md``).
``python -m sim.evaluation.modiin OUT1 OUT2 ...`` prints the table of several runs.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections import Counter
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.config import AgentConfig, agent_config_from_dict, load_agent_config
from agent.configio import to_dict
from agent.events import Context
from agent.types import Action, AgentRecord, Observation, wrap_angle
from sim.evaluation.modiin_summary import comparison_tables, summarize
from sim.evaluation.registry import AgentSpec, register

if TYPE_CHECKING:
    from agent.segmentation import MaskSource

log = logging.getLogger(__name__)

# A goal never seen is put on the map's phantom obstacles when the final map holds at least this
# many obstacle cells in truly open floor (0.25 m^2 at 5 cm cells: enough to close a doorway or a
# corridor once the planner dilates obstacles by the robot's radius; the exact simulator leaves 0).
GHOST_CAUSE_CELLS = 100
# A goal found whose localisation or approach failed is put on the pose when the believed position
# was at some step this far from the true one (half the success radius).
DRIFT_CAUSE_M = 0.5
_MATCHERS: dict[tuple, Any] = {}  # per process: weights load once, not per episode
_AGENTS_BY_ORACLE: dict[int, Any] = {}


def add_arguments(group: Any) -> None:
    group.add_argument("--modiin-config", default="sim", help="agent deployment (sim, stretch) or YAML path")
    group.add_argument("--modiin-reid", choices=["conf", "count", "oracle"], default="conf")
    group.add_argument("--modiin-loc", choices=["mask", "crop", "oracle", "goalmask-oracle"], default="mask")
    group.add_argument("--modiin-matcher", choices=["xfeat_lighterglue", "aliked_lightglue", "sift"], default=None)
    group.add_argument("--modiin-tau", type=float, default=None, help="override the calibrated threshold")
    group.add_argument(
        "--modiin-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="config override, e.g. policy.last_resort=false (YAML value); repeatable (one KEY=VALUE each)",
    )
    group.add_argument(
        "--modiin-oracle-min-px", type=int, default=400, help="goal pixels in view for the oracle re-ID to fire"
    )
    group.add_argument(
        "--modiin-seen-px",
        type=int,
        default=2300,
        help="goal pixels in view (1%% of the frame) for failure attribution to call it 'seen'",
    )
    group.add_argument(
        "--modiin-threads", type=int, default=None, help="torch threads per worker (default 2 // workers)"
    )


def variant_name(args: argparse.Namespace) -> str:
    name = f"reid={args.modiin_reid}, loc={args.modiin_loc}"
    if args.modiin_matcher:
        name += f", matcher={args.modiin_matcher}"
    if args.modiin_set:
        name += ", " + ", ".join(args.modiin_set)
    return name


def build_config(args: argparse.Namespace) -> AgentConfig:
    import yaml

    data = to_dict(load_agent_config(args.modiin_config))
    for item in args.modiin_set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--modiin-set {item!r}: expected KEY=VALUE")
        *path, leaf = key.strip().split(".")
        node = data
        for p in path:
            if p not in node or not isinstance(node[p], dict):
                raise ValueError(f"--modiin-set {item!r}: no config section {p!r}")
            node = node[p]
        node[leaf] = yaml.safe_load(value)
    cfg = agent_config_from_dict(data)
    reid, pol, seg = cfg.reid, cfg.policy, cfg.segmentation
    if args.modiin_matcher:
        reid = replace(reid, matcher=args.modiin_matcher)
    if args.modiin_reid in ("conf", "count"):
        reid = replace(reid, score=args.modiin_reid)
        pol = replace(pol, reid_source="matcher")
    else:
        pol = replace(pol, reid_source="oracle")
    if args.modiin_tau is not None:
        reid = replace(reid, tau=args.modiin_tau)
    if args.modiin_loc == "oracle":
        pol = replace(pol, localisation_source="oracle")
    else:
        pol = replace(pol, localisation_source="goal_mask")
        sources: dict[str, MaskSource] = {"mask": "grabcut", "crop": "crop", "goalmask-oracle": "oracle"}
        seg = replace(seg, source=sources[args.modiin_loc])
    threads = getattr(args, "modiin_threads", None) or max(1, 2 // max(1, getattr(args, "workers", 1) or 1))
    reid = replace(reid, num_threads=threads)
    return replace(cfg, reid=reid, policy=pol, segmentation=seg)


def worker_init(args: argparse.Namespace) -> None:
    """One evaluation worker: torch and OpenCV get the worker's share of the cores (2 workers x
    1 thread on 2 cores), never the default of one thread per core in each worker."""
    import cv2
    import torch

    threads = build_config(args).reid.num_threads
    torch.set_num_threads(threads)
    cv2.setNumThreads(threads)


def make_agent(args: argparse.Namespace, oracle: Any):
    from agent.policy import ModIINAgent
    from agent.reid.identifier import make_matcher, matcher_key

    cfg = build_config(args)
    needs_matcher = cfg.policy.reid_source == "matcher" or cfg.policy.localisation_source == "goal_mask"
    matcher = None
    if needs_matcher:
        key = matcher_key(cfg.reid)
        if key not in _MATCHERS:
            _MATCHERS[key] = make_matcher(cfg.reid)
        matcher = _MATCHERS[key]
    min_px = args.modiin_oracle_min_px
    agent = ModIINAgent(
        cfg,
        matcher=matcher,
        oracle_reid=(lambda obs: int(oracle.goal_mask().sum()) >= min_px)
        if cfg.policy.reid_source == "oracle"
        else None,
        oracle_ego_mask=(lambda obs: oracle.goal_mask()) if cfg.policy.localisation_source == "oracle" else None,
        goal_mask_fn=_PendingGoalMask() if cfg.segmentation.source == "oracle" else None,
    )
    _AGENTS_BY_ORACLE.clear()
    _AGENTS_BY_ORACLE[id(oracle)] = agent
    return agent


def make_memory(args: argparse.Namespace) -> Any:
    """A memory of one home for the agents of a sequence's goals (``imgnav eval --memory``),
    bounded by the agent config's ``memory`` section."""
    from agent.memory import HomeMemory

    return HomeMemory(build_config(args).memory)


class _PendingGoalMask:
    """The ground-truth goal-image mask, filled in by the episode's observer (which knows the
    episode's goal camera) before ``agent.reset`` calls it."""

    def __init__(self) -> None:
        self.mask: np.ndarray | None = None

    def __call__(self, goal_image: np.ndarray) -> np.ndarray:
        if self.mask is None:
            raise RuntimeError("goal-image oracle mask not prepared for this episode")
        return self.mask


def goal_image_mask(oracle: Any, episode: Any) -> np.ndarray:
    """Re-render the episode's goal camera and keep the goal instance's pixels."""
    from sim.camera import GOAL_IMAGE_PX, CameraSpec

    cam = episode.info["goal_camera"]
    eye = cam["eye_xyz_m"]
    spec = CameraSpec(GOAL_IMAGE_PX, GOAL_IMAGE_PX, cam["hfov_deg"], eye[2], cam["pitch_rad"])
    render = oracle.world.render_view(eye, cam["yaw_rad"], cam["pitch_rad"], spec)
    return render.instance_ids == episode.goal_instance_id


# --- failure attribution ------------------------------------------------------------------


GHOST_CLEARANCE_M = 0.15


def _open_floor(grid: Any) -> np.ndarray:
    """(H, W) bool: cells of a true navigable grid at least ``GHOST_CLEARANCE_M`` inside the
    region the robot's centre can reach (so well clear of every real obstacle), cached per grid."""
    cached = _OPEN_FLOOR.get(id(grid))
    if cached is not None and cached[0] is grid:
        return cached[1]
    import cv2

    nav = np.asarray(grid.navigable, np.uint8)
    dist = cv2.distanceTransform(nav, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * grid.resolution_m
    clear = dist >= GHOST_CLEARANCE_M
    _OPEN_FLOOR.clear()
    _OPEN_FLOOR[id(grid)] = (grid, clear)
    return clear


_OPEN_FLOOR: dict[int, tuple[Any, np.ndarray]] = {}


def failure_cause(
    success: bool,
    *,
    candidate_to_goal_m: float | None,
    candidate_on_goal_steps: int,
    detections_goal_in_view: int,
    detections_goal_out_of_view: int,
    goal_seen_steps: int,
    ghost_obstacle_cells: int | None,
    max_pose_error_m: float,
) -> str | None:
    """The failure class of an episode from its summary (the rules: ``Attribution``); the
    arguments are the record's ``modiin`` fields of the same names, so stored records can be
    attributed again (``attribute_record``)."""
    if success:
        return None

    def not_found() -> str:
        if goal_seen_steps > 0:
            return "reid_false_negative"
        ghosts = ghost_obstacle_cells
        return "mapping_ghosts" if ghosts is not None and ghosts >= GHOST_CAUSE_CELLS else "exploration"

    def drift_or(cause: str) -> str:
        if max_pose_error_m >= DRIFT_CAUSE_M:
            return "pose_drift"
        # found and localised but not reached through a map full of phantom obstacles
        ghosts = ghost_obstacle_cells
        if cause == "local_navigation" and ghosts is not None and ghosts >= GHOST_CAUSE_CELLS:
            return "mapping_ghosts"
        return cause

    d = candidate_to_goal_m
    if d is not None and d > 1.0:
        if detections_goal_out_of_view > 0:
            return "reid_false_positive"
        if detections_goal_in_view > 0:
            return drift_or("localisation")
        # a candidate that no detection made (potential evidence, the last resort's choice): the
        # goal itself was never recognised
        return not_found()
    if d is not None or candidate_on_goal_steps > 0:
        return drift_or("local_navigation")
    if detections_goal_in_view > 0:
        return drift_or("localisation")
    return not_found()


def attribute_record(record: Mapping[str, Any]) -> str | None:
    """``failure_cause`` of a stored ``imgnav eval`` record (records made before the noise
    causes existed lack the phantom-cell count and the pose error: then neither is named)."""
    m = record["modiin"]
    return failure_cause(
        bool(record.get("success")),
        candidate_to_goal_m=m["candidate_to_goal_m"],
        candidate_on_goal_steps=m["candidate_on_goal_steps"],
        detections_goal_in_view=m["detections_goal_in_view"],
        detections_goal_out_of_view=m["detections_goal_out_of_view"],
        goal_seen_steps=m["goal_seen_steps"],
        ghost_obstacle_cells=m.get("ghost_obstacle_cells"),
        max_pose_error_m=m.get("pose_error_m", {}).get("max", 0.0),
    )


class Attribution:
    """Per-episode observer: collects per-step ground truth beside the agent's records and
    attributes a failure to one class (checked in this order):

    * the final goal candidate lies off the goal instance (its points' median > 1 m from the
      object's footprint): ``reid_false_positive`` when some detection fired with the goal
      out of view (< 100 goal pixels), ``localisation`` when detections with the goal in view
      projected elsewhere, else (no detection made it: potential evidence or the last resort's
      choice) the goal was never recognised, below;
    * the final candidate lies on the goal: ``local_navigation`` (found and localised, but
      the stop missed the success region or the budget ran out);
    * no final candidate, but a candidate on the goal existed earlier: ``local_navigation``
      (found and localised, then given up as unreachable or for lack of progress);
    * no final candidate, detections with the goal in view, yet no candidate on it ever:
      ``localisation`` (the goal was recognised but its points never landed on it);
    * the goal never recognised: ``reid_false_negative`` when it was in view (>= ``seen_px``),
      else ``mapping_ghosts`` when the final map holds >= ``GHOST_CAUSE_CELLS`` phantom
      obstacle cells (depth noise closed the way), else ``exploration``;
    * a ``localisation`` or ``local_navigation`` failure becomes ``pose_drift`` when the
      believed position was ever ``DRIFT_CAUSE_M`` off the true one, and a ``local_navigation``
      failure ``mapping_ghosts`` when the map holds >= ``GHOST_CAUSE_CELLS`` phantom cells.

    The agent's poses, goal points, candidates and map are put in the world through the oracle's
    ``frame_world``, the world pose of the frame they are in: the run's start, or, for a later
    goal of a sequence run with a memory of the home (``--memory``), the frame of the sequence's
    first start as this run's pose estimate places it (``sim.backend.SimOracle.frame_world``).
    The remembered part of the map is judged where the agent now believes it to be.
    """

    def __init__(self, args: argparse.Namespace, episode: Any, oracle: Any) -> None:
        self.oracle = oracle
        self.seen_px = args.modiin_seen_px
        self.variant = variant_name(args)
        # the resolved agent config (the variant's flags are relative to the deployment YAML,
        # which changes between commits): records stay interpretable on their own
        self.agent_config = to_dict(build_config(args))
        agent = _AGENTS_BY_ORACLE.get(id(oracle))
        if agent is not None and isinstance(
            getattr(agent, "segmenter", None) and agent.segmenter.oracle, _PendingGoalMask
        ):
            agent.segmenter.oracle.mask = goal_image_mask(oracle, episode)
        obj = oracle.world.home.instance(episode.goal_instance_id)
        self.goal_bounds_world = obj.bounds_xy_m()
        self.steps = 0
        self.seen_steps = 0
        self.first_seen: int | None = None
        self.det_seen = 0  # detections with the goal in view
        self.det_unseen = 0  # detections with the goal out of view
        self.first_detection: int | None = None
        self.planner_errors = 0
        self.candidate_on_goal_steps = 0  # steps whose current candidate lay on the goal
        self.modes: Counter[str] = Counter()
        self.events: Counter[str] = Counter()  # steps per event (agent.events.Event values)
        self.contexts: Counter[str] = Counter()  # steps per context (agent.events.Context values)
        self.last: AgentRecord | None = None
        self.timings: dict[str, list[float]] = {}
        self.trace_score: list[float | None] = []  # per step: re-ID score and goal pixels in view,
        self.trace_goal_px: list[int] = []  # kept for threshold analysis on train episodes
        self.trace_gate: list[float | None] = []  # the re-ID gate's cheap score (None: not computed)
        self.trace_exit: list[float | None] = []  # the gate's exit-stage score (None: not computed)
        self.trace_goal_dist: list[float] = []  # robot centre to the goal's footprint, metres (distance-aware evidence)
        self.full_matcher_steps = 0  # steps on which the full matcher ran
        self.gated_goal_in_view = 0  # steps with the goal in view on which the gate skipped the full matcher
        self.second_look_step: int | None = None  # the step that took the second look when exhausted
        self.pose_error_m: list[float] = []  # believed against true position, per step (realism's pose noise)
        self.yaw_error_deg: list[float] = []  # ... and heading
        self.aligned_steps = 0  # steps whose frame the agent fused at a pose it corrected (agent.alignment)

    def on_step(self, obs: Observation, action: Action, record: AgentRecord | None) -> None:
        self.steps += 1
        # the agent's belief: its record's pose (aligned to its map, agent.alignment), else the estimate
        pose = record.pose if record is not None else obs.pose
        self.aligned_steps += record is not None and record.pose != obs.pose
        believed = self.oracle.frame_world.compose(pose)
        true = self.oracle.pose_world
        self.pose_error_m.append(math.hypot(believed.x_m - true.x_m, believed.y_m - true.y_m))
        self.yaw_error_deg.append(abs(math.degrees(wrap_angle(believed.yaw_rad - true.yaw_rad))))
        px = int(self.oracle.goal_mask().sum())
        seen = px >= self.seen_px
        if seen:
            self.seen_steps += 1
            self.first_seen = obs.step if self.first_seen is None else self.first_seen
        if record is None:
            return
        self.trace_score.append(None if record.reid_score is None else round(float(record.reid_score), 2))
        self.trace_goal_px.append(px)
        self.trace_gate.append(None if record.reid_gate_score is None else round(float(record.reid_gate_score), 1))
        self.trace_exit.append(None if record.reid_exit_score is None else round(float(record.reid_exit_score), 2))
        self.trace_goal_dist.append(round(self._robot_to_goal_m(), 2))
        self.full_matcher_steps += bool(record.reid_full_matcher)
        self.gated_goal_in_view += bool(seen and record.reid_full_matcher is False)
        self.last = record
        self.modes[record.mode] += 1
        if record.event:
            self.events[record.event] += 1
        self.contexts.update(record.context)
        if self.second_look_step is None and Context.SECOND_LOOK.value in record.context:
            self.second_look_step = obs.step
        if record.planner_error:
            self.planner_errors += 1
        if record.goal_detected:
            self.first_detection = obs.step if self.first_detection is None else self.first_detection
            # "out of view": (almost) no goal pixels at all, so a detection cannot be the goal
            if px < min(100, self.seen_px):
                self.det_unseen += 1
            else:
                self.det_seen += 1
        d = self._candidate_distance_m(record)
        if d is not None and d <= 1.0:
            self.candidate_on_goal_steps += 1
        for k, v in record.timings_ms.items():
            self.timings.setdefault(k, []).append(float(v))

    def _robot_to_goal_m(self) -> float:
        """Euclidean distance from the robot's centre to the goal's footprint (0 inside it)."""
        p = self.oracle.pose_world
        x0, y0, x1, y1 = self.goal_bounds_world
        return math.hypot(max(x0 - p.x_m, 0.0, p.x_m - x1), max(y0 - p.y_m, 0.0, p.y_m - y1))

    def _candidate_distance_m(self, record: AgentRecord | None = None) -> float | None:
        """Median distance of a record's candidate points (default: the last record's) to the
        goal's footprint (None: no candidate)."""
        record = self.last if record is None else record
        if record is None or len(record.goal_points_xyz) == 0:
            return None
        pts = self.oracle.frame_world.transform_xy(record.goal_points_xyz[:, :2])
        x0, y0, x1, y1 = self.goal_bounds_world
        dx = np.maximum(np.maximum(x0 - pts[:, 0], pts[:, 0] - x1), 0.0)
        dy = np.maximum(np.maximum(y0 - pts[:, 1], pts[:, 1] - y1), 0.0)
        return float(np.median(np.hypot(dx, dy)))

    def _candidates(self) -> list[dict[str, Any]]:
        """The agent's goal candidates at the end (``AgentRecord.candidates``), each with the
        distance from its centroid to the goal's footprint (on the goal: <= 1 m)."""
        if self.last is None:
            return []
        out = []
        x0, y0, x1, y1 = self.goal_bounds_world
        for c in getattr(self.last, "candidates", ()):
            x, y = self.oracle.frame_world.transform_xy(np.array([c.xy_m]))[0]
            to_goal = math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))
            row = {
                "id": c.id,
                "state": c.state,
                "n_views": c.n_views,
                "best_score": round(c.best_score, 1),
                "to_goal_m": round(to_goal, 2),
            }
            if getattr(c, "why", None):
                row["why"] = c.why
            out.append(row)
        return out

    def ghost_cells(self) -> int | None:
        """Obstacle cells of the agent's final map that lie in truly open floor (at least
        ``GHOST_CLEARANCE_M`` beyond where the robot's centre can go): phantom obstacles from
        depth noise or a drifting pose (None: no map)."""
        snap = self.last.map if self.last is not None else None
        if snap is None or not snap.obstacle.any():
            return None if snap is None else 0
        ij = np.argwhere(snap.obstacle)
        xy_run = (ij[:, ::-1] + 0.5) * snap.resolution_m + np.asarray(snap.origin_xy_m)
        xy = self.oracle.frame_world.transform_xy(xy_run)
        grid = self.oracle.navigable
        clear = _open_floor(grid)
        gi = np.floor((xy[:, 1] - grid.origin_xy_m[1]) / grid.resolution_m).astype(np.int64)
        gj = np.floor((xy[:, 0] - grid.origin_xy_m[0]) / grid.resolution_m).astype(np.int64)
        ok = (gi >= 0) & (gi < clear.shape[0]) & (gj >= 0) & (gj < clear.shape[1])
        return int(np.count_nonzero(clear[gi[ok], gj[ok]]))

    def cause(self, success: bool) -> str | None:
        return failure_cause(
            success,
            candidate_to_goal_m=self._candidate_distance_m(),
            candidate_on_goal_steps=self.candidate_on_goal_steps,
            detections_goal_in_view=self.det_seen,
            detections_goal_out_of_view=self.det_unseen,
            goal_seen_steps=self.seen_steps,
            ghost_obstacle_cells=self.ghost_cells(),
            max_pose_error_m=max(self.pose_error_m, default=0.0),
        )

    def finish(self, episode_record: Mapping[str, Any]) -> Mapping[str, Any]:
        d = self._candidate_distance_m()
        return {
            "variant": self.variant,
            "agent_config": self.agent_config,
            "failure_cause": self.cause(bool(episode_record.get("success"))),
            "modiin": {
                "goal_seen_steps": self.seen_steps,
                "first_seen_step": self.first_seen,
                "candidates": self._candidates(),
                "first_detection_step": self.first_detection,
                "detections_goal_in_view": self.det_seen,
                "detections_goal_out_of_view": self.det_unseen,
                "candidate_to_goal_m": None if d is None else round(d, 3),
                "candidate_on_goal_steps": self.candidate_on_goal_steps,
                "final_mode": self.last.mode if self.last else None,
                "final_reason": self.last.reason if self.last else None,
                "final_event": self.last.event if self.last else None,
                "final_context": list(self.last.context) if self.last else None,
                "planner_errors": self.planner_errors,
                "modes": dict(self.modes),
                "events": dict(self.events),
                "contexts": dict(self.contexts),
                "median_ms": {k: round(float(np.median(v)), 2) for k, v in self.timings.items()},
                "full_matcher_steps": self.full_matcher_steps,
                "gated_goal_in_view_steps": self.gated_goal_in_view,
                "second_look_step": self.second_look_step,
                "ghost_obstacle_cells": self.ghost_cells(),
                "pose_error_m": {
                    "max": round(max(self.pose_error_m, default=0.0), 3),
                    "final": round(self.pose_error_m[-1] if self.pose_error_m else 0.0, 3),
                },
                "yaw_error_deg": {
                    "median": round(float(np.median(self.yaw_error_deg)) if self.yaw_error_deg else 0.0, 2),
                    "max": round(max(self.yaw_error_deg, default=0.0), 2),
                },
                "aligned_steps": self.aligned_steps,
                "trace": {
                    "reid_score": self.trace_score,
                    "goal_px": self.trace_goal_px,
                    "gate_score": self.trace_gate,
                    "exit_score": self.trace_exit,
                    "goal_dist_m": self.trace_goal_dist,
                },
            },
        }


register(
    AgentSpec(
        "modiin",
        "the Mod-IIN agent (Krantz et al. 2023) and its ablations",
        make_agent,
        add_arguments,
        make_observer=Attribution,
        summarize=summarize,
        worker_init=worker_init,
        make_memory=make_memory,
    )
)


if __name__ == "__main__":  # python -m sim.evaluation.modiin OUT1 OUT2 ...
    from sim.evaluation.cli import tables_main

    sys.exit(tables_main(comparison_tables, sys.argv[1:]))
