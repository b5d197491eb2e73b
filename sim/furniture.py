"""Furniture and clutter shape variants, in the object's local frame.

Local frame: origin on the floor at the centre of the footprint, width along x,
depth along y, the front (where one sits, the screen side) facing +y. Parts
name a material *slot* (``fabric``, ``fabric2``, ``wood``, ``leaves``, ``pot``,
``ceramic``, ``plastic``, ``metal``, ``screen``, ``picture``, ``books``...) that
the scene generator fills with a per-instance material from the slot's family.

Each builder takes an RNG and returns ``(variant, parts)``; sizes are typical of
real furniture (seat 0.42-0.48 m, table 0.72-0.76 m, bed 0.45-0.6 m).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.home import Part


@dataclass(frozen=True, slots=True)
class LocalPart:
    shape: str
    center_xyz_m: tuple[float, float, float]
    size_xyz_m: tuple[float, float, float]
    slot: str
    yaw_rad: float = 0.0
    uv_mode: str = "world"
    taper: float = 1.0
    solid: bool = True


def _box(cx, cy, z0, sx, sy, sz, slot, **kw) -> LocalPart:
    """A box given by its centre in x, y and its bottom height z0."""
    return LocalPart("box", (cx, cy, z0 + sz / 2.0), (sx, sy, sz), slot, **kw)


def _cyl(cx, cy, z0, d, h, slot, taper=1.0) -> LocalPart:
    return LocalPart("cylinder", (cx, cy, z0 + h / 2.0), (d, d, h), slot, taper=taper)


def _legs(w, d, h, t, slot, inset=0.03) -> list[LocalPart]:
    xs, ys = w / 2 - inset - t / 2, d / 2 - inset - t / 2
    return [_box(sx * xs, sy * ys, 0.0, t, t, h, slot) for sx in (-1, 1) for sy in (-1, 1)]


def place(
    parts: list[LocalPart], pose_xy_yaw: tuple[float, float, float], materials: dict[str, str], z_offset_m: float = 0.0
) -> tuple[Part, ...]:
    """Local parts -> world ``Part``s at the pose, slots replaced by material keys."""
    x, y, yaw = pose_xy_yaw
    c, s = math.cos(yaw), math.sin(yaw)
    out = []
    for p in parts:
        lx, ly, lz = p.center_xyz_m
        out.append(
            Part(
                p.shape,
                (x + c * lx - s * ly, y + s * lx + c * ly, lz + z_offset_m),
                p.size_xyz_m,
                yaw + p.yaw_rad,
                materials[p.slot],
                p.uv_mode,
                p.taper,
                p.solid,
            )
        )
    return tuple(out)


# --- goal categories -------------------------------------------------------


def chair(rng: np.random.Generator) -> tuple[str, list[LocalPart]]:
    v = int(rng.integers(0, 4))
    seat_h = rng.uniform(0.42, 0.48)
    if v == 0:  # upholstered dining chair
        w, d = rng.uniform(0.42, 0.5), rng.uniform(0.45, 0.52)
        return "upholstered", _legs(w, d, seat_h - 0.06, 0.04, "wood") + [
            _box(0, 0, seat_h - 0.08, w, d, 0.1, "fabric"),
            _box(0, -d / 2 + 0.05, seat_h + 0.02, w, 0.08, rng.uniform(0.4, 0.5), "fabric"),
        ]
    if v == 1:  # wooden slat chair with a seat pad
        w, d = rng.uniform(0.4, 0.48), rng.uniform(0.42, 0.5)
        back_h = rng.uniform(0.4, 0.5)
        slats = [
            _box(x, -d / 2 + 0.03, seat_h, 0.05, 0.03, back_h, "wood")
            for x in np.linspace(-w / 2 + 0.04, w / 2 - 0.04, 4)
        ]
        return "slat", _legs(w, d, seat_h - 0.04, 0.04, "wood") + slats + [
            _box(0, 0, seat_h - 0.04, w, d, 0.04, "wood"),
            _box(0, 0.01, seat_h, w - 0.06, d - 0.08, 0.04, "fabric"),
            _box(0, -d / 2 + 0.03, seat_h + back_h - 0.06, w, 0.04, 0.08, "wood"),
        ]
    if v == 2:  # armchair
        w, d = rng.uniform(0.75, 0.9), rng.uniform(0.75, 0.9)
        arm = 0.15
        return "armchair", _legs(w, d, 0.1, 0.05, "wood") + [
            _box(0, 0, 0.1, w, d, seat_h - 0.1, "fabric"),
            _box(0, -d / 2 + 0.1, seat_h, w, 0.2, rng.uniform(0.4, 0.5), "fabric"),
            _box(-w / 2 + arm / 2, 0.05, seat_h, arm, d - 0.1, 0.2, "fabric"),
            _box(w / 2 - arm / 2, 0.05, seat_h, arm, d - 0.1, 0.2, "fabric"),
            _box(0, 0.05, seat_h, w - 2 * arm, d - 0.3, 0.08, "fabric2"),
        ]
    # office chair: pedestal and a round base
    w = rng.uniform(0.5, 0.6)
    return "office", [
        _cyl(0, 0, 0.0, w, 0.06, "metal"),
        _cyl(0, 0, 0.06, 0.06, seat_h - 0.14, "metal"),
        _box(0, 0, seat_h - 0.08, w, w, 0.1, "fabric"),
        _box(0, -w / 2 + 0.05, seat_h + 0.05, w * 0.9, 0.07, rng.uniform(0.45, 0.6), "fabric"),
    ]


def couch(rng: np.random.Generator) -> tuple[str, list[LocalPart]]:
    v = int(rng.integers(0, 3))
    seats = int(rng.integers(2, 4))
    w = seats * rng.uniform(0.6, 0.72) + 0.4
    d = rng.uniform(0.85, 1.0)
    seat_h = rng.uniform(0.4, 0.46)
    arm = 0.2
    parts = [
        _box(0, 0, 0.1, w, d, seat_h - 0.22, "fabric"),
        _box(0, -d / 2 + 0.12, 0.1, w, 0.24, rng.uniform(0.7, 0.8), "fabric"),
        _box(-w / 2 + arm / 2, 0.0, 0.1, arm, d, 0.5, "fabric"),
        _box(w / 2 - arm / 2, 0.0, 0.1, arm, d, 0.5, "fabric"),
    ]
    cw = (w - 2 * arm) / seats
    for k in range(seats):  # seat cushions
        parts.append(_box(-w / 2 + arm + cw * (k + 0.5), 0.1, seat_h - 0.12, cw - 0.02, d - 0.3, 0.14, "fabric"))
    for k in range(int(rng.integers(0, 3))):  # throw pillows
        parts.append(_box((-1) ** k * (w / 2 - arm - 0.25), -d / 2 + 0.3, seat_h + 0.02, 0.4, 0.12, 0.35, "fabric2"))
    if v == 0:
        parts += _legs(w, d, 0.1, 0.06, "wood")
        return f"{seats}-seat", parts
    if v == 1:  # wooden frame couch
        parts += _legs(w, d, 0.1, 0.06, "wood") + [_box(0, -d / 2 + 0.02, 0.1, w, 0.04, 0.8, "wood")]
        return f"{seats}-seat framed", parts
    # sectional: a chaise on the right
    chaise = rng.uniform(0.6, 0.8)
    parts += _legs(w, d, 0.1, 0.06, "wood") + [
        _box(w / 2 - arm - 0.35, d / 2 + chaise / 2 - 0.05, 0.0, 0.7, chaise, seat_h - 0.02, "fabric"),
    ]
    return f"{seats}-seat sectional", parts


def bed(rng: np.random.Generator) -> tuple[str, list[LocalPart]]:
    double = rng.uniform() < 0.65
    w = rng.uniform(1.4, 1.8) if double else rng.uniform(0.9, 1.1)
    length = rng.uniform(1.95, 2.15)
    h = rng.uniform(0.45, 0.6)
    # local front (+y) is the foot end; the headboard is at -y against the wall
    parts = [
        _box(0, 0, 0.0, w + 0.06, length, 0.25, "wood"),
        _box(0, 0.03, 0.25, w, length - 0.06, h - 0.25, "fabric"),
        _box(0, length * 0.17, h, w + 0.04, length * 0.62, 0.05, "fabric2"),
    ]
    n_pillows = 2 if double else 1
    for k in range(n_pillows):
        x = 0.0 if n_pillows == 1 else (k - 0.5) * w / 2
        parts.append(_box(x, -length / 2 + 0.3, h, w / n_pillows - 0.1, 0.4, 0.12, "fabric2"))
    v = int(rng.integers(0, 3))
    if v == 0:
        parts.append(_box(0, -length / 2 - 0.04, 0.0, w + 0.1, 0.08, rng.uniform(0.9, 1.2), "wood"))
        return ("double" if double else "single") + " wooden", parts
    if v == 1:
        parts.append(_box(0, -length / 2 - 0.06, 0.2, w + 0.1, 0.12, rng.uniform(0.8, 1.1), "fabric"))
        return ("double" if double else "single") + " upholstered", parts
    parts.append(_box(0, -length / 2 - 0.04, 0.0, w + 0.1, 0.08, rng.uniform(0.9, 1.1), "wood"))
    parts.append(_box(0, length / 2 + 0.04, 0.0, w + 0.1, 0.08, rng.uniform(0.5, 0.65), "wood"))
    return ("double" if double else "single") + " footboard", parts


def toilet(rng: np.random.Generator) -> tuple[str, list[LocalPart]]:
    # local -y is the wall side (tank)
    v = int(rng.integers(0, 3))
    tank_w = rng.uniform(0.36, 0.44)
    parts = [_box(0, -0.3, 0.0, tank_w, 0.18, 0.1, "ceramic"), _box(0, -0.3, 0.45, tank_w, 0.18, 0.35, "ceramic")]
    if v == 0:  # round bowl
        parts += [
            _cyl(0, 0.0, 0.0, 0.3, 0.4, "ceramic", taper=1.25),
            _cyl(0, 0.0, 0.4, 0.4, 0.04, "ceramic"),
            _box(0, -0.18, 0.1, 0.22, 0.12, 0.3, "ceramic"),
        ]
        name = "round"
    elif v == 1:  # square modern
        parts += [_box(0, -0.02, 0.0, 0.36, 0.5, 0.4, "ceramic"), _box(0, -0.02, 0.4, 0.38, 0.52, 0.04, "ceramic")]
        name = "square"
    else:  # seat with a fabric cover (a common real-world keypoint source)
        parts += [
            _cyl(0, 0.0, 0.0, 0.32, 0.4, "ceramic", taper=1.2),
            _box(0, -0.18, 0.1, 0.24, 0.12, 0.3, "ceramic"),
            _cyl(0, 0.0, 0.4, 0.42, 0.05, "fabric"),
        ]
        name = "covered"
    return name, parts


def potted_plant(rng: np.random.Generator) -> tuple[str, list[LocalPart]]:
    v = int(rng.integers(0, 3))
    pot_d = rng.uniform(0.28, 0.45)
    pot_h = rng.uniform(0.25, 0.45)
    parts = [_cyl(0, 0, 0.0, pot_d, pot_h, "pot", taper=rng.uniform(1.1, 1.3))]
    if v == 0:  # bush
        r = rng.uniform(0.3, 0.45)
        parts.append(
            LocalPart("ellipsoid", (0, 0, pot_h + r * 0.8), (2 * r, 2 * r, 2 * r * rng.uniform(0.9, 1.3)), "leaves")
        )
        return "bush", parts
    if v == 1:  # tall column plant
        r = rng.uniform(0.22, 0.32)
        hgt = rng.uniform(0.9, 1.3)
        parts.append(LocalPart("ellipsoid", (0, 0, pot_h + hgt / 2), (2 * r, 2 * r, hgt), "leaves"))
        return "column", parts
    # a tree: trunk and several foliage balls
    trunk_h = rng.uniform(0.6, 1.0)
    parts.append(_cyl(0, 0, pot_h, 0.05, trunk_h, "wood"))
    for _ in range(int(rng.integers(2, 5))):
        a = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(0.18, 0.28)
        off = rng.uniform(0.0, 0.15)
        parts.append(
            LocalPart(
                "ellipsoid",
                (off * math.cos(a), off * math.sin(a), pot_h + trunk_h + rng.uniform(-0.15, 0.25)),
                (2 * r, 2 * r, 2 * r),
                "leaves",
            )
        )
    return "tree", parts


def tv(rng: np.random.Generator, wall_mounted: bool) -> tuple[str, list[LocalPart]]:
    """A TV; its local origin is at the bottom of the TV (the caller lifts it onto a stand or the wall)."""
    w = rng.uniform(0.75, 1.45)
    h = w * 9 / 16
    depth = 0.06
    parts = [
        _box(0, 0, 0.04 if not wall_mounted else 0.0, w + 0.04, depth, h + 0.04, "plastic"),
        _box(0, depth / 2 + 0.004, (0.04 if not wall_mounted else 0.0) + 0.02, w, 0.01, h, "screen", uv_mode="fit"),
    ]
    if wall_mounted:
        return "wall-mounted", parts
    parts += [_box(0, 0, 0.0, w * 0.35, 0.2, 0.015, "plastic"), _box(0, -0.01, 0.015, 0.06, 0.04, 0.05, "plastic")]
    return "stand", parts


# --- clutter -----------------------------------------------------------------


def table(rng: np.random.Generator, w: float, d: float, h: float) -> list[LocalPart]:
    return _legs(w, d, h - 0.04, 0.05, "wood") + [_box(0, 0, h - 0.04, w, d, 0.04, "wood")]


def shelf(rng: np.random.Generator) -> list[LocalPart]:
    w, d, h = rng.uniform(0.6, 1.2), rng.uniform(0.3, 0.4), rng.uniform(0.8, 1.9)
    n = max(2, int(h / 0.35))
    parts = [
        _box(-w / 2 + 0.01, 0, 0, 0.02, d, h, "wood"),
        _box(w / 2 - 0.01, 0, 0, 0.02, d, h, "wood"),
        _box(0, -d / 2 + 0.01, 0, w, 0.02, h, "wood"),
    ]
    for k in range(n + 1):
        z = k * (h - 0.02) / n
        parts.append(_box(0, 0, z, w, d, 0.02, "wood"))
        if k < n:  # a row of books
            x = -w / 2 + 0.03
            while x < w / 2 - 0.12:
                bw = rng.uniform(0.03, 0.08)
                bh = rng.uniform(0.18, 0.3)
                parts.append(
                    _box(x + bw / 2, 0.0, z + 0.02, bw, d * 0.8, min(bh, (h - 0.02) / n - 0.04), "books", solid=True)
                )
                x += bw + rng.uniform(0.0, 0.06)
    return parts


def cabinet(rng: np.random.Generator, w: float, d: float, h: float, slot: str = "wood") -> list[LocalPart]:
    parts = [_box(0, 0, 0.05, w, d, h - 0.05, slot), _box(0, 0, 0, w - 0.06, d - 0.06, 0.05, "plastic")]
    n = max(1, int(round(w / 0.5)))
    for k in range(n):  # doors with handles
        x = -w / 2 + (k + 0.5) * w / n
        parts.append(_box(x, d / 2 + 0.005, 0.1, w / n - 0.02, 0.01, h - 0.15, slot))
        parts.append(_box(x + w / n / 2 - 0.06, d / 2 + 0.015, h * 0.6, 0.02, 0.02, 0.12, "metal"))
    return parts


def counter(rng: np.random.Generator, w: float) -> list[LocalPart]:
    parts = cabinet(rng, w, 0.6, 0.86)
    parts.append(_box(0, 0.01, 0.86, w + 0.02, 0.62, 0.04, "stone"))
    parts.append(_box(0, -0.29, 1.4, w, 0.35, 0.7, "wood"))  # wall cupboards
    return parts


def fridge(rng: np.random.Generator) -> list[LocalPart]:
    w = rng.uniform(0.6, 0.75)
    return [
        _box(0, 0, 0, w, 0.65, rng.uniform(1.7, 1.9), "metal"),
        _box(w / 2 - 0.08, 0.34, 0.9, 0.03, 0.04, 0.5, "plastic"),
    ]


def floor_lamp(rng: np.random.Generator) -> list[LocalPart]:
    h = rng.uniform(1.4, 1.7)
    return [
        _cyl(0, 0, 0, 0.3, 0.03, "metal"),
        _cyl(0, 0, 0.03, 0.03, h - 0.33, "metal"),
        _cyl(0, 0, h - 0.3, 0.4, 0.3, "fabric", taper=0.6),
    ]


def rug(rng: np.random.Generator, w: float, d: float) -> list[LocalPart]:
    return [_box(0, 0, 0.0, w, d, 0.012, "fabric", solid=False)]


def picture(rng: np.random.Generator, w: float, aspect: float) -> list[LocalPart]:
    """A framed picture; local origin at the bottom centre of the frame, the picture facing +y."""
    h = w * aspect
    t = rng.uniform(0.025, 0.05)
    return [_box(0, 0, 0, w + 2 * t, 0.03, h + 2 * t, "wood"), _box(0, 0.016, t, w, 0.004, h, "picture", uv_mode="fit")]


def vanity(rng: np.random.Generator) -> list[LocalPart]:
    w = rng.uniform(0.6, 1.0)
    parts = cabinet(rng, w, 0.45, 0.8)
    parts.append(_box(0, 0, 0.8, w, 0.47, 0.05, "ceramic"))
    parts.append(_box(0, -0.2, 1.1, w * 0.8, 0.02, 0.7, "mirror"))
    return parts


def bathtub(rng: np.random.Generator) -> list[LocalPart]:
    w, d = rng.uniform(1.5, 1.7), rng.uniform(0.7, 0.8)
    return [
        _box(0, -d / 2 + 0.04, 0, w, 0.08, 0.55, "ceramic"),
        _box(0, d / 2 - 0.04, 0, w, 0.08, 0.55, "ceramic"),
        _box(-w / 2 + 0.04, 0, 0, 0.08, d, 0.55, "ceramic"),
        _box(w / 2 - 0.04, 0, 0, 0.08, d, 0.55, "ceramic"),
        _box(0, 0, 0, w, d, 0.1, "ceramic"),
    ]


def wall_panel(w: float, h: float) -> list[LocalPart]:
    """Dark tiles behind a toilet: contrasting surroundings for a light fixture (docs/architecture.md section 8)."""
    return [_box(0, 0, 0, w, 0.02, h, "panel")]


GOAL_BUILDERS: dict[str, Callable[[np.random.Generator], tuple[str, list[LocalPart]]]] = {
    "chair": chair,
    "couch": couch,
    "bed": bed,
    "toilet": toilet,
    "potted plant": potted_plant,
}
