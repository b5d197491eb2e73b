"""Generating multi-goal sets (``imgnav episodes --goals N``; issue 31, format in ``sim.sequences``).

Homes: the same scene seeds as the single-goal set of the same split and seed
(``scene_seed_for``), ``sequences_per_scene`` sequences per home (default one).

Goals: the first goal and its start are chosen as a single-goal episode's (``episode_gen``:
round-robin over the categories, cycling difficulty bins, the same start checks). Each later
goal is, by a draw per goal: mostly ``new`` (an instance of a category not asked for yet in the
sequence), sometimes a ``repeat`` (an earlier goal's instance again, never the goal just before,
whose robot would already stand at it, photographed again from at least
``repeat_min_eye_shift_m`` away from its earlier photos) and sometimes a ``lookalike`` (another
instance of an earlier goal's category, when the home has one). When the drawn kind is not
possible the others are tried (new, then look-alike, then repeat); a new instance whose
category was already asked for is labelled a look-alike.

Solvability, for every goal (the single-goal guarantee, and more): at least ``min_viewpoints``
viewpoints in the home's free component, which holds the start and so every pose the robot can
reach; the shortest-path oracle agent solves it from the sequence's first start (for goal 0
with the single-goal start checks); and the oracle solves it from where the oracle ended the
goal before (the chain ``imgnav eval --agent oracle`` replays, so the oracle's SR is 1.0 on
every subtask by construction). A goal no candidate instance passes ends the attempt and the
sequence is drawn again from the next first goal.

Deterministic: random choices come from RNGs seeded by (split, seed, home index), floats are
rounded before they are used, and homes are taken in order whatever the number of workers.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agent.types import Pose2D
from sim.episode_gen import (
    EpisodeGenConfig,
    HomeFloor,
    StartPick,
    collect_scenes,
    goal_image_info,
    goal_order,
    home_floor,
    oracle_run,
    pick_start,
    prune_goal_images,
)
from sim.episodes import SPLITS, r4, scene_seed_for, write_rgb
from sim.goals import GoalImage, sample_goal_images
from sim.navigation import geodesic_at, geodesic_field, instance_viewpoints
from sim.scene_gen import GENERATOR_VERSION
from sim.sequences import SequenceEpisode, SequenceGoal, save_sequence_set, subtask_id
from sim.world import SimWorld

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SequenceGenConfig:
    goals: int = 4
    sequences_per_scene: int = 1
    repeat_share: float = 0.2  # of the later goals (from the third on: a repeat skips the goal just before)
    max_repeats_per_goals: float = 0.25  # at most this share of a sequence's goals (at least one) are repeats
    lookalike_share: float = 0.2  # of the later goals, when the home has another instance of an earlier category
    # a later goal is taken at least this far (geodesic) from where the robot left the previous one
    # when some candidate is (the easy bin's lower bound)
    min_subtask_geodesic_m: float = 1.5
    repeat_min_eye_shift_m: float = 0.75
    repeat_photo_attempts: int = 4
    candidates_per_goal: int = 6  # instances checked with the oracle per goal before giving up
    base: EpisodeGenConfig = field(default_factory=EpisodeGenConfig)


@dataclass(frozen=True, slots=True, eq=False)
class _Pick:
    instance_id: int
    kind: str
    of_goal: int | None
    image: GoalImage
    chain_geodesic_m: float | None  # from where the oracle ended the previous goal (None for goal 0)


class _Home:
    """One home's floor, instances and caches (viewpoints and geodesic fields per instance)."""

    def __init__(self, world: SimWorld, cfg: SequenceGenConfig, scene_seed: int) -> None:
        self.world, self.cfg, self.scene_seed = world, cfg, scene_seed
        self.floor: HomeFloor = home_floor(world, cfg.base)
        self._vp: dict[int, np.ndarray] = {}
        self._field: dict[int, np.ndarray] = {}

    def viewpoints(self, inst: int) -> np.ndarray:
        if inst not in self._vp:
            self._vp[inst] = np.round(instance_viewpoints(self.world, inst, self.floor.comp), 4)
        return self._vp[inst]

    def usable(self, inst: int) -> bool:
        return len(self.viewpoints(inst)) >= self.cfg.base.min_viewpoints

    def geodesic_m(self, inst: int, pose: Pose2D) -> float:
        if inst not in self._field:
            self._field[inst] = geodesic_field(self.floor.grid, self.viewpoints(inst), self.floor.comp)
        return r4(geodesic_at(self._field[inst], self.floor.grid, pose.x_m, pose.y_m))

    def oracle_end(self, inst: int, start: Pose2D) -> Pose2D | None:
        """Where the oracle agent ends goal ``inst`` from ``start`` when it succeeds, else None."""
        geo = self.geodesic_m(inst, start)
        if not math.isfinite(geo):
            return None
        m, end = oracle_run(self.world, start, inst, self.viewpoints(inst), geo)
        return end if m is not None and m.success else None

    def category(self, inst: int) -> str:
        return self.world.home.instance(inst).category


