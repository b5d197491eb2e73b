"""Procedural, deterministic, seamlessly tiling textures (docs/architecture.md section 8).

Texture decides re-identification difficulty: flat colours make keypoint re-ID
fall to category level, so every instance gets its own texture drawn from a
per-category family (fabric for seats and bedding, wood for frames, leaves for
plants, tinted ceramic for toilets) with features of 2-10 cm at the family's
tile size. Pictures and TV screens show natural images from ``skimage.data``.

A texture is a pure function of its ``Material``; PNGs are cached on disk
(PyBullet loads textures from files) under ``IMGNAV_CACHE_DIR`` (default
``~/.cache/imgnav``), keyed by the material and ``TEXTURE_VERSION``.
"""

from __future__ import annotations

import colorsys
import hashlib
import json
import logging
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

TEXTURE_VERSION = 2
TEX_PX = 256

# Natural images that ship with scikit-image (no download): (loader name, is colour)
NATURAL_IMAGES: tuple[str, ...] = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "hubble_deep_field",
    "retina",
    "immunohistochemistry",
    "motorcycle",
    "colorwheel",
    "camera",
    "moon",
    "horse_photo",
    "page",
    "brick",
    "grass",
    "gravel",
)


@dataclass(frozen=True, slots=True)
class Material:
    """A texture recipe. ``family`` picks the generator; ``tile_m`` is the texture's physical size.

    family: fabric | wood | leaves | ceramic | plastic | paint | planks | tiles | darktiles | carpet |
            terracotta | metal | picture | screen | plain
    image: a ``NATURAL_IMAGES`` name for pictures and screens.
    aspect: the canvas height / width for pictures and screens.
    style: materials sharing a style look alike (a set of dining chairs, a home's toilets)
    but differ in the layout of their features, like similar real objects.
    rgb: base colour for ``plain`` (0-255).
    """

    family: str
    seed: int
    tile_m: float = 0.5
    image: str = ""
    rgb: tuple[int, int, int] = (200, 200, 200)
    aspect: float = 0.75  # height / width of a picture or screen (the crop keeps it: no distortion)
    style: int = -1  # >= 0: colours and pattern kind come from this seed, the layout from ``seed``

    @property
    def key(self) -> str:
        blob = json.dumps(asdict(self), sort_keys=True) + f"/v{TEXTURE_VERSION}"
        return f"{self.family}-{hashlib.sha1(blob.encode()).hexdigest()[:16]}"


def cache_dir() -> Path:
    root = Path(os.environ.get("IMGNAV_CACHE_DIR", Path.home() / ".cache" / "imgnav"))
    return root / "textures"


