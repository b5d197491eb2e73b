"""Multi-goal episodes: sequences of image goals in one home, and their set files (issue 31).

A robot in a home is asked for one object after another (GOAT, Chang et al. 2023; GOAT-Bench,
Khanna et al. 2024). A sequence holds the robot's first start pose and N goals; subtask k > 0
starts where subtask k - 1 ended, so its start (and the shortest path of its SPL) is known only
when it is run (``SequenceEpisode.subtask``). A sequence set is a directory::

    DIR/episodes.json   {"format": "imgnav-sequences", "version": 1, "split", "seed", "goals_per_episode", ...,
                         "episodes": [{"episode_id", "split", "scene_seed", "start_pose_world",
                                       "geodesic_distance_m", "goals": [...], "info"}, ...]}
    DIR/goals/<episode_id>-g<k>.png   goal k's 512x512 image

Each goal is like a single-goal episode's goal (instance, category, image with its camera in
``info``, viewpoints) plus its ``kind``: ``new`` (a category not asked for earlier in the
sequence), ``repeat`` (an earlier goal's instance again, in another photo from elsewhere) or
``lookalike`` (another instance of an earlier goal's category); ``of_goal`` is the index of
the earlier goal it repeats or resembles. Single-goal sets (``sim.episodes``) are unchanged;
``load_any_set`` reads either kind.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agent.types import Pose2D
from sim.episodes import FORMAT as EPISODES_FORMAT
from sim.episodes import (
    Episode,
    EpisodeSet,
    check_set_version,
    load_episode_set,
    r4,
    read_rgb,
    read_set_doc,
    set_json_text,
    write_set_json,
)

FORMAT = "imgnav-sequences"
FORMAT_VERSION = 1
GOAL_KINDS = ("new", "repeat", "lookalike")


def subtask_id(episode_id: str, goal_index: int) -> str:
    """The id of a sequence's subtask (its goal image's name, the key of its realism noise)."""
    return f"{episode_id}-g{goal_index}"


@dataclass(frozen=True, slots=True)
class SequenceGoal:
    """One goal of a sequence. viewpoints_xy_m: world xy of its viewpoints (as ``Episode``);
    goal_image: the PNG's path relative to the set directory; info: its goal camera, coverage,
    room, ... (JSON-able)."""

    goal_instance_id: int
    goal_category: str
    goal_image: str
    viewpoints_xy_m: tuple[tuple[float, float], ...]
    kind: str
    of_goal: int | None = None
    info: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def viewpoints_array(self) -> np.ndarray:
        """(N, 2) float64 world xy."""
        return np.asarray(self.viewpoints_xy_m, dtype=np.float64).reshape(-1, 2)

    def to_json(self) -> dict[str, Any]:
        return {
            "goal_instance_id": self.goal_instance_id,
            "goal_category": self.goal_category,
            "goal_image": self.goal_image,
            "kind": self.kind,
            "of_goal": self.of_goal,
            "viewpoints_xy_m": [[r4(x), r4(y)] for x, y in self.viewpoints_xy_m],
            "info": self.info,
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> SequenceGoal:
        kind = str(d["kind"])
        if kind not in GOAL_KINDS:
            raise ValueError(f"unknown goal kind {kind!r}")
        return SequenceGoal(
            goal_instance_id=int(d["goal_instance_id"]),
            goal_category=str(d["goal_category"]),
            goal_image=str(d["goal_image"]),
            viewpoints_xy_m=tuple((float(a), float(b)) for a, b in d["viewpoints_xy_m"]),
            kind=kind,
            of_goal=None if d.get("of_goal") is None else int(d["of_goal"]),
            info=dict(d.get("info", {})),
        )


@dataclass(frozen=True, slots=True)
class SequenceEpisode:
    """N goals in one home, asked one after another.

    start_pose_world: where the robot starts the first goal (world frame).
    geodesic_distance_m: the shortest path from that start to goal 0's nearest viewpoint (the
    later goals' starts are where the robot ends up, known only at run time).
    info: the first start's facts (difficulty, rooms, ...), JSON-able."""

    episode_id: str
    split: str
    scene_seed: int
    start_pose_world: Pose2D
    geodesic_distance_m: float
    goals: tuple[SequenceGoal, ...]
    info: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    @property
    def id(self) -> str:
        return self.episode_id

    def subtask(self, goal_index: int, start_pose_world: Pose2D, geodesic_distance_m: float) -> Episode:
        """Goal ``goal_index`` as a single-goal ``Episode`` starting at ``start_pose_world`` (where
        the previous subtask ended) with that start's shortest path: what a backend, an agent's
        observer and a record take."""
        goal = self.goals[goal_index]
        info = {**goal.info, "goal_index": goal_index, "kind": goal.kind, "of_goal": goal.of_goal}
        if goal_index == 0:
            info = {**self.info, **info}
        return Episode(
            subtask_id(self.episode_id, goal_index),
            self.split,
            self.scene_seed,
            start_pose_world,
            goal.goal_instance_id,
            goal.goal_category,
            goal.goal_image,
            goal.viewpoints_xy_m,
            geodesic_distance_m,
            info,
        )

    def to_json(self) -> dict[str, Any]:
        p = self.start_pose_world
        return {
            "episode_id": self.episode_id,
            "split": self.split,
            "scene_seed": self.scene_seed,
            "start_pose_world": [r4(p.x_m), r4(p.y_m), r4(p.yaw_rad)],
            "geodesic_distance_m": r4(self.geodesic_distance_m),
            "goals": [g.to_json() for g in self.goals],
            "info": self.info,
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> SequenceEpisode:
        try:
            x, y, yaw = d["start_pose_world"]
            goals = tuple(SequenceGoal.from_json(g) for g in d["goals"])
            if not goals:
                raise ValueError("no goals")
            return SequenceEpisode(
                episode_id=str(d["episode_id"]),
                split=str(d["split"]),
                scene_seed=int(d["scene_seed"]),
                start_pose_world=Pose2D(float(x), float(y), float(yaw)),
                geodesic_distance_m=float(d["geodesic_distance_m"]),
                goals=goals,
                info=dict(d.get("info", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"malformed sequence {d.get('episode_id', '?')}: {exc}") from exc


@dataclass(frozen=True, slots=True)
class SequenceSet:
    directory: Path
    split: str
    seed: int
    episodes: tuple[SequenceEpisode, ...]
    meta: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def goal_image_path(self, episode: SequenceEpisode, goal_index: int) -> Path:
        return self.directory / episode.goals[goal_index].goal_image

    def load_goal_image(self, episode: SequenceEpisode, goal_index: int) -> np.ndarray:
        return read_rgb(self.goal_image_path(episode, goal_index))

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self):
        return iter(self.episodes)

    def by_id(self, episode_id: str) -> SequenceEpisode:
        for e in self.episodes:
            if e.episode_id == episode_id:
                return e
        raise KeyError(f"no sequence {episode_id!r} in {self.directory}")


def sequences_json_text(split: str, seed: int, episodes: list[SequenceEpisode], meta: dict[str, Any]) -> str:
    return set_json_text(FORMAT, FORMAT_VERSION, split, seed, episodes, meta)


def save_sequence_set(
    directory: str | Path, split: str, seed: int, episodes: list[SequenceEpisode], meta: dict[str, Any]
) -> Path:
    """Write DIR/episodes.json (goal PNGs are written by the generator as it goes)."""
    return write_set_json(directory, sequences_json_text(split, seed, episodes, meta))


def load_sequence_set(directory: str | Path) -> SequenceSet:
    """Read a multi-goal set written by ``imgnav episodes --goals N``."""
    directory = Path(directory)
    doc = read_set_doc(directory)
    path = directory / "episodes.json"
    if doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not an imgnav multi-goal set (format {doc.get('format')!r})")
    check_set_version(path, doc, "sequence-set", FORMAT_VERSION)
    episodes = tuple(SequenceEpisode.from_json(e) for e in doc["episodes"])
    meta = {k: v for k, v in doc.items() if k != "episodes"}
    return SequenceSet(directory, str(doc["split"]), int(doc["seed"]), episodes, meta)


def load_any_set(directory: str | Path) -> EpisodeSet | SequenceSet:
    """A single-goal ``EpisodeSet`` or a multi-goal ``SequenceSet``, whichever the directory holds."""
    directory = Path(directory)
    fmt = read_set_doc(directory).get("format")
    if fmt == FORMAT:
        return load_sequence_set(directory)
    if fmt != EPISODES_FORMAT:
        raise ValueError(f"{directory / 'episodes.json'}: neither an episode set nor a multi-goal set ({fmt!r})")
    return load_episode_set(directory)
