"""The data spec of a procedural home: pure data, no PyBullet (docs/architecture.md section 8).

``sim.scene_gen.generate_home(seed)`` produces a ``HomeSpec``; ``sim.world.SimWorld``
builds it in PyBullet. World frame: z up, metres, the floor at z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from agent.types import GOAL_CATEGORIES
from sim.geometry import CircleFootprint, Footprint, RectFootprint
from sim.textures import Material

WALL_THICKNESS_M = 0.1
WALL_HEIGHT_M = 2.5
DOOR_HEIGHT_M = 2.1
# Foliage meshes are jittered up to this factor beyond their nominal radius.
FOLIAGE_JITTER = 1.15


@dataclass(frozen=True, slots=True)
class Part:
    """One convex piece of an object, in the world frame.

    shape: ``box`` | ``cylinder`` (tapered by ``taper`` = top / bottom radius) | ``ellipsoid``.
    size_xyz_m: full extents before the yaw (a cylinder's diameter is ``size_xyz_m[0]``).
    material: key into ``HomeSpec.materials``; ``uv_mode`` ``world`` tiles it at its physical
    size, ``fit`` stretches it once over the +y face (pictures, screens).
    solid: whether it blocks the robot (rugs do not).
    """

    shape: str
    center_xyz_m: tuple[float, float, float]
    size_xyz_m: tuple[float, float, float]
    yaw_rad: float
    material: str
    uv_mode: str = "world"
    taper: float = 1.0
    solid: bool = True

    def footprint(self) -> Footprint:
        cx, cy, cz = self.center_xyz_m
        sx, sy, sz = self.size_xyz_m
        z0, z1 = cz - sz / 2.0, cz + sz / 2.0
        if self.shape == "box":
            return RectFootprint(cx, cy, sx / 2.0, sy / 2.0, self.yaw_rad, z0, z1)
        if self.shape == "cylinder":
            return CircleFootprint(cx, cy, max(sx, sy) / 2.0 * max(1.0, self.taper), z0, z1)
        if self.shape == "ellipsoid":
            return CircleFootprint(cx, cy, max(sx, sy) / 2.0 * FOLIAGE_JITTER, z0 * 1.0, z1)
        raise ValueError(f"unknown part shape {self.shape!r}")

    @property
    def top_z_m(self) -> float:
        return self.center_xyz_m[2] + self.size_xyz_m[2] / 2.0


@dataclass(frozen=True, slots=True)
class Room:
    """An axis-aligned room; ``rect_m`` = (x0, y0, x1, y1) on the wall centre lines."""

    index: int
    kind: str  # living room | kitchen | bedroom | bathroom | hallway
    name: str  # e.g. "bedroom 2"
    rect_m: tuple[float, float, float, float]
    floor_material: str

    @property
    def interior_m(self) -> tuple[float, float, float, float]:
        h = WALL_THICKNESS_M / 2.0
        x0, y0, x1, y1 = self.rect_m
        return (x0 + h, y0 + h, x1 - h, y1 - h)

    @property
    def center_xy_m(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.rect_m
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0)

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.interior_m
        return (x1 - x0) * (y1 - y0)

    def contains(self, x_m: float, y_m: float) -> bool:
        x0, y0, x1, y1 = self.rect_m
        return x0 <= x_m <= x1 and y0 <= y_m <= y1


@dataclass(frozen=True, slots=True)
class Door:
    """A doorway between two rooms in a wall along ``axis`` ("x": the wall runs along x at y = coord_m)."""

    room_a: int
    room_b: int
    axis: str
    coord_m: float
    start_m: float
    end_m: float

    @property
    def center_xy_m(self) -> tuple[float, float]:
        mid = (self.start_m + self.end_m) / 2.0
        return (mid, self.coord_m) if self.axis == "x" else (self.coord_m, mid)

    @property
    def width_m(self) -> float:
        return self.end_m - self.start_m


@dataclass(frozen=True, slots=True)
class SceneObject:
    """A furniture piece or clutter item: one PyBullet body.

    object_id: goal-category instances are numbered 0..N-1 (the instance ids of the
    segmentation); clutter continues after them. ``pose_xy_yaw`` is where its local
    origin (floor centre, front facing local +y) was placed.
    """

    object_id: int
    category: str
    variant: str
    room_index: int
    pose_xy_yaw: tuple[float, float, float]
    parts: tuple[Part, ...]

    @property
    def is_instance(self) -> bool:
        return self.category in GOAL_CATEGORIES

    def footprints(self) -> list[Footprint]:
        return [p.footprint() for p in self.parts]

    def bounds_xy_m(self) -> tuple[float, float, float, float]:
        bs = [fp.bounds() for fp in self.footprints()]
        return (min(b[0] for b in bs), min(b[1] for b in bs), max(b[2] for b in bs), max(b[3] for b in bs))

    def center_xyz_m(self) -> tuple[float, float, float]:
        """Centre of the parts' bounding box (the point goal cameras look at)."""
        x0, y0, x1, y1 = self.bounds_xy_m()
        z0 = min(p.center_xyz_m[2] - p.size_xyz_m[2] / 2 for p in self.parts)
        z1 = max(p.top_z_m for p in self.parts)
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0, (z0 + z1) / 2.0)


@dataclass(frozen=True, slots=True)
class HomeSpec:
    """A whole home. ``objects`` holds goal instances first (object_id == index), then clutter."""

    seed: int
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]
    walls: tuple[Part, ...]
    floors: tuple[Part, ...]
    ceiling: Part
    objects: tuple[SceneObject, ...]
    materials: dict[str, Material]
    bounds_m: tuple[float, float, float, float]

    @property
    def instances(self) -> tuple[SceneObject, ...]:
        return tuple(o for o in self.objects if o.is_instance)

    def instance(self, instance_id: int) -> SceneObject:
        obj = self.objects[instance_id]
        if not obj.is_instance or obj.object_id != instance_id:
            raise KeyError(f"no goal instance {instance_id} in home {self.seed}")
        return obj

    def room_at(self, x_m: float, y_m: float) -> Room | None:
        for room in self.rooms:
            if room.contains(x_m, y_m):
                return room
        return None

    def solid_footprints(self) -> list[Footprint]:
        out: list[Footprint] = [w.footprint() for w in self.walls if w.solid]
        for obj in self.objects:
            out += [p.footprint() for p in obj.parts if p.solid]
        return out


def yaw_to_quaternion(yaw_rad: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw_rad / 2.0), math.cos(yaw_rad / 2.0))
