"""Generating InstanceImageNav episode sets (``imgnav episodes``).

Scenes: the set (split, seed) uses scene seeds ``scene_seed_for(split, seed, k)``
for k = 0, 1, ... (disjoint ranges per split). Each scene yields up to
``episodes_per_scene`` episodes, one per goal instance, cycling through the
categories so rarer ones (toilet, tv, couch, bed) are well represented.

Difficulty: episodes cycle through geodesic-distance bins (easy 1.5-4 m, medium
4-8 m, hard > 8 m); easy starts are taken in the goal's room and medium and hard
ones in another room when the home allows, so most episodes cross rooms.

Validity: the start is collision-free with 0.1 m to spare, in the same free
component as the viewpoints, and the goal region is reachable on the robot's discrete motion
lattice (a lattice A* search with the simulator's own collision-checked step).
Episodes whose region the lattice cannot reach would be unsolvable with the
task's actions, so they are not generated. Finally every episode must be solved by the
shortest-path oracle agent itself (``sim.oracle_agent``, its own A* weight and node budget,
run through a ``SimBackend`` and scored by ``sim.metrics``), so that oracle SR is 1.0 by
construction: the validation search above is a different search (greedier weight 2.0 against
the oracle's 1.2, both capped at ``lattice.MAX_EXPANSIONS``), and a start it accepts is not
guaranteed to be solved by the oracle. A start the oracle does not solve is replaced by
another (``oracle_check``).

Deterministic: every random choice comes from RNGs seeded by (split, seed, k);
floats are rounded before they are used, so the JSON and PNGs are identical
whatever the number of workers.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from scipy import ndimage

from agent.types import Pose2D
from sim.episodes import SPLITS, Episode, r4, save_episode_set, scene_seed_for, write_rgb
from sim.geometry import NavGrid
from sim.goals import GoalImage, sample_goal_images
from sim.home import HomeSpec, Room
from sim.lattice import LatticePlan, ViewpointGoal, plan_to_goal
from sim.metrics import EpisodeMetrics
from sim.navigation import GRID_RESOLUTION_M, geodesic_at, geodesic_field, instance_viewpoints, reachable_component
from sim.scene_gen import GENERATOR_VERSION
from sim.world import SimWorld

T = TypeVar("T")

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class EpisodeGenConfig:
    episodes_per_scene: int = 5
    difficulty_bins_m: tuple[tuple[str, float, float], ...] = (
        ("easy", 1.5, 4.0),
        ("medium", 4.0, 8.0),
        ("hard", 8.0, 1e9),
    )
    min_viewpoints: int = 8
    start_attempts: int = 25
    # one episode in this many may have a goal image that also shows a same-category instance
    distractor_every: int = 5
    validate_weight: float = 2.0
    start_clearance_m: float = 0.1
    oracle_check: bool = True  # run the oracle agent on each episode and keep only those it solves


def _scene_episodes(split: str, set_seed: int, k: int, out_dir: Path, cfg: EpisodeGenConfig) -> list[Episode]:
    scene_seed = scene_seed_for(split, set_seed, k)
    rng = np.random.default_rng([SPLITS.index(split), set_seed, k, 4242])
    world = SimWorld.from_seed(scene_seed)
    try:
        return _generate(world, split, set_seed, k, scene_seed, rng, out_dir, cfg)
    finally:
        world.close()


def _generate(
    world: SimWorld,
    split: str,
    set_seed: int,
    k: int,
    scene_seed: int,
    rng: np.random.Generator,
    out_dir: Path,
    cfg: EpisodeGenConfig,
) -> list[Episode]:
    floor = home_floor(world, cfg)
    home = world.home
    order = goal_order(home, rng)
    episodes: list[Episode] = []
    for inst_id in order:
        if len(episodes) >= cfg.episodes_per_scene:
            break
        j = len(episodes)
        vp = np.round(instance_viewpoints(world, inst_id, floor.comp), 4)
        if len(vp) < cfg.min_viewpoints:
            continue
        start = pick_start(world, floor, inst_id, vp, k * cfg.episodes_per_scene + j, rng, cfg, scene_seed)
        if start is None:
            log.debug("scene %d instance %d: no lattice-reachable start", scene_seed, inst_id)
            continue
        pose, plan, name, goal_room = start.pose, start.plan, start.difficulty, start.goal_room
        allow = 1 if (k * cfg.episodes_per_scene + j) % cfg.distractor_every == 0 else 0
        images = sample_goal_images(world, inst_id, 1, seed=(scene_seed % 2**31, inst_id, 17), distractor_budget=allow)
        if not images:
            log.debug("scene %d instance %d: no acceptable goal image", scene_seed, inst_id)
            continue
        gi = images[0]
        episode_id = f"{split}-s{set_seed}-{k:04d}-{j}"
        rel = f"goals/{episode_id}.png"
        write_rgb(out_dir / rel, gi.rgb)
        start_room = home.room_at(pose.x_m, pose.y_m)
        obj = home.instance(inst_id)
        geo = start.geodesic_m
        info = {
            "difficulty": name,
            "start_room": start_room.name if start_room else None,
            "goal_room": goal_room.name if goal_room else None,
            "multi_room": start_room is not goal_room,
            "goal_variant": obj.variant,
            "euclidean_distance_m": r4(min(math.hypot(pose.x_m - x, pose.y_m - y) for x, y in vp)),
            "lattice_path_m": r4(plan.path_length_m),
            **goal_image_info(gi),
        }
        episodes.append(
            Episode(
                episode_id,
                split,
                scene_seed,
                pose,
                inst_id,
                obj.category,
                rel,
                tuple((float(x), float(y)) for x, y in vp),
                geo,
                info,
            )
        )
    return episodes


@dataclass(frozen=True, slots=True, eq=False)
class HomeFloor:
    """Where a home's episodes live. grid: the 0.05 m navigable grid; comp: (H, W) bool, its
    largest free component; free_ij / free_xy: (N, 2) the cells of ``comp`` a start may take
    (``start_clearance_m`` to spare), grid indices and world metres."""

    grid: NavGrid
    comp: np.ndarray
    free_ij: np.ndarray
    free_xy: np.ndarray


def home_floor(world: SimWorld, cfg: EpisodeGenConfig) -> HomeFloor:
    grid = world.navigable_grid(GRID_RESOLUTION_M)
    comp = reachable_component(grid)
    # starts keep START_CLEARANCE_M beyond the robot's radius from everything (not wedged
    # against a wall or a bed edge), as a robot would be parked
    r = int(round(cfg.start_clearance_m / grid.resolution_m))
    disc = np.hypot(*np.mgrid[-r : r + 1, -r : r + 1]) <= r + 1e-9
    start_ok = ndimage.binary_erosion(comp, structure=disc) if r > 0 else comp
    free_ij = np.argwhere(start_ok)
    return HomeFloor(grid, comp, free_ij, grid.ij_to_xy(free_ij))


def goal_order(home: HomeSpec, rng: np.random.Generator) -> list[int]:
    """The home's instance ids, round-robin over its categories (both shuffled by ``rng``), so
    rarer categories (toilet, tv, couch, bed) come early."""
    by_cat: dict[str, list[int]] = {}
    for inst in home.instances:
        by_cat.setdefault(inst.category, []).append(inst.object_id)
    cats = sorted(by_cat)
    rng.shuffle(cats)
    for cat in cats:
        rng.shuffle(by_cat[cat])
    order: list[int] = []
    while any(by_cat.values()):  # round-robin over categories
        for cat in cats:
            if by_cat[cat]:
                order.append(by_cat[cat].pop())
    return order


@dataclass(frozen=True, slots=True, eq=False)
class StartPick:
    """A validated start for a goal: its pose, the validation's lattice plan, the difficulty bin
    it was drawn from, the geodesic to the goal (rounded, as stored) and the goal's room."""

    pose: Pose2D
    plan: LatticePlan
    difficulty: str
    geodesic_m: float
    goal_room: Room | None


