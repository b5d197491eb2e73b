"""Room-to-room potential visibility, to skip drawing rooms a camera cannot see.

TinyRenderer has no occlusion culling: every front-facing triangle in the view
is rasterised even when a wall hides it, and a full-screen layer costs tens of
milliseconds. Walls are floor-to-ceiling except at doorways, so what one room
can see of the others is a 2D question: room B is potentially visible from room
A when a straight line from a point in A reaches B without crossing a wall.

``room_visibility`` answers it by casting dense fans of rays from a lattice of
points in each room; rooms that share a doorway are always included. A missed
sight line would show as a hole, so the sampling is generous and a test renders
many random views with and without culling and requires identical images.
"""

from __future__ import annotations

import math

import numpy as np

from sim.home import HomeSpec

POINT_SPACING_M = 0.25
DIRECTIONS = 240


def _slab(origins: np.ndarray, dirs: np.ndarray, rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances of rays (N) through axis-aligned rectangles (M, 4): two (N, M) arrays."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs  # (N, 2); inf where a component is 0
        tx0 = (rects[None, :, 0] - origins[:, None, 0]) * inv[:, None, 0]
        tx1 = (rects[None, :, 2] - origins[:, None, 0]) * inv[:, None, 0]
        ty0 = (rects[None, :, 1] - origins[:, None, 1]) * inv[:, None, 1]
        ty1 = (rects[None, :, 3] - origins[:, None, 1]) * inv[:, None, 1]
    # a ray parallel to an axis: inside the slab -> (-inf, inf), outside -> empty
    px = dirs[:, None, 0] == 0.0
    inside_x = (origins[:, None, 0] >= rects[None, :, 0]) & (origins[:, None, 0] <= rects[None, :, 2])
    tx0 = np.where(px, np.where(inside_x, -np.inf, np.inf), tx0)
    tx1 = np.where(px, np.where(inside_x, np.inf, -np.inf), tx1)
    py = dirs[:, None, 1] == 0.0
    inside_y = (origins[:, None, 1] >= rects[None, :, 1]) & (origins[:, None, 1] <= rects[None, :, 3])
    ty0 = np.where(py, np.where(inside_y, -np.inf, np.inf), ty0)
    ty1 = np.where(py, np.where(inside_y, np.inf, -np.inf), ty1)
    t_enter = np.maximum(np.minimum(tx0, tx1), np.minimum(ty0, ty1))
    t_exit = np.minimum(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
    return t_enter, t_exit


def room_visibility(home: HomeSpec) -> list[frozenset[int]]:
    """For each room index, the set of room indices potentially visible from inside it (itself included)."""
    walls = np.array([w.footprint().bounds() for w in home.walls if w.center_xyz_m[2] - w.size_xyz_m[2] / 2 < 0.01])
    rooms = np.array([r.rect_m for r in home.rooms], dtype=np.float64)
    ang = np.linspace(0.0, 2.0 * math.pi, DIRECTIONS, endpoint=False) + 1e-3
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    out: list[frozenset[int]] = []
    for room in home.rooms:
        seen = {room.index}
        for d in home.doors:
            if room.index in (d.room_a, d.room_b):
                seen |= {d.room_a, d.room_b}
        x0, y0, x1, y1 = room.interior_m
        xs = np.arange(x0 + 0.08, x1 - 0.08 + 1e-9, POINT_SPACING_M)
        ys = np.arange(y0 + 0.08, y1 - 0.08 + 1e-9, POINT_SPACING_M)
        # the lattice plus points along the room's edges (doorways are on the edges)
        edge = [(x, y) for x in (x0 + 0.06, x1 - 0.06) for y in ys] + [
            (x, y) for y in (y0 + 0.06, y1 - 0.06) for x in xs
        ]
        pts = np.concatenate([np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2), np.array(edge).reshape(-1, 2)])
        origins = np.repeat(pts, len(dirs), axis=0)
        rd = np.tile(dirs, (len(pts), 1))
        if len(walls):
            w_in, w_out = _slab(origins, rd, walls)
            hit = np.where((w_out >= np.maximum(w_in, 0.0)) & (w_out > 1e-9), np.maximum(w_in, 0.0), np.inf).min(axis=1)
        else:
            hit = np.full(len(origins), np.inf)
        r_in, r_out = _slab(origins, rd, rooms)
        # a room is seen when the ray is inside it somewhere before the first wall
        reach = (r_out >= np.maximum(r_in, 0.0)) & (np.maximum(r_in, 0.0) < hit[:, None])
        seen |= {int(k) for k in np.flatnonzero(reach.any(axis=0))}
        out.append(frozenset(seen))
    return out


class ViewCuller:
    """Per-view 2D visibility: rooms a camera's horizontal fan of rays reaches before a wall.

    ``visible_rooms`` casts about 1.5 rays per image column (plus a margin) over the
    azimuths the image covers; a room is visible when some ray
    is inside it before hitting a full-height wall. Vertical walls make this exact up to
    the ray spacing (a room seen only through a gap narrower than a pixel may be missed)."""

    def __init__(self, home: HomeSpec, margin_deg: float = 6.0) -> None:
        self.walls = np.array(
            [w.footprint().bounds() for w in home.walls if w.center_xyz_m[2] - w.size_xyz_m[2] / 2 < 0.01]
        )
        self.rooms = np.array([r.rect_m for r in home.rooms], dtype=np.float64)
        self.margin = math.radians(margin_deg)

    def visible_rooms(
        self,
        eye_xy: tuple[float, float],
        yaw_rad: float,
        pitch_rad: float,
        hfov_deg: float,
        vfov_deg: float,
        width_px: int,
    ) -> set[int]:
        """Rooms seen by a camera at ``eye_xy`` (yaw, pitch down) with this field of view."""
        # azimuth span of the image: the corners of a pitched camera reach wider than hfov / 2
        th, tv = math.tan(math.radians(hfov_deg) / 2), math.tan(math.radians(vfov_deg) / 2)
        cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
        half = 0.0
        for sv in (-1.0, 1.0):
            # camera frame: forward (cp, 0, -sp), up (sp, 0, cp), right (0, -1, 0) before the yaw
            fx = cp + sv * tv * sp
            if fx <= 1e-6:
                half = math.pi  # looking (nearly) straight up or down: all around
                break
            half = max(half, math.atan2(th, fx))
        half = min(half + self.margin, math.pi)
        n = max(32, int(1.5 * width_px * (2 * half) / math.radians(hfov_deg)))
        ang = yaw_rad + np.linspace(-half, half, n)
        dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
        origins = np.repeat(np.array([eye_xy], dtype=np.float64), n, axis=0)
        if len(self.walls):
            w_in, w_out = _slab(origins, dirs, self.walls)
            hit = np.where((w_out >= np.maximum(w_in, 0.0)) & (w_out > 1e-9), np.maximum(w_in, 0.0), np.inf).min(axis=1)
        else:
            hit = np.full(n, np.inf)
        r_in, r_out = _slab(origins, dirs, self.rooms)
        reach = (r_out >= np.maximum(r_in, 0.0)) & (np.maximum(r_in, 0.0) < hit[:, None])
        return {int(k) for k in np.flatnonzero(reach.any(axis=0))}
