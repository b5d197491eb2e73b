"""InstanceImageNav episodes and episode-set files.

An episode set is a directory::

    DIR/episodes.json        {"format": "imgnav-episodes", "version": 1, "split", "seed", ..., "episodes": [...]}
    DIR/goals/<episode_id>.png   the 512x512 goal image (RGB PNG)

Positions are in the world frame of the episode's home (``SimWorld.from_seed(scene_seed)``),
metres and radians, rounded to 0.1 mm / 1e-4 rad so the JSON is byte-stable; the
simulator and the metrics use exactly the stored (rounded) values.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from agent.types import Pose2D

FORMAT = "imgnav-episodes"
FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")
# Disjoint scene-seed ranges per split: scene_seed = base + set_seed * SCENES_PER_SET + k.
SPLIT_SCENE_BASE = {"train": 0, "val": 100_000_000, "test": 200_000_000}
SCENES_PER_SET = 10_000
_DIGITS = 4


def scene_seed_for(split: str, set_seed: int, k: int) -> int:
    if split not in SPLIT_SCENE_BASE:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    if not 0 <= k < SCENES_PER_SET or not 0 <= set_seed < SPLIT_SCENE_BASE["val"] // SCENES_PER_SET:
        raise ValueError(f"scene index {k} or set seed {set_seed} out of range")
    return SPLIT_SCENE_BASE[split] + set_seed * SCENES_PER_SET + k


def split_of_scene(scene_seed: int) -> str:
    for split in reversed(SPLITS):
        if scene_seed >= SPLIT_SCENE_BASE[split]:
            return split
    raise ValueError(f"negative scene seed {scene_seed}")


def r4(v: float) -> float:
    """Round for storage (0.1 mm, 1e-4 rad); -0.0 becomes 0.0 so the JSON is stable."""
    out = round(float(v), _DIGITS)
    return out + 0.0


@dataclass(frozen=True, slots=True)
class Episode:
    """One episode (docs/architecture.md section 1).

    start_pose_world: the robot's start in the home's world frame. viewpoints_xy_m: world xy of the goal viewpoints.
    geodesic_distance_m: fast-marching shortest path from the start to the nearest viewpoint.
    goal_image: path of the PNG relative to the episode-set directory.
    info: extra facts (rooms, difficulty, goal camera, ...), JSON-able.
    """

    episode_id: str
    split: str
    scene_seed: int
    start_pose_world: Pose2D
    goal_instance_id: int
    goal_category: str
    goal_image: str
    viewpoints_xy_m: tuple[tuple[float, float], ...]
    geodesic_distance_m: float
    info: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    @property
    def id(self) -> str:
        """Alias of ``episode_id``."""
        return self.episode_id

    def viewpoints_array(self) -> np.ndarray:
        """(N, 2) float64 world xy."""
        return np.asarray(self.viewpoints_xy_m, dtype=np.float64).reshape(-1, 2)

    def to_json(self) -> dict[str, Any]:
        return {
            "episode_id": self.episode_id,
            "split": self.split,
            "scene_seed": self.scene_seed,
            "start_pose_world": [
                r4(self.start_pose_world.x_m),
                r4(self.start_pose_world.y_m),
                r4(self.start_pose_world.yaw_rad),
            ],
            "goal_instance_id": self.goal_instance_id,
            "goal_category": self.goal_category,
            "goal_image": self.goal_image,
            "geodesic_distance_m": r4(self.geodesic_distance_m),
            "viewpoints_xy_m": [[r4(x), r4(y)] for x, y in self.viewpoints_xy_m],
            "info": self.info,
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> Episode:
        try:
            x, y, yaw = d["start_pose_world"]
            return Episode(
                episode_id=str(d["episode_id"]),
                split=str(d["split"]),
                scene_seed=int(d["scene_seed"]),
                start_pose_world=Pose2D(float(x), float(y), float(yaw)),
                goal_instance_id=int(d["goal_instance_id"]),
                goal_category=str(d["goal_category"]),
                goal_image=str(d["goal_image"]),
                viewpoints_xy_m=tuple((float(a), float(b)) for a, b in d["viewpoints_xy_m"]),
                geodesic_distance_m=float(d["geodesic_distance_m"]),
                info=dict(d.get("info", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"malformed episode {d.get('episode_id', '?')}: {exc}") from exc


@dataclass(frozen=True, slots=True)
class EpisodeSet:
    directory: Path
    split: str
    seed: int
    episodes: tuple[Episode, ...]
    meta: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def goal_image_path(self, episode: Episode) -> Path:
        return self.directory / episode.goal_image

    def load_goal_image(self, episode: Episode) -> np.ndarray:
        return read_rgb(self.goal_image_path(episode))

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self):
        return iter(self.episodes)

    def by_id(self, episode_id: str) -> Episode:
        for e in self.episodes:
            if e.episode_id == episode_id:
                return e
        raise KeyError(f"no episode {episode_id!r} in {self.directory}")


def read_rgb(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB from an image file."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def write_rgb(path: str | Path, rgb: np.ndarray) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write image {path}")


def set_json_text(fmt: str, version: int, split: str, seed: int, items: Any, meta: dict[str, Any]) -> str:
    """The ``episodes.json`` text of a set (single-goal episodes or multi-goal sequences)."""
    doc = {
        "format": fmt,
        "version": version,
        "split": split,
        "seed": seed,
        **meta,
        "episodes": [e.to_json() for e in items],
    }
    return json.dumps(doc, indent=1, sort_keys=False) + "\n"


def write_set_json(directory: str | Path, text: str) -> Path:
    """Write DIR/episodes.json atomically (goal PNGs are written by the generator as it goes)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "episodes.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def read_set_doc(directory: Path) -> dict[str, Any]:
    """DIR/episodes.json as written by ``imgnav episodes`` (any format)."""
    path = directory / "episodes.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{path} not found: not an episode set (create one with `imgnav episodes`)") from exc


def check_set_version(path: Path, doc: dict[str, Any], what: str, version: int) -> None:
    if doc.get("version") != version:
        raise ValueError(f"{path}: {what} version {doc.get('version')} is not supported (expected {version})")


def episodes_json_text(
    split: str, seed: int, episodes: list[Episode] | tuple[Episode, ...], meta: dict[str, Any]
) -> str:
    return set_json_text(FORMAT, FORMAT_VERSION, split, seed, episodes, meta)


def save_episode_set(
    directory: str | Path, split: str, seed: int, episodes: list[Episode], meta: dict[str, Any]
) -> Path:
    """Write DIR/episodes.json (goal PNGs are written by the generator as it goes)."""
    return write_set_json(directory, episodes_json_text(split, seed, episodes, meta))


def load_episode_set(directory: str | Path) -> EpisodeSet:
    """Read an episode set written by ``imgnav episodes``."""
    directory = Path(directory)
    path = directory / "episodes.json"
    doc = read_set_doc(directory)
    if doc.get("format") == "imgnav-sequences":
        raise ValueError(f"{path}: a multi-goal set (imgnav episodes --goals N): read it with sim.sequences")
    if doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not an imgnav episode set (format {doc.get('format')!r})")
    check_set_version(path, doc, "episode-set", FORMAT_VERSION)
    episodes = tuple(Episode.from_json(e) for e in doc["episodes"])
    meta = {k: v for k, v in doc.items() if k not in ("episodes",)}
    return EpisodeSet(directory, str(doc["split"]), int(doc["seed"]), episodes, meta)