def pick_start(
    world: SimWorld,
    floor: HomeFloor,
    inst_id: int,
    vp: np.ndarray,
    bin_index: int,
    rng: np.random.Generator,
    cfg: EpisodeGenConfig,
    scene_seed: int,
) -> StartPick | None:
    """A start for the goal instance ``inst_id`` (viewpoints ``vp``) in difficulty bin
    ``bin_index`` (cycled), checked as the module docstring says; None if no attempt passes."""
    grid, free_ij, free_xy, home = floor.grid, floor.free_ij, floor.free_xy, world.home
    field = geodesic_field(grid, vp, floor.comp)
    goal_room = home.room_at(*home.instance(inst_id).center_xyz_m()[:2])
    name, lo, hi = cfg.difficulty_bins_m[bin_index % len(cfg.difficulty_bins_m)]
    d = field[free_ij[:, 0], free_ij[:, 1]]
    in_bin = (d >= lo) & (d < hi)
    if not in_bin.any():
        in_bin = d >= cfg.difficulty_bins_m[0][1]
        name = "any"
    cand = np.flatnonzero(in_bin)
    if goal_room is not None:
        # medium and hard episodes start in another room; easy ones in the goal's room when they can
        same = np.array([home.room_at(*free_xy[c]) is goal_room for c in cand], dtype=bool)
        pick = same if name == "easy" else ~same
        if name != "any" and pick.any():
            cand = cand[pick]
    goal = ViewpointGoal(vp)
    for _ in range(cfg.start_attempts):
        c = int(cand[rng.integers(len(cand))])
        pose = Pose2D(r4(free_xy[c, 0]), r4(free_xy[c, 1]), r4(rng.uniform(-math.pi, math.pi)))
        if world.collides(pose.x_m, pose.y_m):
            continue
        plan = plan_to_goal(
            world.move,
            pose,
            goal,
            lambda x, y: max(geodesic_at(field, grid, x, y) - 0.1, 0.0),
            weight=cfg.validate_weight,
        )
        if plan is None:
            continue
        geo_m = r4(geodesic_at(field, grid, pose.x_m, pose.y_m))
        if cfg.oracle_check and not oracle_solves(world, pose, inst_id, vp, geo_m):
            log.info(
                "scene %d instance %d: the oracle agent does not solve start %s; trying another",
                scene_seed,
                inst_id,
                pose,
            )
            continue
        return StartPick(pose, plan, name, geo_m, goal_room)
    return None


