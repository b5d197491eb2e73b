"""Floor plans: rooms from a recursive split of the home's rectangle, doorways, walls.

3 to 8 rooms. From 5 rooms on, most homes get a hallway strip with rooms on both
sides (the common apartment layout); otherwise the rooms split the rectangle
directly. Doorways join the rooms along a spanning tree of the adjacency graph
that prefers public rooms (living room, hallway, kitchen), plus sometimes one
extra doorway or a wide opening between public rooms, so some homes have loops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.home import DOOR_HEIGHT_M, WALL_HEIGHT_M, WALL_THICKNESS_M, Door, Part

MIN_ROOM_SIDE_M = 2.4
MIN_SHARED_WALL_M = 1.4
PUBLIC_KINDS = ("living room", "hallway", "kitchen")


@dataclass(frozen=True, slots=True)
class RoomPlan:
    kind: str
    rect_m: tuple[float, float, float, float]


def _snap(v: float, step: float = 0.05) -> float:
    return round(round(v / step) * step, 6)


def _split(
    rng: np.random.Generator, rect: tuple[float, float, float, float], n: int
) -> list[tuple[float, float, float, float]]:
    if n == 1:
        return [rect]
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    along_x = w > h if abs(w / h - 1.0) > 0.25 else rng.uniform() < 0.5
    n1 = n // 2 if rng.uniform() < 0.5 else n - n // 2
    length = w if along_x else h
    cut = length * n1 / n * rng.uniform(0.88, 1.12)
    cut = min(max(cut, MIN_ROOM_SIDE_M * 1.0), length - MIN_ROOM_SIDE_M)
    if along_x:
        c = _snap(x0 + cut)
        return _split(rng, (x0, y0, c, y1), n1) + _split(rng, (c, y0, x1, y1), n - n1)
    c = _snap(y0 + cut)
    return _split(rng, (x0, y0, x1, c), n1) + _split(rng, (x0, c, x1, y1), n - n1)


def _ok(rects: list[tuple[float, float, float, float]]) -> bool:
    return all(
        min(r[2] - r[0], r[3] - r[1]) >= MIN_ROOM_SIDE_M - 1e-6 and max(r[2] - r[0], r[3] - r[1]) <= 7.5 for r in rects
    )


def _layout(rng: np.random.Generator, n_rooms: int) -> list[RoomPlan]:
    hallway = n_rooms >= 5 and rng.uniform() < 0.75
    k = n_rooms - (1 if hallway else 0)
    for _ in range(200):
        area = float(sum(rng.uniform(10.0, 18.0) for _ in range(k)))
        aspect = rng.uniform(1.0, 1.7)
        w = _snap(math.sqrt(area * aspect))
        h = _snap(area / w)
        if not hallway:
            rects = _split(rng, (0.0, 0.0, w, h), k)
            if _ok(rects):
                break
            continue
        hw = _snap(rng.uniform(1.35, 1.7))
        h_bottom = _snap(h * rng.uniform(0.4, 0.6))
        h_top = _snap(h - h_bottom)
        k_bottom = max(1, min(k - 1, int(round(k * h_bottom / h))))
        rects = _split(rng, (0.0, 0.0, w, h_bottom), k_bottom)
        rects += _split(rng, (0.0, _snap(h_bottom + hw), w, _snap(h_bottom + hw + h_top)), k - k_bottom)
        if _ok(rects):
            rects.append((0.0, h_bottom, w, _snap(h_bottom + hw)))
            break
    else:
        raise RuntimeError(f"no valid floor plan for {n_rooms} rooms")
    main = rects[:k]
    order = sorted(range(k), key=lambda i: -(main[i][2] - main[i][0]) * (main[i][3] - main[i][1]))
    kinds = [""] * k
    n_bath = 1 if k < 6 else 2
    kinds[order[0]] = "living room"
    for i in order[-n_bath:]:
        kinds[i] = "bathroom"
    rest = [i for i in order[1:-n_bath]]
    if k >= 4:
        kinds[rest.pop(0)] = "kitchen"
    for i in rest:
        kinds[i] = "bedroom"
    plans = [RoomPlan(kinds[i], main[i]) for i in range(k)]
    if hallway:
        plans.append(RoomPlan("hallway", rects[k]))
    return plans


def _shared_wall(
    a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> tuple[str, float, float, float] | None:
    """(axis, coord, start, end) of the wall two rooms share, or None."""
    eps = 1e-6
    for ax, c_a, c_b, lo, hi in (
        ("y", a[2], b[0], (a[1], b[1]), (a[3], b[3])),
        ("y", a[0], b[2], (a[1], b[1]), (a[3], b[3])),
        ("x", a[3], b[1], (a[0], b[0]), (a[2], b[2])),
        ("x", a[1], b[3], (a[0], b[0]), (a[2], b[2])),
    ):
        if abs(c_a - c_b) < eps:
            s, e = max(lo), min(hi)
            if e - s >= MIN_SHARED_WALL_M:
                return (ax, c_a, s, e)
    return None


def _doors(rng: np.random.Generator, plans: list[RoomPlan]) -> list[Door]:
    edges = []
    for i in range(len(plans)):
        for j in range(i + 1, len(plans)):
            wall = _shared_wall(plans[i].rect_m, plans[j].rect_m)
            if wall is None:
                continue
            pub = (plans[i].kind in PUBLIC_KINDS) + (plans[j].kind in PUBLIC_KINDS)
            weight = rng.uniform() + (0.0 if pub == 2 else 1.0 if pub == 1 else 3.0)
            if "hallway" in (plans[i].kind, plans[j].kind):
                weight -= 0.5
            edges.append((weight, i, j, wall))
    edges.sort(key=lambda e: e[0])
    parent = list(range(len(plans)))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    chosen, spare = [], []
    for e in edges:
        ra, rb = find(e[1]), find(e[2])
        if ra != rb:
            parent[ra] = rb
            chosen.append(e)
        else:
            spare.append(e)
    if len({find(i) for i in range(len(plans))}) != 1:
        raise RuntimeError("floor plan is not connected")
    public_spare = [e for e in spare if plans[e[1]].kind in PUBLIC_KINDS and plans[e[2]].kind in PUBLIC_KINDS]
    if public_spare and rng.uniform() < 0.5:
        chosen.append(public_spare[0])
    doors = []
    for _, i, j, (axis, coord, s, end) in chosen:
        both_public = plans[i].kind in PUBLIC_KINDS and plans[j].kind in PUBLIC_KINDS
        width = rng.uniform(1.2, 2.0) if both_public and rng.uniform() < 0.4 else rng.uniform(0.85, 1.0)
        width = min(width, end - s - 0.5)
        start = _snap(rng.uniform(s + 0.25, end - 0.25 - width))
        doors.append(Door(i, j, axis, coord, start, _snap(start + width)))
    return doors


def _walls(plans: list[RoomPlan], doors: list[Door], material: str) -> list[Part]:
    lines: dict[tuple[str, float], list[tuple[float, float]]] = {}
    for p in plans:
        x0, y0, x1, y1 = p.rect_m
        for key, iv in ((("x", y0), (x0, x1)), (("x", y1), (x0, x1)), (("y", x0), (y0, y1)), (("y", x1), (y0, y1))):
            lines.setdefault((key[0], round(key[1], 6)), []).append(iv)
    parts: list[Part] = []
    t = WALL_THICKNESS_M
    for (axis, coord), ivs in sorted(lines.items()):
        ivs.sort()
        merged = [list(ivs[0])]
        for s, e in ivs[1:]:
            if s <= merged[-1][1] + 1e-6:
                merged[-1][1] = max(merged[-1][1], e)
            else:
                merged.append([s, e])
        cuts = sorted((d.start_m, d.end_m) for d in doors if d.axis == axis and abs(d.coord_m - coord) < 1e-6)
        segments = []
        for s, e in merged:
            cur = s
            for cs, ce in cuts:
                if ce <= cur or cs >= e:
                    continue
                if cs > cur:
                    segments.append((cur, cs, 0.0, WALL_HEIGHT_M))
                segments.append((cs, ce, DOOR_HEIGHT_M, WALL_HEIGHT_M))  # lintel above the doorway
                cur = ce
            if cur < e:
                segments.append((cur, e, 0.0, WALL_HEIGHT_M))
        for s, e, z0, z1 in segments:
            ext = t / 2 if z0 == 0.0 else 0.0  # close the corners
            s2, e2 = s - ext if s in (m[0] for m in merged) else s, e + ext if e in (m[1] for m in merged) else e
            length, mid = e2 - s2, (s2 + e2) / 2
            center = (mid, coord, (z0 + z1) / 2) if axis == "x" else (coord, mid, (z0 + z1) / 2)
            size = (length, t, z1 - z0) if axis == "x" else (t, length, z1 - z0)
            parts.append(Part("box", center, size, 0.0, material))
    return parts


def generate_floorplan(
    rng: np.random.Generator, n_rooms: int, wall_material: str
) -> tuple[list[RoomPlan], list[Door], list[Part]]:
    plans = _layout(rng, n_rooms)
    doors = _doors(rng, plans)
    return plans, doors, _walls(plans, doors, wall_material)