def _photo(
    home: _Home, inst: int, seed: tuple[int, ...], allow: int, earlier: list[GoalImage], min_shift_m: float
) -> GoalImage | None:
    """A goal image of ``inst``; a repeat's (``earlier`` photos of it) is taken from elsewhere."""
    attempts = home.cfg.repeat_photo_attempts if earlier else 1
    for a in range(attempts):
        images = sample_goal_images(home.world, inst, 1, seed=seed + ((a,) if earlier else ()), distractor_budget=allow)
        if not images:
            continue
        eye = np.asarray(images[0].camera.eye_xyz_m)
        if all(np.linalg.norm(eye - np.asarray(e.camera.eye_xyz_m)) >= min_shift_m for e in earlier):
            return images[0]
    return None


def _pools(home: _Home, order: list[int], picks: list[_Pick]) -> dict[str, list[tuple[int, int | None]]]:
    """Candidates (instance, of_goal) for the next goal, per kind, in the home's goal order."""
    used = {p.instance_id for p in picks}
    max_repeats = max(1, math.floor(home.cfg.max_repeats_per_goals * home.cfg.goals))
    last_of_cat = {home.category(p.instance_id): i for i, p in enumerate(picks)}
    fresh = [i for i in order if i not in used and home.usable(i)]
    last_of_inst = {p.instance_id: i for i, p in enumerate(picks[:-1]) if p.instance_id != picks[-1].instance_id}
    return {
        "new": [(i, None) for i in fresh if home.category(i) not in last_of_cat],
        "lookalike": [(i, last_of_cat[home.category(i)]) for i in fresh if home.category(i) in last_of_cat],
        "repeat": sorted(last_of_inst.items()) if sum(p.kind == "repeat" for p in picks) < max_repeats else [],
    }


def _next_goal(
    home: _Home,
    order: list[int],
    picks: list[_Pick],
    first_start: Pose2D,
    end: Pose2D,
    rng: np.random.Generator,
    photo_seed: tuple[int, ...],
    allow: int,
) -> tuple[_Pick, Pose2D] | None:
    """The next goal of a sequence and where the oracle ends it, or None."""
    cfg = home.cfg
    u = float(rng.uniform())
    if u < cfg.repeat_share:
        prefs = ("repeat", "new", "lookalike")
    elif u < cfg.repeat_share + cfg.lookalike_share:
        prefs = ("lookalike", "new", "repeat")
    else:
        prefs = ("new", "lookalike", "repeat")
    pools = _pools(home, order, picks)
    for kind in prefs:
        cands = pools[kind]
        if kind == "repeat":
            cands = [cands[int(i)] for i in rng.permutation(len(cands))]
        else:  # goals far from where the robot stands first: a goal next to the last one asks little
            cands = sorted(cands, key=lambda c: home.geodesic_m(c[0], end) < cfg.min_subtask_geodesic_m)
        for inst, of_goal in cands[: cfg.candidates_per_goal]:
            if kind != "repeat" and home.oracle_end(inst, first_start) is None:
                continue  # a repeat's instance was checked from the first start when first chosen
            new_end = home.oracle_end(inst, end)
            if new_end is None:
                continue
            earlier = [p.image for p in picks if p.instance_id == inst]
            image = _photo(home, inst, photo_seed + (inst,), allow, earlier, cfg.repeat_min_eye_shift_m)
            if image is None:
                continue
            return _Pick(inst, kind, of_goal, image, home.geodesic_m(inst, end)), new_end
    return None


def _sequence(
    home: _Home, order: list[int], first: int, start: StartPick, rng: np.random.Generator, ids: tuple[int, int]
) -> list[_Pick] | None:
    """The goals of one sequence from its first goal and start, or None. ids: (sequence's global
    index, index in its home), for the distractor cycle and the photo seeds."""
    cfg = home.cfg
    n_global, j = ids
    end = home.oracle_end(first, start.pose)
    if end is None:
        return None

    def allow(g: int) -> int:
        return 1 if (n_global * cfg.goals + g) % cfg.base.distractor_every == 0 else 0

    seed = (home.scene_seed % 2**31, 31, j)
    image = _photo(home, first, seed + (0, first), allow(0), [], 0.0)
    if image is None:
        return None
    picks = [_Pick(first, "new", None, image, None)]
    for g in range(1, cfg.goals):
        nxt = _next_goal(home, order, picks, start.pose, end, rng, seed + (g,), allow(g))
        if nxt is None:
            log.debug("scene %d: no goal %d after %s", home.scene_seed, g, [p.instance_id for p in picks])
            return None
        picks.append(nxt[0])
        end = nxt[1]
    return picks


