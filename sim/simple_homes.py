"""Hand-made tiny homes for tests and demos: one rectangular room, optional box objects.

    home = room_home(4.0, 3.0, objects=[box_object(0, "chair", (2.0, 1.5), (0.5, 0.5, 0.9))])
    world = SimWorld(home)

The room spans [0, width] x [0, depth] on the wall centre lines (walls 0.1 m thick,
2.5 m high), so the free floor is [0.05, width - 0.05] x [0.05, depth - 0.05].
"""

from __future__ import annotations

from sim.home import WALL_HEIGHT_M, WALL_THICKNESS_M, HomeSpec, Part, Room, SceneObject
from sim.textures import Material

_MATERIALS = {
    "wall": Material("paint", 1, 2.0),
    "floor": Material("planks", 2, 2.0),
    "ceiling": Material("plain", 0, 1.0, rgb=(236, 234, 228)),
    "fabric": Material("fabric", 3, 0.5),
    "wood": Material("wood", 4, 0.6),
}


def box_object(
    object_id: int,
    category: str,
    center_xy_m: tuple[float, float],
    size_xyz_m: tuple[float, float, float],
    yaw_rad: float = 0.0,
    material: str = "fabric",
    z0_m: float = 0.0,
) -> SceneObject:
    """A single-box object standing on the floor (or from ``z0_m`` up)."""
    cx, cy = center_xy_m
    part = Part("box", (cx, cy, z0_m + size_xyz_m[2] / 2.0), size_xyz_m, yaw_rad, material)
    return SceneObject(object_id, category, "box", 0, (cx, cy, yaw_rad), (part,))


def room_home(
    width_m: float = 4.0,
    depth_m: float = 4.0,
    objects: tuple[SceneObject, ...] | list[SceneObject] = (),
    seed: int = -1,
) -> HomeSpec:
    t, h = WALL_THICKNESS_M, WALL_HEIGHT_M
    walls = (
        Part("box", (width_m / 2, 0.0, h / 2), (width_m + t, t, h), 0.0, "wall"),
        Part("box", (width_m / 2, depth_m, h / 2), (width_m + t, t, h), 0.0, "wall"),
        Part("box", (0.0, depth_m / 2, h / 2), (t, depth_m + t, h), 0.0, "wall"),
        Part("box", (width_m, depth_m / 2, h / 2), (t, depth_m + t, h), 0.0, "wall"),
    )
    room = Room(0, "living room", "living room 1", (0.0, 0.0, width_m, depth_m), "floor")
    floor = Part("box", (width_m / 2, depth_m / 2, -0.01), (width_m, depth_m, 0.02), 0.0, "floor", solid=False)
    ceiling = Part(
        "box", (width_m / 2, depth_m / 2, h + 0.02), (width_m + 0.2, depth_m + 0.2, 0.04), 0.0, "ceiling", solid=False
    )
    objs = tuple(sorted(objects, key=lambda o: o.object_id))
    if [o.object_id for o in objs] != list(range(len(objs))):
        raise ValueError("object ids must be 0..N-1 (goal instances first)")
    return HomeSpec(
        seed=seed,
        rooms=(room,),
        doors=(),
        walls=walls,
        floors=(floor,),
        ceiling=ceiling,
        objects=objs,
        materials=dict(_MATERIALS),
        bounds_m=(0.0, 0.0, width_m, depth_m),
    )
