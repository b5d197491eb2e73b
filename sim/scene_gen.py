"""Procedural homes from a seed: ``generate_home(seed) -> HomeSpec`` (pure data, no PyBullet).

A home has 3-8 rooms joined by doorways (``sim.floorplan``), room-specific floors,
furniture of the six goal categories in several shape variants (``sim.furniture``)
with per-instance textures from per-category families, same-category distractors
(dining chairs, several bedrooms and bathrooms, plants, TVs) that sometimes come
from one style and look alike (a set of dining chairs always does), and clutter: tables,
shelves, counters, rugs, lamps, framed pictures with natural images (1-3 per room).
Toilets sit on dark tiles in front of a dark panel (docs/architecture.md section 8).

Deterministic: the same seed gives the same spec on every run and machine
(``numpy.random.default_rng`` and plain float arithmetic only).
"""

from __future__ import annotations

import math

import numpy as np

from sim import furniture as F
from sim.floorplan import generate_floorplan
from sim.home import WALL_HEIGHT_M, HomeSpec, Part, Room, SceneObject
from sim.placement import RoomPlacer
from sim.textures import NATURAL_IMAGES, Material

GENERATOR_VERSION = 3

_SLOT_FAMILIES = {
    "fabric": ("fabric", 0.5),
    "fabric2": ("fabric", 0.4),
    "wood": ("wood", 0.6),
    "leaves": ("leaves", 0.4),
    "pot": ("terracotta", 0.5),
    "ceramic": ("ceramic", 0.5),
    "plastic": ("plastic", 0.5),
    "metal": ("metal", 0.5),
    "books": ("fabric", 0.3),
    "stone": ("carpet", 0.5),
    "mirror": ("metal", 1.0),
    "panel": ("darktiles", 0.8),
}


class _Materials:
    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.table: dict[str, Material] = {}
        self.images = list(rng.permutation(len(NATURAL_IMAGES)))

    def add(self, material: Material) -> str:
        self.table[material.key] = material
        return material.key

    def new(self, family: str, tile_m: float, **kw) -> str:
        return self.add(Material(family, int(self.rng.integers(0, 2**31 - 1)), tile_m, **kw))

    def image(self) -> str:
        """A natural image, cycling through all of them before repeating within a home."""
        if not self.images:
            self.images = list(self.rng.permutation(len(NATURAL_IMAGES)))
        return NATURAL_IMAGES[int(self.images.pop())]

    def slots(self, local: list[F.LocalPart], aspect: float = 0.5625, style: int | None = None) -> dict[str, str]:
        """A material per slot; with ``style`` the colours and pattern kinds are those of the style
        (a matching set) and only the layout of the features is the instance's own."""
        out: dict[str, str] = {}
        for p in local:
            if p.slot in out:
                continue
            if p.slot in ("screen", "picture"):
                out[p.slot] = self.new(p.slot, 1.0, image=self.image(), aspect=round(aspect, 4))
            else:
                fam, tile = _SLOT_FAMILIES[p.slot]
                slot_style = -1 if style is None else (style * 31 + sorted(_SLOT_FAMILIES).index(p.slot)) % (2**31 - 1)
                out[p.slot] = self.new(fam, tile, style=slot_style)
        return out


def _try(n: int, fn) -> bool:
    for _ in range(n):
        if fn():
            return True
    return False


