"""Placing furniture in one room without blocking it.

Every placement is checked against the room's walls, the doorway clearance zones
and the objects placed so far (axis-aligned bounds plus a gap), and then against
navigability: the robot must still reach every doorway of the room and nearly all
of its free floor (no room cut in two), and every goal instance in the room must
keep free floor within reach (its goal viewpoints live there). A placement that
breaks any of these is rejected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from sim.furniture import LocalPart, place
from sim.geometry import FootprintIndex
from sim.home import Door, Part, Room

GAP_M = 0.04
DOOR_CLEARANCE_DEPTH_M = 0.75
GRID_M = 0.05
# a goal instance needs this much reachable floor within this distance of it
APPROACH_RADIUS_M = 0.8
MIN_APPROACH_CELLS = 12
# share of the room's free floor that must stay reachable from its doorways
MIN_REACHABLE_SHARE = 0.85
PASSAGE_MARGIN_M = 0.1
_R = int(round(PASSAGE_MARGIN_M / GRID_M))
_DISC = np.hypot(*np.mgrid[-_R : _R + 1, -_R : _R + 1]) <= _R + 1e-9

Bounds = tuple[float, float, float, float]


def _bounds(parts: tuple[Part, ...], solid_only: bool = False) -> Bounds:
    bs = [p.footprint().bounds() for p in parts if p.solid or not solid_only]
    return (min(b[0] for b in bs), min(b[1] for b in bs), max(b[2] for b in bs), max(b[3] for b in bs))


def _overlap(a: Bounds, b: Bounds, gap: float = GAP_M) -> bool:
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


@dataclass(slots=True)
class Placed:
    category: str
    variant: str
    pose_xy_yaw: tuple[float, float, float]
    parts: tuple[Part, ...]
    bounds: Bounds
    top_z_m: float


@dataclass
class RoomPlacer:
    room: Room
    doors: list[Door]
    walls: list[Part]
    rng: np.random.Generator
    placed: list[Placed] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.interior = self.room.interior_m
        self.door_zones: list[Bounds] = []
        self.door_anchors: list[tuple[float, float]] = []
        x0, y0, x1, y1 = self.interior
        for d in self.doors:
            if d.axis == "x":  # wall along x at y = coord
                inward = 1.0 if abs(d.coord_m - self.room.rect_m[1]) < 1e-6 else -1.0
                depth = sorted([d.coord_m, d.coord_m + inward * DOOR_CLEARANCE_DEPTH_M])
                self.door_zones.append((d.start_m - 0.2, depth[0], d.end_m + 0.2, depth[1]))
                self.door_anchors.append(((d.start_m + d.end_m) / 2, d.coord_m + inward * 0.3))
            else:
                inward = 1.0 if abs(d.coord_m - self.room.rect_m[0]) < 1e-6 else -1.0
                depth = sorted([d.coord_m, d.coord_m + inward * DOOR_CLEARANCE_DEPTH_M])
                self.door_zones.append((depth[0], d.start_m - 0.2, depth[1], d.end_m + 0.2))
                self.door_anchors.append((d.coord_m + inward * 0.3, (d.start_m + d.end_m) / 2))
        m = 0.4
        self.check_bounds = (x0 - m, y0 - m, x1 + m, y1 + m)
        self.local_walls = [w for w in self.walls if _overlap(w.footprint().bounds(), self.check_bounds, 0.0)]

    # --- queries ---------------------------------------------------------

    def _navigable_ok(self, extra: tuple[Part, ...], instance_parts: list[tuple[Part, ...]]) -> bool:
        parts = (
            list(self.local_walls)
            + [p for pl in self.placed for p in pl.parts if p.solid]
            + [p for p in extra if p.solid]
        )
        index = FootprintIndex([p.footprint() for p in parts], self.check_bounds)
        grid = index.navigable_grid(GRID_M)
        # Connectivity through passages with PASSAGE_MARGIN_M to spare on each side: the robot's
        # discrete 0.25 m / 30 deg moves cannot thread a passage only a grid cell wide.
        core = ndimage.binary_erosion(grid.navigable, structure=_DISC)
        labels, _ = ndimage.label(core, structure=np.ones((3, 3), dtype=bool))
        anchor_ij = grid.xy_to_ij(np.array(self.door_anchors))
        ids = {int(labels[i, j]) for i, j in anchor_ij}
        if 0 in ids or len(ids) != 1:
            return False
        comp = ndimage.binary_dilation(labels == ids.pop(), structure=_DISC) & grid.navigable
        xs, ys = grid.cell_centres()
        x0, y0, x1, y1 = self.interior
        inside = grid.navigable & (xs > x0) & (xs < x1) & (ys > y0) & (ys < y1)
        if np.count_nonzero(comp & inside) < MIN_REACHABLE_SHARE * np.count_nonzero(inside):
            return False  # furniture must not cut the room in two
        for inst in instance_parts:
            d = np.full(grid.shape, np.inf)
            for p in inst:
                d = np.minimum(d, p.footprint().distance_grid(xs, ys))
            if int(np.count_nonzero(comp & (d <= APPROACH_RADIUS_M))) < MIN_APPROACH_CELLS:
                return False
        return True

    def fits(self, parts: tuple[Part, ...], ignore: tuple[int, ...] = (), on_wall_z_m: float | None = None) -> bool:
        """Geometric checks without navigability. ``on_wall_z_m``: a wall-hung item's bottom height."""
        b = _bounds(parts, solid_only=True) if any(p.solid for p in parts) else _bounds(parts)
        x0, y0, x1, y1 = self.interior
        if b[0] < x0 - 1e-6 or b[1] < y0 - 1e-6 or b[2] > x1 + 1e-6 or b[3] > y1 + 1e-6:
            return False
        solid = any(p.solid for p in parts)
        if solid and any(_overlap(b, z, 0.0) for z in self.door_zones):
            return False
        for k, pl in enumerate(self.placed):
            if k in ignore:
                continue
            if on_wall_z_m is not None:
                if pl.top_z_m > on_wall_z_m - 0.05 and _overlap(b, pl.bounds, 0.02):
                    return False
            elif solid and any(p.solid for p in pl.parts) and _overlap(b, _bounds(pl.parts, True), GAP_M):
                return False
            elif not solid and not any(p.solid for p in pl.parts) and _overlap(b, pl.bounds, 0.0):
                return False  # two rugs
        return True

    def add(
        self,
        category: str,
        variant: str,
        local: list[LocalPart],
        pose: tuple[float, float, float],
        materials: dict[str, str],
        is_instance: bool,
        z_offset_m: float = 0.0,
        ignore: tuple[int, ...] = (),
        on_wall_z_m: float | None = None,
    ) -> bool:
        parts = place(local, pose, materials, z_offset_m)
        if not self.fits(parts, ignore, on_wall_z_m):
            return False
        if any(p.solid for p in parts) and on_wall_z_m is None:
            instances = [pl.parts for pl in self.placed if pl.category in _INSTANCE_CATEGORIES]
            if is_instance:
                instances.append(parts)
            if not self._navigable_ok(parts, instances):
                return False
        self.placed.append(Placed(category, variant, pose, parts, _bounds(parts), max(p.top_z_m for p in parts)))
        return True

    # --- pose proposals ----------------------------------------------------

    def wall_pose(
        self, local: list[LocalPart], side: int | None = None, along: float | None = None
    ) -> tuple[float, float, float]:
        """A pose with the object's back (local -y) against a wall. side: 0 south, 1 east, 2 north, 3 west."""
        side = int(self.rng.integers(0, 4)) if side is None else side
        yaw = (0.0, math.pi / 2, math.pi, -math.pi / 2)[side]
        b = _bounds(place(local, (0.0, 0.0, yaw), {p.slot: "" for p in local}))
        x0, y0, x1, y1 = self.interior
        u = self.rng.uniform() if along is None else along
        g = 0.02
        if side in (0, 2):
            x = x0 - b[0] + u * max((x1 - x0) - (b[2] - b[0]), 0.0)
            y = y0 - b[1] + g if side == 0 else y1 - b[3] - g
        else:
            y = y0 - b[1] + u * max((y1 - y0) - (b[3] - b[1]), 0.0)
            x = x1 - b[2] - g if side == 1 else x0 - b[0] + g
        return (float(x), float(y), yaw)

    def free_pose(self, margin_m: float = 0.3, yaw: float | None = None) -> tuple[float, float, float]:
        x0, y0, x1, y1 = self.interior
        x = self.rng.uniform(x0 + margin_m, max(x1 - margin_m, x0 + margin_m + 1e-3))
        y = self.rng.uniform(y0 + margin_m, max(y1 - margin_m, y0 + margin_m + 1e-3))
        return (float(x), float(y), float(self.rng.uniform(-math.pi, math.pi) if yaw is None else yaw))

    def corner_pose(self, radius_m: float) -> tuple[float, float, float]:
        x0, y0, x1, y1 = self.interior
        cx = x0 + radius_m + 0.05 if self.rng.uniform() < 0.5 else x1 - radius_m - 0.05
        cy = y0 + radius_m + 0.05 if self.rng.uniform() < 0.5 else y1 - radius_m - 0.05
        return (float(cx), float(cy), float(self.rng.uniform(-math.pi, math.pi)))


_INSTANCE_CATEGORIES = ("chair", "couch", "bed", "toilet", "potted plant", "tv")