def oracle_solves(
    world: SimWorld, start_world: Pose2D, goal_instance_id: int, viewpoints_xy_m: np.ndarray, shortest_path_m: float
) -> bool:
    """Whether the shortest-path oracle agent succeeds on this episode, as ``imgnav eval --agent
    oracle`` would run it (same backend, agent and metrics). The oracle never looks at the
    images, so one blank observation stands in for the renders."""
    result, _ = oracle_run(world, start_world, goal_instance_id, viewpoints_xy_m, shortest_path_m)
    return bool(result is not None and result.success)


def oracle_run(
    world: SimWorld, start_world: Pose2D, goal_instance_id: int, viewpoints_xy_m: np.ndarray, shortest_path_m: float
) -> tuple[EpisodeMetrics | None, Pose2D]:
    """The shortest-path oracle agent's metrics on this goal from ``start_world`` (as in
    ``oracle_solves``) and the pose where it ended (a multi-goal sequence's next start)."""
    from sim.backend import SimBackend
    from sim.oracle_agent import run_blind

    blank = np.zeros((1, 1, 3), np.uint8)
    backend = SimBackend(
        world, blank, start_world, goal_instance_id, np.asarray(viewpoints_xy_m, float), shortest_path_m
    )
    try:
        return run_blind(backend), backend.pose_world
    finally:
        backend.close()  # does not close the shared world


def _worker(args: tuple[str, int, int, str, EpisodeGenConfig]) -> list[Episode]:
    split, set_seed, k, out_dir, cfg = args
    return _scene_episodes(split, set_seed, k, Path(out_dir), cfg)


def goal_image_info(gi: GoalImage) -> dict:
    """What an episode's ``info`` records of its goal photo: the camera, coverage, distractor."""
    return {
        "goal_camera": {
            "eye_xyz_m": [r4(v) for v in gi.camera.eye_xyz_m],
            "yaw_rad": r4(gi.camera.yaw_rad),
            "pitch_rad": r4(gi.camera.pitch_rad),
            "hfov_deg": r4(gi.camera.hfov_deg),
        },
        "goal_coverage": r4(gi.coverage),
        "goal_shows_distractor": gi.shows_distractor,
    }


def collect_scenes(
    worker: Callable[[tuple[str, int, int, str, Any]], list[T]],
    job: tuple[str, int, Path, Any],
    count: int,
    per_scene: int,
    workers: int,
    progress: bool,
    what: str,
) -> list[T]:
    """The first ``count`` items (episodes, sequences) that ``worker`` makes from the scenes 0, 1, ...
    of ``job`` = (split, set seed, output folder, generator config), at most ``per_scene`` from a
    scene (a scene may give fewer), in scene order whatever the number of ``workers``."""
    from tqdm import tqdm

    split, seed, out, cfg = job
    (out / "goals").mkdir(parents=True, exist_ok=True)
    items: list[T] = []
    bar = tqdm(total=count, desc=f"{split} {what}", unit=what, disable=not progress)
    k = 0
    pool = ProcessPoolExecutor(max_workers=workers) if workers > 1 else None
    try:
        while len(items) < count:
            need = count - len(items)
            batch = max(1, min(workers, math.ceil(need / per_scene)))
            jobs = [(split, seed, k + i, str(out), cfg) for i in range(batch)]
            results = list(pool.map(worker, jobs)) if pool else [worker(jobs[0])]
            k += len(results)
            for made in results:  # in scene order: the set does not depend on the worker count
                take = made[: count - len(items)]
                items += take
                bar.update(len(take))
            if k > 50 + 3 * count:
                raise RuntimeError(f"only {len(items)} {what} from {k} scenes; something is wrong")
    finally:
        bar.close()
        if pool:
            pool.shutdown()
    return items


def prune_goal_images(out: Path, keep: set[str]) -> None:
    """Remove the goal images in ``out/goals`` that no kept item uses (``keep``: ``goals/<name>.png``):
    those of items past the count, or stale ones."""
    for png in (out / "goals").glob("*.png"):
        if f"goals/{png.name}" not in keep:
            png.unlink()


def generate_episode_set(
    split: str,
    seed: int,
    count: int,
    out_dir: str | Path,
    cfg: EpisodeGenConfig = EpisodeGenConfig(),
    workers: int = 1,
    progress: bool = True,
) -> list[Episode]:
    """Generate ``count`` episodes into ``out_dir`` (episodes.json + goals/*.png)."""
    out = Path(out_dir)
    job = (split, seed, out, cfg)
    episodes = collect_scenes(_worker, job, count, cfg.episodes_per_scene, workers, progress, "episodes")
    prune_goal_images(out, {e.goal_image for e in episodes})
    meta = {
        "generator_version": GENERATOR_VERSION,
        "count": len(episodes),
        "scenes": len({e.scene_seed for e in episodes}),
    }
    save_episode_set(out, split, seed, episodes, meta)
    return episodes