class _Furnisher:
    """Room programmes: what a living room, kitchen, bedroom, bathroom and hallway contain."""

    def __init__(self, rng: np.random.Generator, mats: _Materials) -> None:
        self.rng, self.mats = rng, mats
        # Look-alike distractors, as in real homes: sometimes all of a home's toilets, plants,
        # chairs or beds come from one style (same colours and pattern kind, own layout).
        self.styles: dict[str, int] = {}
        for category, p in (("toilet", 0.7), ("potted plant", 0.5), ("chair", 0.35), ("bed", 0.3), ("couch", 0.3)):
            if rng.uniform() < p:
                self.styles[category] = int(rng.integers(0, 2**30))

    def item(
        self,
        pl: RoomPlacer,
        category: str,
        variant: str,
        local: list[F.LocalPart],
        pose_fn,
        tries: int = 25,
        is_instance: bool = False,
        style: int | None = None,
        **kw,
    ) -> bool:
        mats = self.mats.slots(local, style=style if style is not None else self.styles.get(category))
        return _try(tries, lambda: pl.add(category, variant, local, pose_fn(), mats, is_instance, **kw))

    def goal(self, pl: RoomPlacer, category: str, pose_fn, tries: int = 36, redraws: int = 3) -> bool:
        """Place a goal instance; ``pose_fn(local, attempt)`` proposes poses. The shape is
        drawn again a few times (a single bed fits where a double does not)."""
        per = tries // redraws
        for r in range(redraws):
            variant, local = F.GOAL_BUILDERS[category](self.rng)
            attempt = iter(range(r * per, (r + 1) * per))
            if self.item(pl, category, variant, local, lambda: pose_fn(local, next(attempt)), per, is_instance=True):
                return True
        return False

    def plant(self, pl: RoomPlacer) -> bool:
        return self.goal(
            pl, "potted plant", lambda local, k: pl.corner_pose(0.4) if self.rng.uniform() < 0.7 else pl.free_pose(0.4)
        )

    def tv(self, pl: RoomPlacer, side: int | None) -> bool:
        wall = self.rng.uniform() < 0.35
        variant, local = F.tv(self.rng, wall)
        mats = self.mats.slots(local)
        if wall:
            z = float(self.rng.uniform(1.0, 1.25))
            return _try(
                20,
                lambda: pl.add(
                    "tv", variant, local, pl.wall_pose(local, side), mats, True, z_offset_m=z, on_wall_z_m=z
                ),
            )
        stand = F.cabinet(self.rng, float(self.rng.uniform(1.2, 1.8)), 0.42, float(self.rng.uniform(0.45, 0.6)))
        stand_mats = self.mats.slots(stand)
        stand_h = max(p.center_xyz_m[2] + p.size_xyz_m[2] / 2 for p in stand)
        for _ in range(20):
            pose = pl.wall_pose(stand, side)
            if not pl.add("tv stand", "cabinet", stand, pose, stand_mats, False):
                continue
            k = len(pl.placed) - 1
            if pl.add("tv", variant, local, pose, mats, True, z_offset_m=stand_h, ignore=(k,)):
                return True
            pl.placed.pop()
        return False

    def pictures(self, pl: RoomPlacer, n: int) -> None:
        for _ in range(n):
            w = float(self.rng.uniform(0.4, 0.9))
            aspect = float(self.rng.choice([0.66, 0.75, 1.0, 1.33]))
            local = F.picture(self.rng, w, aspect)
            mats = self.mats.slots(local, aspect)
            z = float(self.rng.uniform(1.2, 1.5))
            _try(
                15,
                lambda: pl.add(
                    "picture", "framed", local, pl.wall_pose(local), mats, False, z_offset_m=z, on_wall_z_m=z
                ),
            )

    def rug(self, pl: RoomPlacer, around: tuple[float, float] | None = None) -> None:
        w, d = float(self.rng.uniform(1.4, 2.6)), float(self.rng.uniform(1.0, 1.8))
        local = F.rug(self.rng, w, d)
        pose_fn = (lambda: (around[0], around[1], 0.0)) if around else (lambda: pl.free_pose(w / 2, 0.0))
        self.item(pl, "rug", "rect", local, pose_fn, 10)

    def living_room(self, pl: RoomPlacer) -> None:
        side = int(self.rng.integers(0, 4))
        self.goal(pl, "couch", lambda local, k: pl.wall_pose(local, side if k < 12 else None))
        if self.rng.uniform() < 0.9:
            self.tv(pl, (side + 2) % 4)
        if pl.placed and pl.placed[0].category == "couch":
            x, y, yaw = pl.placed[0].pose_xy_yaw
            fx, fy = -math.sin(yaw), math.cos(yaw)
            w, d = float(self.rng.uniform(0.8, 1.2)), float(self.rng.uniform(0.5, 0.7))
            cx, cy = x + fx * 1.15, y + fy * 1.15
            if self.rng.uniform() < 0.7:
                self.rug(pl, (cx, cy))
            self.item(pl, "table", "coffee", F.table(self.rng, w, d, 0.42), lambda: (cx, cy, yaw), 1)
        if self.rng.uniform() < 0.4:
            self.goal(pl, "couch", lambda local, k: pl.wall_pose(local))
        for _ in range(int(self.rng.integers(0, 3))):
            self.goal(
                pl, "chair", lambda local, k: pl.free_pose(0.5) if self.rng.uniform() < 0.5 else pl.wall_pose(local)
            )
        for _ in range(int(self.rng.integers(1, 3))):
            self.plant(pl)
        if self.rng.uniform() < 0.6:
            shelf = F.shelf(self.rng)
            self.item(pl, "shelf", "bookcase", shelf, lambda: pl.wall_pose(shelf))
        if self.rng.uniform() < 0.6:
            self.item(pl, "lamp", "floor", F.floor_lamp(self.rng), lambda: pl.corner_pose(0.25))
        self.pictures(pl, int(self.rng.integers(1, 4)))

    def kitchen(self, pl: RoomPlacer) -> None:
        side = int(self.rng.integers(0, 4))
        x0, y0, x1, y1 = pl.interior
        length = (x1 - x0) if side in (0, 2) else (y1 - y0)
        cw = float(min(self.rng.uniform(1.5, 3.0), length - 0.4))
        counter = F.counter(self.rng, cw)
        self.item(pl, "counter", "kitchen", counter, lambda: pl.wall_pose(counter, side), 10)
        fr = F.fridge(self.rng)
        self.item(pl, "fridge", "fridge", fr, lambda: pl.wall_pose(fr), 15)
        tw, td = float(self.rng.uniform(1.0, 1.6)), float(self.rng.uniform(0.75, 0.95))
        table = F.table(self.rng, tw, td, 0.75)
        if self.item(
            pl, "table", "dining", table, lambda: pl.free_pose(1.0, float(self.rng.choice([0.0, math.pi / 2]))), 25
        ):
            tx, ty, tyaw = pl.placed[-1].pose_xy_yaw
            variant, chair_local = F.chair(self.rng)
            while variant in ("armchair",):
                variant, chair_local = F.chair(self.rng)
            o = 0.36
            seats = [
                (0.0, td / 2 + o, math.pi),
                (0.0, -td / 2 - o, 0.0),
                (tw / 2 + o, 0.0, math.pi / 2),
                (-tw / 2 - o, 0.0, -math.pi / 2),
            ]
            n = int(self.rng.integers(2, 5))
            set_style = self.styles.get("chair", int(self.rng.integers(0, 2**30)))  # a matching set
            for lx, ly, lyaw in seats[:n]:
                c, s = math.cos(tyaw), math.sin(tyaw)
                pose = (tx + c * lx - s * ly, ty + s * lx + c * ly, tyaw + lyaw)
                self.item(pl, "chair", variant, chair_local, lambda: pose, 1, is_instance=True, style=set_style)
        if self.rng.uniform() < 0.5:
            self.plant(pl)
        self.pictures(pl, int(self.rng.integers(1, 3)))

    def bedroom(self, pl: RoomPlacer) -> None:
        side = int(self.rng.integers(0, 4))
        if self.goal(pl, "bed", lambda local, k: pl.wall_pose(local, side if k < 8 else None)):
            bx, by, byaw = pl.placed[-1].pose_xy_yaw
            b = pl.placed[-1].bounds
            along_x = abs(math.sin(byaw)) < 0.5
            half_w = (b[2] - b[0]) / 2 if along_x else (b[3] - b[1]) / 2
            length = (b[3] - b[1]) if along_x else (b[2] - b[0])
            for sgn in (-1, 1):
                if self.rng.uniform() < 0.7:
                    ns = F.cabinet(self.rng, 0.45, 0.4, 0.55)
                    c, s = math.cos(byaw), math.sin(byaw)
                    lx, ly = sgn * (half_w + 0.3), -length / 2 + 0.22
                    pose = (bx + c * lx - s * ly, by + s * lx + c * ly, byaw)
                    self.item(pl, "nightstand", "cabinet", ns, lambda: pose, 1)
        if self.rng.uniform() < 0.6:
            wd = F.cabinet(self.rng, float(self.rng.uniform(1.0, 1.6)), 0.6, 2.0)
            self.item(pl, "wardrobe", "cabinet", wd, lambda: pl.wall_pose(wd))
        if self.rng.uniform() < 0.5:
            desk = F.table(self.rng, 1.1, 0.6, 0.75)
            if self.item(pl, "desk", "table", desk, lambda: pl.wall_pose(desk)):
                dx, dy, dyaw = pl.placed[-1].pose_xy_yaw
                pose = (dx - math.sin(dyaw) * 0.68, dy + math.cos(dyaw) * 0.68, dyaw + math.pi)
                variant, local = F.chair(self.rng)
                self.item(pl, "chair", variant, local, lambda: pose, 1, is_instance=True)
        if self.rng.uniform() < 0.4:
            self.tv(pl, (side + 2) % 4)
        if self.rng.uniform() < 0.5:
            self.plant(pl)
        if self.rng.uniform() < 0.5:
            self.rug(pl)
        self.pictures(pl, int(self.rng.integers(1, 3)))

    def bathroom(self, pl: RoomPlacer) -> None:
        side = int(self.rng.integers(0, 4))
        if self.goal(pl, "toilet", lambda local, k: pl.wall_pose(local, side if k < 8 else None)):
            tx, ty, tyaw = pl.placed[-1].pose_xy_yaw
            panel = F.wall_panel(float(self.rng.uniform(0.9, 1.3)), 1.3)
            b = pl.placed[-1].bounds
            back = 0.5 * ((b[3] - b[1]) if abs(math.sin(tyaw)) < 0.5 else (b[2] - b[0]))
            pose = (tx + math.sin(tyaw) * (back - 0.02), ty - math.cos(tyaw) * (back - 0.02), tyaw)
            self.item(pl, "panel", "tiles", panel, lambda: pose, 1, ignore=(len(pl.placed) - 1,), on_wall_z_m=0.0)
        vanity = F.vanity(self.rng)
        self.item(pl, "vanity", "sink", vanity, lambda: pl.wall_pose(vanity))
        if pl.room.area_m2 > 7.0 and self.rng.uniform() < 0.7:
            tub = F.bathtub(self.rng)
            self.item(pl, "bathtub", "tub", tub, lambda: pl.wall_pose(tub))
        if self.rng.uniform() < 0.3:
            self.plant(pl)
        self.pictures(pl, int(self.rng.integers(0, 2)))

    def hallway(self, pl: RoomPlacer) -> None:
        for _ in range(int(self.rng.integers(0, 3))):
            self.plant(pl)
        if self.rng.uniform() < 0.5:
            self.goal(pl, "chair", lambda local, k: pl.wall_pose(local))
        if self.rng.uniform() < 0.5:
            sh = F.cabinet(self.rng, float(self.rng.uniform(0.8, 1.2)), 0.35, 0.8)
            self.item(pl, "console", "cabinet", sh, lambda: pl.wall_pose(sh))
        self.pictures(pl, int(self.rng.integers(1, 4)))


