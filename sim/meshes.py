"""Triangle meshes with world-scaled texture coordinates for furniture parts.

PyBullet's box primitive stretches one texture over each face whatever its size
(docs/architecture.md section 8), so a 2 m couch and a 0.4 m stool would show the same
pattern at different scales. These builders emit explicit meshes whose UVs are
the surface coordinates in metres divided by the texture's tile size, so a
texture has the same physical scale on every object. PyBullet's TinyRenderer
does not wrap texture coordinates (a UV beyond [0, 1] reads neighbouring texel
rows, which shows as stripes), so faces are cut at tile boundaries and every
cell gets UVs inside [0, 1]. ``uv_mode="fit"`` instead stretches the image once
over the front face (+y side of the part, before its yaw), for pictures and screens.

Meshes are flat-shaded: every face has its own vertices and normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True, eq=False)
class Mesh:
    """vertices (N, 3) float64 metres; normals (N, 3); uvs (N, 2); indices (M,) int32, 3 per triangle."""

    vertices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    indices: np.ndarray

    @staticmethod
    def merge(meshes: list[Mesh]) -> Mesh:
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.normals for m in meshes]),
            np.concatenate([m.uvs for m in meshes]),
            np.concatenate([m.indices + o for m, o in zip(meshes, offsets)]).astype(np.int32),
        )

    def transformed(self, center_xyz: tuple[float, float, float], yaw_rad: float) -> Mesh:
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return Mesh(self.vertices @ rot.T + np.asarray(center_xyz), self.normals @ rot.T, self.uvs, self.indices)


# Large faces are also cut into cells of at most this size (bounded triangle sizes keep
# the rasteriser's per-triangle work small and even).
MAX_CELL_M = 1.0
_UV_MAX = 0.999  # a UV of exactly 1.0 would address one texel past the edge


def _quads(corners: list[np.ndarray], normals: list[np.ndarray], uvs: list[np.ndarray]) -> Mesh:
    """Each entry: 4 corners (counter-clockwise seen from outside), one normal, 4 uvs."""
    n = len(corners)
    verts = np.concatenate(corners).reshape(-1, 3)
    norms = np.repeat(np.asarray(normals, dtype=np.float64).reshape(-1, 3), 4, axis=0)
    uv = np.clip(np.concatenate(uvs).reshape(-1, 2), 0.0, _UV_MAX)
    base = np.arange(n)[:, None] * 4
    idx = (base + np.array([0, 1, 2, 0, 2, 3])).reshape(-1).astype(np.int32)
    return Mesh(verts, norms, uv, idx)


def _cuts(start: float, length: float, tile: float, max_cell: float = math.inf) -> list[float]:
    """Cell boundaries of [start, start + length] at multiples of the tile, no cell longer than ``max_cell``."""
    end = start + length
    k0 = math.floor(start / tile + 1e-9) + 1
    bounds = [start]
    while tile * k0 < end - 1e-6:
        bounds.append(tile * k0)
        k0 += 1
    bounds.append(end)
    out = [start]
    for a, b in zip(bounds[:-1], bounds[1:]):
        n = max(1, int(math.ceil((b - a) / max_cell - 1e-9)))
        out += [a + (b - a) * k / n for k in range(1, n + 1)]
    return out


def _face(
    origin: np.ndarray,
    u_axis: np.ndarray,
    v_axis: np.ndarray,
    ul: float,
    vl: float,
    tile: float,
    normal,
    corners: list,
    normals: list,
    uvs: list,
    offset: tuple[float, float] = (0.0, 0.0),
    max_cell: float = math.inf,
) -> None:
    """A rectangle cut into tile cells, each with UVs inside [0, 1]; ``offset`` shifts the pattern (metres)."""
    us, vs = _cuts(offset[0], ul, tile, max_cell), _cuts(offset[1], vl, tile, max_cell)
    for u0, u1 in zip(us[:-1], us[1:]):
        for v0, v1 in zip(vs[:-1], vs[1:]):
            p = [
                origin + u_axis * (a - offset[0]) + v_axis * (b - offset[1])
                for a, b in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))
            ]
            corners.append(np.stack(p))
            normals.append(normal)
            fu, fv = math.floor(u0 / tile + 1e-9), math.floor(v0 / tile + 1e-9)
            uvs.append(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]) / tile - [fu, fv])


def box(
    size_xyz: tuple[float, float, float],
    tile_m: float,
    uv_mode: str = "world",
    uv_offset_m: tuple[float, float] = (0.0, 0.0),
    max_cell_m: float = MAX_CELL_M,
) -> Mesh:
    """An axis-aligned box centred at the origin; ``uv_offset_m`` shifts where the pattern starts."""
    hx, hy, hz = (s / 2.0 for s in size_xyz)
    sx, sy, sz = size_xyz
    # (normal, origin corner, u axis, v axis, u length, v length)
    faces = [
        ((1, 0, 0), (hx, -hy, -hz), (0, 1, 0), (0, 0, 1), sy, sz),
        ((-1, 0, 0), (-hx, hy, -hz), (0, -1, 0), (0, 0, 1), sy, sz),
        ((0, 1, 0), (hx, hy, -hz), (-1, 0, 0), (0, 0, 1), sx, sz),
        ((0, -1, 0), (-hx, -hy, -hz), (1, 0, 0), (0, 0, 1), sx, sz),
        ((0, 0, 1), (-hx, -hy, hz), (1, 0, 0), (0, 1, 0), sx, sy),
        ((0, 0, -1), (-hx, hy, -hz), (1, 0, 0), (0, -1, 0), sx, sy),
    ]
    corners: list = []
    normals: list = []
    uvs: list = []
    for k, (nrm, o_xyz, u_xyz, v_xyz, ul, vl) in enumerate(faces):
        o, ua, va = np.array(o_xyz, float), np.array(u_xyz, float), np.array(v_xyz, float)
        if uv_mode == "fit":
            # the +y face shows the whole image upright; the others a single texel
            corners.append(np.stack([o, o + ua * ul, o + ua * ul + va * vl, o + va * vl]))
            normals.append(nrm)
            uvs.append(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) if k == 2 else np.full((4, 2), 0.01))
        else:
            _face(o, ua, va, ul, vl, tile_m, nrm, corners, normals, uvs, uv_offset_m, max_cell_m)
    return _quads(corners, normals, uvs)


def cylinder(radius_m: float, height_m: float, tile_m: float, top_scale: float = 1.0, segments: int = 16) -> Mesh:
    """A (possibly tapered) cylinder along z centred at the origin; ``top_scale`` = top radius / bottom radius.

    Around the side, a whole number of segments spans one tile (the scale is rounded
    to that); up the side, rows are cut at tile boundaries."""
    hz = height_m / 2.0
    r0, r1 = radius_m, radius_m * top_scale
    ang = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    arc = 2.0 * math.pi * radius_m / segments
    per_tile = max(1, int(round(tile_m / arc)))
    slope = (r0 - r1) / height_m
    rows = [r - 0.0 for r in _cuts(0.0, height_m, tile_m)]
    corners, normals, uvs = [], [], []
    for k, (a, b) in enumerate(zip(ang[:-1], ang[1:])):
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        mid = (a + b) / 2.0
        nrm = np.array([math.cos(mid), math.sin(mid), slope])
        nrm /= np.linalg.norm(nrm)
        u0, u1 = (k % per_tile) / per_tile, (k % per_tile + 1) / per_tile
        for z0, z1 in zip(rows[:-1], rows[1:]):
            ra, rb = r0 + (r1 - r0) * z0 / height_m, r0 + (r1 - r0) * z1 / height_m
            corners.append(
                np.array(
                    [
                        [ca * ra, sa * ra, z0 - hz],
                        [cb * ra, sb * ra, z0 - hz],
                        [cb * rb, sb * rb, z1 - hz],
                        [ca * rb, sa * rb, z1 - hz],
                    ]
                )
            )
            normals.append(nrm)
            f = math.floor(z0 / tile_m + 1e-9)
            v0, v1 = z0 / tile_m - f, z1 / tile_m - f
            uvs.append(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]))
    side = _quads(corners, normals, uvs)
    caps = []
    for z, r, sign in ((hz, r1, 1.0), (-hz, r0, -1.0)):
        ring = np.stack([np.cos(ang[:-1]) * r, np.sin(ang[:-1]) * r, np.full(segments, z)], axis=1)
        verts = np.vstack([[0.0, 0.0, z], ring])
        tri = []
        for k in range(segments):
            a, b = 1 + k, 1 + (k + 1) % segments
            tri += [0, a, b] if sign > 0 else [0, b, a]
        scale = max(tile_m, 2.02 * r)
        caps.append(
            Mesh(
                verts,
                np.tile([0.0, 0.0, sign], (len(verts), 1)),
                np.clip(0.5 + verts[:, :2] / scale, 0.0, _UV_MAX),
                np.array(tri, np.int32),
            )
        )
    return Mesh.merge([side] + caps)


def ellipsoid(
    radii_xyz: tuple[float, float, float],
    tile_m: float,
    rings: int = 6,
    segments: int = 10,
    jitter: np.ndarray | None = None,
) -> Mesh:
    """A low-poly ellipsoid centred at the origin; ``jitter`` (rings+1, segments) scales radii for lumpy foliage.

    Every quad has its own vertices so its UVs can stay inside [0, 1] (a whole
    number of quads per tile in each direction)."""
    rx, ry, rz = radii_xyz
    theta = np.linspace(0.0, math.pi, rings + 1)  # from the top
    phi = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    scale = np.ones((rings + 1, segments + 1)) if jitter is None else np.concatenate([jitter, jitter[:, :1]], axis=1)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    pts = np.stack(
        [rx * st * np.cos(phi) * scale, ry * st * np.sin(phi) * scale, np.broadcast_to(rz * ct, scale.shape) * scale],
        axis=-1,
    )
    nrm = pts / np.maximum(np.array([rx, ry, rz]) ** 2, 1e-9)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12)
    mean_r = (rx + ry + rz) / 3.0
    mu = max(1, int(round(tile_m / (2 * math.pi * mean_r / segments))))
    mv = max(1, int(round(tile_m / (math.pi * mean_r / rings))))
    verts: list[np.ndarray] = []
    norms: list[np.ndarray] = []
    uvs: list[list[float]] = []
    tri: list[int] = []
    for i in range(rings):
        for j in range(segments):
            cells = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]  # counter-clockwise seen from outside
            u0, u1 = (j % mu) / mu, (j % mu + 1) / mu
            v0, v1 = (i % mv) / mv, (i % mv + 1) / mv
            base = len(verts)
            verts += [pts[a, b] for a, b in cells]
            norms += [nrm[a, b] for a, b in cells]
            uvs += [[u0, v0], [u0, v1], [u1, v1], [u1, v0]]
            tri += [base, base + 1, base + 2, base, base + 2, base + 3]
    return Mesh(np.array(verts), np.array(norms), np.clip(np.array(uvs), 0.0, _UV_MAX), np.array(tri, np.int32))
