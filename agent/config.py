"""The agent's configuration: one frozen dataclass per module, composed (DESIGN section 7).

Deployments: ``agent/configs/sim.yaml`` and ``agent/configs/stretch.yaml``; loading is
strict (``agent.configio``): an unknown key is an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

from agent.configio import from_dict, load_yaml
from agent.frontier import FrontierConfig
from agent.localisation import LocalisationConfig
from agent.mapping import MappingConfig
from agent.planner import PlannerConfig
from agent.reid.identifier import ReIDConfig
from agent.segmentation import SegmentationConfig


@dataclass(frozen=True, slots=True)
class PolicyConfig:
    # where detections come from: the matcher (the paper) or an injected oracle (ablation)
    reid_source: Literal["matcher", "oracle"] = "matcher"
    # where goal points come from: matched keypoints inside the goal-image mask (the paper),
    # or the injected ground-truth egocentric instance mask (the "oracle" localisation ablation)
    localisation_source: Literal["goal_mask", "oracle"] = "goal_mask"
    look_around_turns: int = 12  # a full turn at the start (12 x 30 deg); 0 disables
    stop_radius_m: float = 0.8  # stop when the robot centre is this close to a goal cell (success: 1.0 m)
    facing_tolerance_deg: float = 16.0  # and the goal is within this of the heading
    rank_candidates_by: Literal["points", "score"] = "points"  # the paper keeps the largest cluster
    verify: bool = True  # confirm a candidate by a re-match at close range before stopping
    verify_range_m: float = 2.0  # a detection from this close confirms the candidate
    # ... when its points lie this close to the candidate's cells (large objects split into clusters)
    verify_match_radius_m: float = 1.0
    # when the stop region is unreachable, the nearest cells up to this much farther will do
    stop_radius_slack_m: float = 0.25
    verify_scan_steps: int = 4  # turns (left, right, right, left) looking for a confirmation
    # "close_range": the paper-plus check above (scan at the stop point, confirm by a detection
    # within verify_range_m); "approach": a candidate without a detection from within
    # verify_range_m is approached to the verify ring and looked at before it is trusted
    verify_by: Literal["close_range", "approach"] = "close_range"
    # frames scoring at least this share of tau add goal points too, as evidence of a
    # *potential* candidate, which is verified by approach before it is trusted; 1.0: only
    # detections add points (the paper)
    potential_tau_ratio: float = 1.0
    verify_distance_m: float = 2.0  # the verify ring's outer radius around the candidate's cells
    # the ring's inner radius: where the level camera starts to lose the candidate's top
    # ((camera height - top of its points) / tan(half vertical FOV)), plus this margin
    verify_min_margin_m: float = 0.3
    verify_views: int = 8  # steps looking at a potential candidate from the ring before rejecting it
    # a look from the verify ring, facing the candidate, that scores at least this share of tau
    # and adds points to it confirms it (1.0: only a detection does). From 1-2 m true goals
    # reach tau/2 in most frames and frames without them seldom do (docs/evidence/evidence.md)
    verify_ring_tau_ratio: float = 1.0
    # where to stop: "radius" = within stop_radius_m of the nearest goal cell (the paper);
    # "core" = within stop_radius_m of the candidate's core cells (robust to stray points), and
    # closer than stop_radius_m of the nearest one
    stop_rule: Literal["radius", "core"] = "radius"
    stop_core_quantile: float = 0.7  # core cells: this share of the cells nearest to the points' median
    # what the quantile counts: "points" = the cells of this share of the candidate's points
    # nearest to their median (each cell weighs by its evidence); "cells" = this share of its
    # cells (a few stray points spread over many cells, and the objects' own points pack into a
    # few: on val a third of a TV's cells held 3% of its points, 0.4-0.9 m in front of it)
    stop_core_by: Literal["points", "cells"] = "cells"
    # success needs the object in view from the stop point. At the stop, facing the candidate,
    # its points that fall in the frame are checked against the depth image: when fewer than
    # ``stop_view_min_share`` of them (and at least ``stop_view_min_points`` fall in the frame)
    # are seen, not hidden behind something nearer (a wall between the robot and an object
    # against its other side; the object's own near side counts as seen), the spot is struck
    # off the candidate's stop region, what hid it blocks the line of sight, and the approach
    # goes on; after ``stop_view_max_spots`` such spots, or when no other spot can be reached,
    # it stops where it can, as without the check. Points out of the frame (a low object below
    # the level camera) are no evidence
    stop_needs_view: bool = False
    stop_view_min_share: float = 0.1  # the simulator calls an object visible from 10% of its sample points
    stop_view_min_points: int = 10
    # nearer by more than this (plus the share below of the point's depth) is hidden: an object
    # against a wall has the wall within 0.1-0.2 m of its points
    stop_view_margin_m: float = 0.1
    stop_view_margin_frac: float = 0.05
    stop_view_own_m: float = 0.05  # a surface in or next to the candidate's cells is the object itself
    stop_view_occluder_m: float = 0.1  # what hid the candidate blocks lines of sight this far around it
    stop_view_spot_radius_m: float = 0.3
    stop_view_max_spots: int = 4
    reject_radius_m: float = 0.3  # blacklist margin around a rejected candidate's cells
    # a rejected candidate that never scored tau (potential evidence only) blacklists only the
    # evidence below tau around it: a later detection there still counts
    soft_reject_potential: bool = True
    unreachable_goal_steps: int = 10  # consecutive unreachable plans before a candidate is dropped
    # before that, drop the collision marks and count again, this many times per candidate (0: off)
    unreachable_forgive: int = 0
    approach_patience_steps: int = 100  # steps without getting nearer to a candidate before it is dropped
    max_rescans: int = 3  # look-arounds (forgiving given-up frontiers) before stopping as "exhausted"
    # when exploration is exhausted, go to the rejected candidate with the best evidence (highest
    # re-ID score of its views) and stop there, trusted, instead of stopping where the robot
    # stands: with nothing left to explore, the best rejected guess beats any other spot
    last_resort: bool = False
    # The last resort before the step budget runs out: a time-out always fails, so when the
    # steps left are only just enough to reach the best rejected candidate (its geodesic
    # distance in forward steps, times deadline_path_factor for the turns and zig-zags of the way, plus
    # deadline_margin_steps to face it), head for it and stop there, as the last resort does
    # when exploration is exhausted. Needs step_budget (the episode's action budget; 0: not
    # known, off). The check runs only in the last deadline_window_steps of the budget.
    last_resort_at_deadline: bool = False
    step_budget: int = 0
    deadline_window_steps: int = 200
    deadline_path_factor: float = 2.5  # train: a median 2.56 actions per forward move (40 episodes)
    deadline_margin_steps: int = 30
    # ... and the deadline also comes before verifying a potential candidate whose best score is
    # below the best rejected one's: with the budget nearly spent, the better evidence is the
    # better bet (without it the last resort waits while any candidate is live, and a candidate
    # scoring 1-5 can keep the robot verifying until the budget runs out)
    deadline_over_weaker: bool = False
    collision_min_motion_m: float = 0.05  # a forward move shorter than this was a collision
    # The turn-in-place livelock: the plan points at a forward move that already failed from
    # here (refused by the motion memory), the refusal turns away, the plan turns back, for
    # ever: the frontier's no-progress count never runs out, because each rescan in between
    # (which forgives collision marks and given-up frontiers) starts it again. After this many
    # alternating turns in a row the frontier is given up, as after no progress, and one
    # rescan's forgiving is spent, so that the loop cannot come back for ever (0: off).
    oscillation_turns: int = 0
    # The same run, got out of instead of given up: after this many alternating turns in a row,
    # step forward once on the free heading (map traversible, not a remembered failed move) that
    # ends nearest the path 1 m ahead, turning to it first without re-planning (0: off).
    detour_after_turns: int = 0
    snapshot_every: int = 1  # map snapshot in the record every n steps (0: never)
    # The second look when exploration is exhausted: with nothing left to explore and no goal
    # candidate at all (none live, none rejected for the last resort), the agent would stop where
    # it stands, a failure unless it happens to stand at the goal. The goal is in the home, so it
    # was probably among the frames already seen, scored low by the matcher (or dropped by the
    # gate). The searching frames with the most mutual-nearest descriptor pairs with the goal (the
    # gate's first-stage count; the re-ID score when the gate is off) are kept, this many of them
    # (0: off); at that point each is scored again with the full matcher and its matches are
    # localised whatever the score, as potential evidence, verified by approach like any other
    # (and, rejected, left to the last resort). Once per run; matcher localisation only.
    exhausted_recheck_frames: int = 0
    # ... of which only those scoring at least this share of the best re-scored frame are
    # localised: the others (train: 1-5 against 15-50 for the goal's) form candidates whose
    # verification can use up the budget before the last resort reaches the best one (0: all)
    exhausted_recheck_min_share: float = 0.0


@dataclass(frozen=True, slots=True)
class AgentConfig:
    mapping: MappingConfig = field(default_factory=MappingConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    frontier: FrontierConfig = field(default_factory=FrontierConfig)
    reid: ReIDConfig = field(default_factory=ReIDConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    localisation: LocalisationConfig = field(default_factory=LocalisationConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)


DEPLOYMENTS = ("sim", "stretch")


def deployment_path(name: str) -> Path:
    return Path(str(resources.files("agent").joinpath("configs", f"{name}.yaml")))


def load_agent_config(name_or_path: str | Path = "sim") -> AgentConfig:
    """A deployment name (``sim``, ``stretch``) or a YAML path -> ``AgentConfig`` (strict)."""
    p = Path(name_or_path)
    if str(name_or_path) in DEPLOYMENTS:
        p = deployment_path(str(name_or_path))
    return load_yaml(AgentConfig, p)


def agent_config_from_dict(data: dict) -> AgentConfig:
    return from_dict(AgentConfig, data, where="agent config")