def _goal_info(home: _Home, pick: _Pick) -> dict:
    obj = home.world.home.instance(pick.instance_id)
    room = home.world.home.room_at(*obj.center_xyz_m()[:2])
    info = {
        "goal_room": room.name if room else None,
        "goal_variant": obj.variant,
        **goal_image_info(pick.image),
    }
    if pick.chain_geodesic_m is not None:
        # the shortest path from where the oracle agent ended the previous goal (an agent's own
        # start for this goal is where it ended the previous one)
        info["oracle_chain_geodesic_m"] = pick.chain_geodesic_m
    return info


def _scene_sequences(split: str, set_seed: int, k: int, out_dir: Path, cfg: SequenceGenConfig) -> list[SequenceEpisode]:
    scene_seed = scene_seed_for(split, set_seed, k)
    rng = np.random.default_rng([SPLITS.index(split), set_seed, k, 4343])
    world = SimWorld.from_seed(scene_seed)
    try:
        home = _Home(world, cfg, scene_seed)
        order = goal_order(world.home, rng)
        out: list[SequenceEpisode] = []
        firsts = [i for i in order if home.usable(i)]
        for first in firsts:
            if len(out) >= cfg.sequences_per_scene:
                break
            j = len(out)
            n_global = k * cfg.sequences_per_scene + j
            vp = home.viewpoints(first)
            start = pick_start(world, home.floor, first, vp, n_global, rng, cfg.base, scene_seed)
            if start is None:
                continue
            picks = _sequence(home, order, first, start, rng, (n_global, j))
            if picks is None:
                continue
            out.append(_write_sequence(home, split, set_seed, k, j, start, picks, out_dir))
        return out
    finally:
        world.close()


def _write_sequence(
    home: _Home,
    split: str,
    set_seed: int,
    k: int,
    j: int,
    start: StartPick,
    picks: list[_Pick],
    out_dir: Path,
) -> SequenceEpisode:
    episode_id = f"{split}-s{set_seed}-{k:04d}-q{j}"
    goals = []
    for g, p in enumerate(picks):
        rel = f"goals/{subtask_id(episode_id, g)}.png"
        write_rgb(out_dir / rel, p.image.rgb)
        vp = home.viewpoints(p.instance_id)
        goals.append(
            SequenceGoal(
                p.instance_id,
                home.category(p.instance_id),
                rel,
                tuple((float(x), float(y)) for x, y in vp),
                p.kind,
                p.of_goal,
                _goal_info(home, p),
            )
        )
    pose = start.pose
    start_room = home.world.home.room_at(pose.x_m, pose.y_m)
    vp0 = home.viewpoints(picks[0].instance_id)
    info = {
        "difficulty": start.difficulty,
        "start_room": start_room.name if start_room else None,
        "multi_room": start_room is not start.goal_room,
        "euclidean_distance_m": r4(min(math.hypot(pose.x_m - x, pose.y_m - y) for x, y in vp0)),
        "lattice_path_m": r4(start.plan.path_length_m),
        "kinds": [p.kind for p in picks],
    }
    return SequenceEpisode(episode_id, split, home.scene_seed, pose, start.geodesic_m, tuple(goals), info)


def _worker(args: tuple[str, int, int, str, SequenceGenConfig]) -> list[SequenceEpisode]:
    split, set_seed, k, out_dir, cfg = args
    return _scene_sequences(split, set_seed, k, Path(out_dir), cfg)


def generate_sequence_set(
    split: str,
    seed: int,
    count: int,
    out_dir: str | Path,
    cfg: SequenceGenConfig = SequenceGenConfig(),
    workers: int = 1,
    progress: bool = True,
) -> list[SequenceEpisode]:
    """Generate ``count`` sequences of ``cfg.goals`` goals into ``out_dir`` (episodes.json + goals/*.png)."""
    if cfg.goals < 2:
        raise ValueError("a multi-goal set needs at least 2 goals per sequence (1 goal: generate_episode_set)")
    out = Path(out_dir)
    job = (split, seed, out, cfg)
    sequences = collect_scenes(_worker, job, count, cfg.sequences_per_scene, workers, progress, "sequences")
    prune_goal_images(out, {g.goal_image for s in sequences for g in s.goals})
    meta = {
        "generator_version": GENERATOR_VERSION,
        "goals_per_episode": cfg.goals,
        "count": len(sequences),
        "scenes": len({s.scene_seed for s in sequences}),
    }
    save_sequence_set(out, split, seed, sequences, meta)
    return sequences