_FLOORS = {
    "living room": ("planks", 2.0),
    "bedroom": ("planks", 2.0),
    "hallway": ("planks", 2.0),
    "kitchen": ("tiles", 1.5),
    "bathroom": ("darktiles", 1.2),
}


def generate_home(seed: int, n_rooms: int | None = None) -> HomeSpec:
    """The home of ``seed`` (3-8 rooms unless ``n_rooms`` is given)."""
    rng = np.random.default_rng([int(seed), GENERATOR_VERSION, 7919])
    mats = _Materials(rng)
    n_rooms = int(rng.integers(3, 9)) if n_rooms is None else n_rooms
    wall_mat = mats.new("paint", 2.0)
    plans, doors, walls = generate_floorplan(rng, n_rooms, wall_mat)
    counts: dict[str, int] = {}
    rooms = []
    for k, plan in enumerate(plans):
        counts[plan.kind] = counts.get(plan.kind, 0) + 1
        fam, tile = _FLOORS[plan.kind]
        if plan.kind == "bedroom" and rng.uniform() < 0.3:
            fam, tile = "carpet", 1.0
        rooms.append(Room(k, plan.kind, f"{plan.kind} {counts[plan.kind]}", plan.rect_m, mats.new(fam, tile)))
    floors = [
        Part(
            "box",
            ((r.rect_m[0] + r.rect_m[2]) / 2, (r.rect_m[1] + r.rect_m[3]) / 2, -0.01),
            (r.rect_m[2] - r.rect_m[0], r.rect_m[3] - r.rect_m[1], 0.02),
            0.0,
            r.floor_material,
            solid=False,
        )
        for r in rooms
    ]
    xmax = max(r.rect_m[2] for r in rooms)
    ymax = max(r.rect_m[3] for r in rooms)
    ceiling_mat = mats.add(Material("plain", 0, 1.0, rgb=(236, 234, 228)))
    ceiling = Part(
        "box", (xmax / 2, ymax / 2, WALL_HEIGHT_M + 0.02), (xmax + 0.2, ymax + 0.2, 0.04), 0.0, ceiling_mat, solid=False
    )
    furnisher = _Furnisher(rng, mats)
    placed = []
    for room in rooms:
        room_doors = [d for d in doors if room.index in (d.room_a, d.room_b)]
        pl = RoomPlacer(room, room_doors, walls, rng)
        getattr(furnisher, room.kind.replace(" ", "_"))(pl)
        placed += [(room.index, p) for p in pl.placed]
    instances = [(ri, p) for ri, p in placed if p.category in F.GOAL_BUILDERS or p.category == "tv"]
    clutter = [(ri, p) for ri, p in placed if not (p.category in F.GOAL_BUILDERS or p.category == "tv")]
    objects = tuple(
        SceneObject(k, p.category, p.variant, ri, p.pose_xy_yaw, p.parts)
        for k, (ri, p) in enumerate(instances + clutter)
    )
    used = {p.material for o in objects for p in o.parts} | {p.material for p in walls + floors} | {ceiling.material}
    return HomeSpec(
        seed=int(seed),
        rooms=tuple(rooms),
        doors=tuple(doors),
        walls=tuple(walls),
        floors=tuple(floors),
        ceiling=ceiling,
        objects=objects,
        materials={k: v for k, v in mats.table.items() if k in used},
        bounds_m=(0.0, 0.0, xmax, ymax),
    )
