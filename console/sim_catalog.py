"""The simulator catalogue's types: homes, their start poses and gallery images.

A leaf module: ``console.sim_provider`` (the backend choice) and ``console.sim_adapter``
(the calls into ``sim/``) both use these types and neither imports the other for them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Start:
    id: str
    label: str
    pose_world: tuple[float, float, float]  # x_m, y_m, yaw_rad in the home frame


@dataclass(frozen=True, slots=True)
class GalleryItem:
    item: str  # "home-<seed>/i<instance>-v<view>"
    instance_id: int
    category: str
    room: str
    label: str
    file: str
    dhash: str  # 16 hex digits


@dataclass(frozen=True, slots=True)
class HomeEntry:
    id: str
    seed: int
    label: str
    rooms: int
    starts: tuple[Start, ...]
    gallery: tuple[GalleryItem, ...]

    @staticmethod
    def from_json(d: Mapping[str, Any]) -> HomeEntry:
        return HomeEntry(
            id=d["id"],
            seed=int(d["seed"]),
            label=d["label"],
            rooms=int(d["rooms"]),
            starts=tuple(Start(s["id"], s["label"], tuple(s["pose_world"])) for s in d["starts"]),
            gallery=tuple(GalleryItem(**g) for g in d["gallery"]),
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "seed": self.seed,
            "label": self.label,
            "rooms": self.rooms,
            "starts": [asdict(s) for s in self.starts],
            "gallery": [asdict(g) for g in self.gallery],
        }