def texture_path(material: Material) -> Path:
    """The PNG of ``material``, generated and cached on first use (atomic write, safe across processes)."""
    path = cache_dir() / f"{material.key}.png"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        rgb = generate(material)
        fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
        os.close(fd)
        if not cv2.imwrite(tmp, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write texture {tmp}")
        os.replace(tmp, path)
    return path


def generate(material: Material) -> np.ndarray:
    """(TEX_PX, TEX_PX, 3) uint8 RGB (pictures keep their aspect: (h, w, 3))."""
    fam = _FAMILY_IDS[material.family]
    rng = np.random.default_rng([material.seed, fam])
    srng = np.random.default_rng([material.style, fam, 99] if material.style >= 0 else [material.seed, fam, 98])
    img = _GENERATORS[material.family](rng, material, srng)
    return np.clip(img, 0, 255).astype(np.uint8)


# --- building blocks -------------------------------------------------------


def _noise(rng: np.random.Generator, cells: int, size: int = TEX_PX) -> np.ndarray:
    """Seamless value noise in [-1, 1] with ``cells`` features per tile, (size, size) float32."""
    grid = rng.uniform(-1.0, 1.0, (cells, cells)).astype(np.float32)
    big = cv2.resize(np.tile(grid, (3, 3)), (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
    return big[size : 2 * size, size : 2 * size]


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb(h % 1.0, min(max(s, 0), 1), min(max(v, 0), 1))) * 255.0


def _shade(img: np.ndarray, amount: np.ndarray | float) -> np.ndarray:
    return img * (1.0 + np.asarray(amount, dtype=np.float32))[..., None]


def _wrapped(draw, size: int = TEX_PX) -> None:
    """Call ``draw(dx, dy)`` for the 9 offsets so shapes crossing an edge wrap around."""
    for dy in (-size, 0, size):
        for dx in (-size, 0, size):
            draw(dx, dy)


def _palette(rng: np.random.Generator, n: int, sat: tuple[float, float] = (0.3, 0.8)) -> list[np.ndarray]:
    h = rng.uniform()
    out = []
    for _ in range(n):
        h = h + rng.uniform(0.08, 0.5)
        out.append(_hsv(h, rng.uniform(*sat), rng.uniform(0.3, 0.95)))
    return out


# --- families ----------------------------------------------------------------


def _fabric(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX
    cols = _palette(srng, 3)
    img = np.ones((s, s, 3), np.float32) * cols[0]
    yy, xx = np.mgrid[0:s, 0:s]
    kind = srng.integers(0, 6)
    if kind == 0:  # stripes
        k = max(2, int(srng.integers(3, 12)) + int(rng.integers(-1, 2)))
        band = np.sin(2 * math.pi * k * (yy if srng.uniform() < 0.5 else xx) / s) > rng.uniform(-0.5, 0.5)
        img[band] = cols[1]
    elif kind == 1:  # plaid
        k1, k2 = int(srng.integers(2, 7)) + int(rng.integers(0, 2)), int(srng.integers(2, 7)) + int(rng.integers(0, 2))
        a = np.sin(2 * math.pi * k1 * xx / s) > 0.3
        b = np.sin(2 * math.pi * k2 * yy / s) > 0.3
        img[a] = img[a] * 0.5 + cols[1] * 0.5
        img[b] = img[b] * 0.5 + cols[2] * 0.5
    elif kind == 2:  # polka dots on a jittered lattice
        k = int(srng.integers(3, 8))
        r = int(s / k * srng.uniform(0.15, 0.35))
        for gi in range(k):
            for gj in range(k):
                cx = int((gj + 0.5 + 0.5 * (gi % 2)) * s / k + rng.normal(0, 2))
                cy = int((gi + 0.5) * s / k + rng.normal(0, 2))
                col = tuple(float(c) for c in (cols[1] if rng.uniform() < 0.8 else cols[2]))
                _wrapped(lambda dx, dy: cv2.circle(img, (cx + dx, cy + dy), r, col, -1, cv2.LINE_AA))
    elif kind == 3:  # floral blobs
        for _ in range(int(rng.integers(15, 40))):
            cx, cy = int(rng.integers(0, s)), int(rng.integers(0, s))
            ax = (int(rng.integers(5, 25)), int(rng.integers(5, 25)))
            ang = float(rng.uniform(0, 180))
            col = tuple(float(c) for c in cols[int(rng.integers(1, 3))])
            _wrapped(lambda dx, dy: cv2.ellipse(img, (cx + dx, cy + dy), ax, ang, 0, 360, col, -1, cv2.LINE_AA))
    elif kind == 4:  # chevrons
        k = int(srng.integers(2, 6))
        amp = s / k / 2
        band = ((yy + amp * np.abs(((xx * k * 2 / s) % 2) - 1)) * k * 2 / s).astype(int) % 2 == 0
        img[band] = cols[1]
    else:  # heathered solid with slubs
        img = _shade(img, 0.25 * _noise(rng, 12) + 0.15 * _noise(rng, 40))
    # the instance's own marks (embroidery, wear, a stain): what tells a matching set apart
    for _ in range(int(rng.integers(3, 9))):
        cx, cy = int(rng.integers(0, s)), int(rng.integers(0, s))
        r = int(rng.integers(5, 14))
        col = tuple(float(c) for c in (cols[2] * rng.uniform(0.6, 1.2)))
        pts = (
            np.array(
                [
                    [math.cos(a), math.sin(a)]
                    for a in np.linspace(0, 2 * math.pi, int(rng.integers(3, 7)), endpoint=False)
                ]
            )
            * r
            * rng.uniform(0.5, 1.0, (1, 1))
            + [cx, cy]
        ).astype(np.int32)
        _wrapped(lambda dx, dy: cv2.fillPoly(img, [pts + [dx, dy]], col, cv2.LINE_AA))
    weave = 0.06 * np.sign(np.sin(xx * math.pi / 2) * np.sin(yy * math.pi / 2))
    return _shade(img, weave + 0.12 * _noise(rng, 6))


def _wood(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX
    base = _hsv(srng.uniform(0.04, 0.11), srng.uniform(0.4, 0.75), srng.uniform(0.3, 0.8))
    yy, xx = np.mgrid[0:s, 0:s].astype(np.float32)
    warp = 10.0 * _noise(rng, 4) + 3.0 * _noise(rng, 16)
    k = int(srng.integers(8, 20))
    grain = np.sin(2 * math.pi * k * (yy + warp) / s)
    img = np.ones((s, s, 3), np.float32) * base
    img = _shade(img, 0.18 * grain + 0.1 * _noise(rng, 8))
    for _ in range(int(rng.integers(0, 4))):  # knots
        cx, cy, r = int(rng.integers(0, s)), int(rng.integers(0, s)), int(rng.integers(4, 12))
        col = tuple(float(c) for c in base * 0.5)
        _wrapped(lambda dx, dy: cv2.ellipse(img, (cx + dx, cy + dy), (r * 2, r), 0, 0, 360, col, -1, cv2.LINE_AA))
    return img


def _planks(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX * 2
    base = _hsv(rng.uniform(0.05, 0.1), rng.uniform(0.35, 0.7), rng.uniform(0.35, 0.8))
    n = int(rng.integers(6, 12))
    img = np.zeros((s, s, 3), np.float32)
    yy, xx = np.mgrid[0:s, 0:s].astype(np.float32)
    warp = 8.0 * _noise(rng, 6, s)
    for p in range(n):
        y0, y1 = p * s // n, (p + 1) * s // n
        grain = np.sin(2 * math.pi * rng.integers(20, 50) * (yy[y0:y1] + warp[y0:y1]) / s)
        tone = base * rng.uniform(0.8, 1.2)
        img[y0:y1] = _shade(np.ones((y1 - y0, s, 3), np.float32) * tone, 0.12 * grain)
        img[y0] *= 0.55
        cut = int(rng.integers(0, s))
        img[y0:y1, cut : cut + 2] *= 0.55
    return img


def _tiles(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX * 2
    n = int(rng.integers(3, 8))
    # dark tiles make light fixtures stand out (docs/architecture.md section 8)
    dark = m.family == "darktiles" or rng.uniform() < 0.6
    base = _hsv(rng.uniform(), rng.uniform(0.1, 0.5), rng.uniform(0.2, 0.45) if dark else rng.uniform(0.6, 0.9))
    img = np.ones((s, s, 3), np.float32) * base
    img = _shade(img, 0.12 * _noise(rng, 20, s))
    for i in range(n):
        for j in range(n):
            y0, x0 = i * s // n, j * s // n
            img[y0 : y0 + s // n, x0 : x0 + s // n] *= rng.uniform(0.85, 1.15)
    grout = _hsv(0, 0, 0.85 if dark else 0.35)
    for k in range(n):
        img[k * s // n : k * s // n + 3] = grout
        img[:, k * s // n : k * s // n + 3] = grout
    return img


def _carpet(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img = np.ones((TEX_PX, TEX_PX, 3), np.float32) * _hsv(rng.uniform(), rng.uniform(0.2, 0.6), rng.uniform(0.3, 0.7))
    return _shade(img, 0.25 * _noise(rng, 60) + 0.15 * _noise(rng, 10))


def _leaves(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX
    h0 = srng.uniform(0.2, 0.38)
    img = np.ones((s, s, 3), np.float32) * _hsv(h0, 0.7, 0.18)
    img = _shade(img, 0.3 * _noise(rng, 10))
    variegated = srng.uniform() < 0.35
    length = srng.uniform(8, 30)
    for _ in range(int(rng.integers(60, 120))):
        cx, cy = int(rng.integers(0, s)), int(rng.integers(0, s))
        ax = (int(length * rng.uniform(0.7, 1.3)), int(length * rng.uniform(0.2, 0.45)))
        ang = float(rng.uniform(0, 180))
        col = _hsv(h0 + rng.normal(0, 0.03), rng.uniform(0.5, 0.9), rng.uniform(0.3, 0.75))
        vein = col * 1.4 if not variegated else _hsv(0.15, 0.4, 0.9)
        c1, c2 = tuple(float(c) for c in col), tuple(float(c) for c in vein)

        def draw(dx: int, dy: int) -> None:
            cv2.ellipse(img, (cx + dx, cy + dy), ax, ang, 0, 360, c1, -1, cv2.LINE_AA)
            e = (math.cos(math.radians(ang)) * ax[0], math.sin(math.radians(ang)) * ax[0])
            cv2.line(img, (int(cx + dx - e[0]), int(cy + dy - e[1])), (int(cx + dx + e[0]), int(cy + dy + e[1])), c2, 1)

        _wrapped(draw)
    return img


def _ceramic(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    # Tinted, shaded, veined ceramic: a pure white fixture is nearly unmatchable (docs/architecture.md section 8).
    s = TEX_PX
    base = _hsv(srng.uniform(), srng.uniform(0.15, 0.45), srng.uniform(0.7, 0.9))
    img = _shade(np.ones((s, s, 3), np.float32) * base, 0.15 * _noise(rng, 4) + 0.05 * _noise(rng, 30))
    vein_col = tuple(float(c) for c in _hsv(srng.uniform(), srng.uniform(0.3, 0.7), srng.uniform(0.2, 0.5)))
    for _ in range(int(rng.integers(6, 14))):
        pts = np.cumsum(rng.normal(0, 9, (8, 2)), axis=0) + rng.integers(0, s, 2)
        pts_i = pts.astype(np.int32).reshape(-1, 1, 2)
        thick = int(rng.integers(1, 4))
        _wrapped(lambda dx, dy: cv2.polylines(img, [pts_i + [dx, dy]], False, vein_col, thick, cv2.LINE_AA))
    return img


def _plastic(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img = np.ones((TEX_PX, TEX_PX, 3), np.float32) * _hsv(rng.uniform(), rng.uniform(0, 0.3), rng.uniform(0.08, 0.25))
    return _shade(img, 0.2 * _noise(rng, 50))


def _metal(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img = np.ones((TEX_PX, TEX_PX, 3), np.float32) * _hsv(rng.uniform(), rng.uniform(0, 0.15), rng.uniform(0.5, 0.8))
    brushed = cv2.resize(rng.uniform(-1, 1, (TEX_PX, 8)).astype(np.float32), (TEX_PX, TEX_PX))
    return _shade(img, 0.08 * brushed)


def _terracotta(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    s = TEX_PX
    img = np.ones((s, s, 3), np.float32) * _hsv(
        srng.uniform(0.0, 0.12), srng.uniform(0.3, 0.8), srng.uniform(0.3, 0.85)
    )
    img = _shade(img, 0.1 * _noise(rng, 20))
    if srng.uniform() < 0.7:  # painted bands / zigzags (decorated pots)
        col = tuple(float(c) for c in _palette(srng, 1)[0])
        k = int(srng.integers(2, 6))
        for b in range(k):
            y = (b + 0.5) * s / k
            pts = np.array(
                [[x, y + (8 if (x // 16) % 2 else -8) * rng.uniform(0, 1)] for x in range(0, s + 16, 16)], np.int32
            )
            cv2.polylines(img, [pts.reshape(-1, 1, 2)], False, col, int(rng.integers(2, 6)), cv2.LINE_AA)
    return img


def _paint(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img = np.ones((TEX_PX, TEX_PX, 3), np.float32) * _hsv(
        rng.uniform(), rng.uniform(0.03, 0.25), rng.uniform(0.75, 0.93)
    )
    return _shade(img, 0.05 * _noise(rng, 6) + 0.02 * _noise(rng, 60))


def _plain(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img = np.ones((16, 16, 3), np.float32) * np.array(m.rgb, np.float32)
    return img


@lru_cache(maxsize=32)
def _natural(name: str) -> np.ndarray:
    import skimage.data as data

    if name == "motorcycle":
        img = data.stereo_motorcycle()[0]
    elif name == "horse_photo":
        img = data.chelsea()[:, ::-1]
    else:
        img = getattr(data, name)()
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    return np.ascontiguousarray(img[..., :3])


def _picture(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    img: np.ndarray = _natural(m.image).astype(np.float32)  # float64 after the tint and scale below
    h, w = img.shape[:2]
    cw = int(w * rng.uniform(0.55, 1.0))
    ch = int(cw * m.aspect)
    if ch > h:
        ch = h
        cw = int(h / m.aspect)
    y0, x0 = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    img = img[y0 : y0 + ch, x0 : x0 + cw]
    if rng.uniform() < 0.5:
        img = img[:, ::-1]
    if _natural(m.image).std(axis=2).mean() < 1.0:  # grey photo: tint it like a print
        img = img * (_hsv(rng.uniform(), 0.35, 1.0) / 255.0)
    img = img * rng.uniform(0.85, 1.1)
    return cv2.resize(img, (TEX_PX, max(int(round(TEX_PX * m.aspect)), 16)), interpolation=cv2.INTER_AREA)


def _screen(rng: np.random.Generator, m: Material, srng: np.random.Generator) -> np.ndarray:
    return _picture(rng, m, srng) * 0.9 + 10  # a lit screen: a little washed out


_GENERATORS = {
    "fabric": _fabric,
    "wood": _wood,
    "leaves": _leaves,
    "ceramic": _ceramic,
    "plastic": _plastic,
    "paint": _paint,
    "planks": _planks,
    "tiles": _tiles,
    "darktiles": _tiles,
    "carpet": _carpet,
    "terracotta": _terracotta,
    "metal": _metal,
    "picture": _picture,
    "screen": _screen,
    "plain": _plain,
}
_FAMILY_IDS = {name: k for k, name in enumerate(sorted(_GENERATORS))}
