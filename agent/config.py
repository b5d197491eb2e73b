"""The agent's configuration: one frozen dataclass per module, composed (docs/architecture.md section 7).

The dataclass defaults are the agent we ship, as measured in the simulator. A deployment
(``agent/configs/sim.yaml``, ``agent/configs/stretch.yaml``) sets only what differs on its camera
or robot, each line with its reason; loading is strict (``agent.configio``): an unknown key is
an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

from agent.alignment import AlignmentConfig
from agent.configio import from_dict, load_yaml
from agent.frontier import FrontierConfig
from agent.localisation import LocalisationConfig
from agent.mapping import MappingConfig
from agent.memory import MemoryConfig
from agent.planner import PlannerConfig
from agent.reid.identifier import ReIDConfig
from agent.segmentation import SegmentationConfig


@dataclass(frozen=True, slots=True)
class PolicyConfig:
    """The policy's rules. The defaults are the agent we ship (measured on train, reported on val:
    docs/experiments/README.md); a deployment's YAML changes only what its camera or robot demands.
    The paper's own rules are ``stop_rule="radius"``, ``stop_radius_m=0.8``, ``potential_tau_ratio=1.0``
    and every mechanism beyond it off (``last_resort``, the deadline, the side-step, the second look)."""

    # where detections come from: the matcher (the paper) or an injected oracle (ablation)
    reid_source: Literal["matcher", "oracle"] = "matcher"
    # where goal points come from: matched keypoints inside the goal-image mask (the paper),
    # or the injected ground-truth egocentric instance mask (the "oracle" localisation ablation)
    localisation_source: Literal["goal_mask", "oracle"] = "goal_mask"
    look_around_turns: int = 12  # a full turn at the start (12 x 30 deg); 0 disables
    # where to stop: "radius" = within stop_radius_m of the nearest goal cell (the paper);
    # "core" = within stop_radius_m of the candidate's core cells (the cells of the
    # stop_core_quantile of its points nearest their median: stray points, e.g. depth read off
    # what stands behind an object's edge, do not pull the stop point off the object), and only
    # where the map shows a line of sight to them (success needs the object in view)
    stop_rule: Literal["radius", "core"] = "core"
    stop_radius_m: float = 0.6  # success is decided at 1.0 m; the paper stopped at 0.8 m of the nearest cell
    stop_core_quantile: float = 0.7
    # ... of them, only those on the one obstacle of the map that holds most of the core's
    # points: the goal mask leaks onto what stands before the object (agent/stop_region.py)
    stop_one_object: bool = True
    facing_tolerance_deg: float = 16.0  # ... and the goal is within this of the heading
    # when the stop region is unreachable, the nearest cells up to this much farther will do
    stop_radius_slack_m: float = 0.25
    # frames scoring at least this share of tau add goal points too, as evidence of a
    # *potential* candidate, which is verified by approach before it is trusted; 1.0: only
    # detections add points (the paper)
    potential_tau_ratio: float = 0.5
    verify_distance_m: float = 2.0  # the verify ring's outer radius around the candidate's cells
    # the ring's inner radius: where the level camera starts to lose the candidate's top
    # ((camera height - top of its points) / tan(half vertical FOV)), plus this margin
    verify_min_margin_m: float = 0.3
    verify_views: int = 8  # steps looking at a potential candidate from the ring before rejecting it
    # a look from the verify ring, facing the candidate, that scores at least this share of tau
    # and adds points to it confirms it (1.0: only a detection does). From 1-2 m true goals
    # reach tau/2 in most frames and frames without them seldom do (docs/experiments)
    verify_ring_tau_ratio: float = 0.5
    reject_radius_m: float = 0.3  # blacklist margin around a rejected candidate's cells
    unreachable_goal_steps: int = 10  # consecutive unreachable plans before a candidate is dropped
    # before that, drop the collision marks and count again, this many times per candidate (0: off):
    # failed moves near an object leave bands that can wall in its stop region
    unreachable_forgive: int = 1
    # ... and when a way to it that the robot already had grows by more than this (a failed move
    # in a doorway: its band closes the door and the plan goes round the home), drop them if that
    # gives back a way at least this much shorter; counted with ``unreachable_forgive`` (0: off)
    detour_forgive_m: float = 2.0
    approach_patience_steps: int = 100  # steps without getting nearer to a candidate before it is dropped
    max_rescans: int = 3  # look-arounds (forgiving given-up frontiers) before stopping as "exhausted"
    # A fresh map when exploration runs out early with nothing worth going to: once the rescans
    # are spent with at least ``fresh_map_min_steps_left`` steps of the budget left, and no
    # rejected candidate scores ``fresh_map_below_tau_ratio`` x tau or more (the last resort
    # would stop at no evidence, or the run would end exhausted), the second look is taken first
    # and then the map's geometry (obstacles, explored area, collision marks) is forgotten and the
    # robot looks around and explores again; candidates, rejections and where the robot has been
    # are kept. Once a run; 0: off. With a drifting pose and noisy depth the map accumulates
    # walls drawn a little off from every earlier pose and range, and those copies close
    # doorways for good (the obstacle evidence clears only what is seen through from within
    # 3 m); a map begun again from where the robot stands carries none of them. Without the
    # score floor it came before last resorts and second looks that would have succeeded and
    # lost on val (docs/experiments/fresh-map.md); with it, it acts only where the run would
    # stop at no evidence (docs/experiments/fresh-map-no-evidence.md)
    fresh_map_min_steps_left: int = 250
    # 0.15 x tau (75.3): 11.3, about the 95th percentile of the re-ID scores of *different*
    # objects in the agent's calibration pairs (11.7 clean, 10.7 with phone-like photos,
    # docs/results/i30_realism/calibration_phone): a candidate scoring below it is no evidence
    fresh_map_below_tau_ratio: float = 0.15
    # when exploration is exhausted, go to the rejected candidate with the best evidence (highest
    # re-ID score of its views) and stop there, trusted, instead of stopping where the robot
    # stands: with nothing left to explore, the best rejected guess beats any other spot
    last_resort: bool = True
    # The last resort before the step budget runs out: a time-out always fails, so when the
    # steps left are only just enough to reach the best rejected candidate (its geodesic
    # distance in forward steps, times deadline_path_factor for the turns and zig-zags of the way, plus
    # deadline_margin_steps to face it), head for it and stop there, as the last resort does
    # when exploration is exhausted. Needs step_budget (the episode's action budget; 0: not
    # known, off). The check runs only in the last deadline_window_steps of the budget.
    last_resort_at_deadline: bool = True
    step_budget: int = 1000  # the benchmark's action budget (docs/architecture.md section 1)
    deadline_window_steps: int = 200
    deadline_path_factor: float = 2.5  # train: a median 2.56 actions per forward move (40 episodes)
    deadline_margin_steps: int = 30
    # ... and the deadline also comes before verifying a potential candidate whose best score is
    # below the best rejected one's: with the budget nearly spent, the better evidence is the
    # better bet (without it the last resort waits while any candidate is live, and a candidate
    # scoring 1-5 can keep the robot verifying until the budget runs out)
    deadline_over_weaker: bool = True
    collision_min_motion_m: float = 0.05  # a forward move shorter than this was a collision
    # The turn-in-place livelock: the plan points at a forward move that already failed from
    # here, the refusal turns away, the plan turns back, for ever. After this many alternating
    # turns in a row, step forward once on the free heading (map traversible, not a remembered
    # failed move) that ends nearest the path 1 m ahead, turning to it first without
    # re-planning (0: off).
    detour_after_turns: int = 4
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
    exhausted_recheck_frames: int = 16


@dataclass(frozen=True, slots=True)
class AgentConfig:
    mapping: MappingConfig = field(default_factory=MappingConfig)
    # each depth frame aligned to the map before it is fused (agent/alignment.py)
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    frontier: FrontierConfig = field(default_factory=FrontierConfig)
    reid: ReIDConfig = field(default_factory=ReIDConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    localisation: LocalisationConfig = field(default_factory=LocalisationConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    # the memory of a home across goals (agent/memory.py): used only by an agent given a HomeMemory
    memory: MemoryConfig = field(default_factory=MemoryConfig)


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
