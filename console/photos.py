"""Goal-photo ingestion: bytes from a phone (or a file) -> an upright RGB array.

Phones send JPEG (with an EXIF orientation tag instead of rotated pixels), HEIC
(iPhones), PNG screenshots or WebP. Everything else, and anything that is not a
usable picture, is rejected with a ``PhotoError`` carrying an HTTP status and a
machine-readable code, so the API can answer with a clear 4xx.

The pixel count is checked from the header *before* any pixel is decoded, which
is what defuses decompression bombs (a tiny file declaring a gigantic image).
"""

from __future__ import annotations

import hashlib
import io
import logging
import warnings
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from console.words import size_words

logger = logging.getLogger(__name__)

try:  # HEIC/HEIF from iPhones; pillow-heif is a hard dependency but keep the error clear.
    import pillow_heif

    pillow_heif.register_heif_opener()
    _HEIF = True
except ImportError:  # pragma: no cover - dependency is in pyproject
    _HEIF = False
    logger.warning("pillow-heif is not installed: HEIC photos will be rejected")

# PIL format name -> file extension used for the stored original.
ACCEPTED_FORMATS: dict[str, str] = {"JPEG": "jpg", "PNG": "png", "WEBP": "webp", "HEIF": "heic"}
if not _HEIF:  # pragma: no cover
    ACCEPTED_FORMATS.pop("HEIF")


class PhotoError(ValueError):
    """A goal photo that cannot be used. ``status`` is the HTTP status to answer with."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.code = code


@dataclass(frozen=True, slots=True)
class PhotoLimits:
    max_bytes: int = 25 * 1024 * 1024  # a 48 MP iPhone HEIC is ~5 MB, a JPEG ~15 MB
    max_pixels: int = 50_000_000  # decoded pixel count (width * height) from the header
    min_side_px: int = 32  # smaller than this holds no keypoints worth matching
    max_side_for_agent_px: int = 1024  # the goal image handed to the agent is downscaled to this


@dataclass(frozen=True, slots=True, eq=False)
class GoalPhoto:
    """A decoded, upright goal photo.

    rgb: (h, w, 3) uint8, R,G,B, EXIF orientation applied, long side at most
         ``PhotoLimits.max_side_for_agent_px``.
    source_format: PIL format name of the upload (JPEG, PNG, WEBP, HEIF).
    original_size_px: (width, height) of the upload after orientation.
    sha256: of the uploaded bytes (identifies a file re-uploaded unchanged).
    dhash: 64-bit difference hash of the upright picture (identifies the same
           picture re-encoded or resized; see ``dhash``).
    """

    rgb: np.ndarray
    source_format: str
    original_size_px: tuple[int, int]
    sha256: str
    dhash: int

    @property
    def extension(self) -> str:
        return ACCEPTED_FORMATS[self.source_format]

    def png_bytes(self) -> bytes:
        """Lossless PNG of ``rgb``. zlib level 1: written between the run's first and second
        actions; ~3x faster than Pillow's default level 6 for ~20% more bytes, same pixels."""
        buf = io.BytesIO()
        Image.fromarray(self.rgb).save(buf, format="PNG", compress_level=1)
        return buf.getvalue()


def dhash(rgb: np.ndarray, hash_size: int = 8) -> int:
    """Difference hash: sign of horizontal gradients of a (hash_size+1 x hash_size) grey thumbnail.

    Robust to re-encoding and rescaling (Krawetz's dHash); two pictures are "the same" when the
    Hamming distance of their hashes is small (<= 6 of 64 bits in practice)."""
    grey = Image.fromarray(np.asarray(rgb, dtype=np.uint8)).convert("L")
    small = np.asarray(grey.resize((hash_size + 1, hash_size), Image.Resampling.LANCZOS), dtype=np.int16)
    bits = (small[:, 1:] > small[:, :-1]).flatten()
    value = 0
    for bit in bits:
        value = (value << 1) | int(bit)
    return value


def hamming(a: int, b: int) -> int:
    return (a ^ b).bit_count()


def decode_photo(data: bytes, limits: PhotoLimits = PhotoLimits()) -> GoalPhoto:
    """Validate and decode an uploaded photo. Raises ``PhotoError`` (4xx) when unusable."""
    if not data:
        raise PhotoError(400, "empty", "the goal photo is empty (0 bytes)")
    if len(data) > limits.max_bytes:
        raise PhotoError(
            413,
            "too_large",
            # the read stops one byte past the limit: say the limit, in MB (not "26214401 bytes")
            f"the goal photo is over the limit of {size_words(limits.max_bytes)}",
        )
    try:
        with warnings.catch_warnings():
            # PIL warns (and later raises) on huge images; our own, lower pixel limit comes first.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data))
    except UnidentifiedImageError:
        raise PhotoError(
            415, "unsupported_format", "the upload is not an image in a supported format (JPEG, PNG, WebP, HEIC)"
        ) from None
    except Image.DecompressionBombError:
        # PIL refuses images beyond twice its own limit before we can read the size; answer
        # with our limit, not PIL's wording.
        raise PhotoError(
            413,
            "too_many_pixels",
            f"the image declares far more pixels than the limit of {_megapixels(limits.max_pixels)}",
        ) from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise PhotoError(422, "corrupt", f"the image header cannot be read: {exc}") from None

    fmt = (image.format or "").upper()
    if fmt not in ACCEPTED_FORMATS:
        raise PhotoError(
            415, "unsupported_format", f"{fmt or 'this'} images are not accepted; send JPEG, PNG, WebP or HEIC"
        )
    width, height = image.size
    if width * height > limits.max_pixels:
        raise PhotoError(
            413,
            "too_many_pixels",
            f"the image is {width}x{height} = {_megapixels(width * height)}; the limit is {_megapixels(limits.max_pixels)}",
        )
    if min(width, height) < limits.min_side_px:
        raise PhotoError(
            422, "too_small", f"the image is {width}x{height}; each side must be at least {limits.min_side_px} px"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image.load()
            upright = ImageOps.exif_transpose(image)  # phones store rotation as an EXIF tag
            n_frames = getattr(image, "n_frames", 1)  # only multi-frame formats (HEIC, animated WebP) have it
            if n_frames > 1:
                logger.info("goal photo has %d frames; using the first", n_frames)
            rgb_image = _to_rgb(upright)
    except PhotoError:
        raise
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PhotoError(422, "corrupt", f"the image data cannot be decoded: {exc}") from None

    original_size = rgb_image.size
    long_side = max(original_size)
    if long_side > limits.max_side_for_agent_px:
        scale = limits.max_side_for_agent_px / long_side
        new_size = (max(1, round(original_size[0] * scale)), max(1, round(original_size[1] * scale)))
        rgb_image = rgb_image.resize(new_size, Image.Resampling.LANCZOS)
    rgb = np.ascontiguousarray(np.asarray(rgb_image, dtype=np.uint8))
    # Per channel: a solid (200, 100, 50) has a large spread over all values but none within
    # any channel.
    if _max_channel_std(rgb) < 1.0:
        raise PhotoError(422, "blank", "the image is a single flat colour; it shows no object to look for")
    return GoalPhoto(
        rgb=rgb,
        source_format=fmt,
        original_size_px=(int(original_size[0]), int(original_size[1])),
        sha256=hashlib.sha256(data).hexdigest(),
        dhash=dhash(rgb),
    )


def _max_channel_std(rgb: np.ndarray) -> float:
    """The largest per-channel standard deviation of (h, w, 3) uint8, from per-channel value
    histograms (exact integer sums): the same figure as ``rgb.reshape(-1, 3).std(axis=0).max()``
    without a float64 copy of the photo, which took half of the photo's decoding time."""
    values = np.arange(256, dtype=np.int64)
    flat = rgb.reshape(-1, 3)
    n = flat.shape[0]
    best = 0.0
    for c in range(3):
        counts = np.bincount(flat[:, c], minlength=256).astype(np.int64)
        s1, s2 = int(counts @ values), int(counts @ (values * values))
        best = max(best, (n * s2 - s1 * s1) / (n * n))  # variance, from Python's exact integers
    return best**0.5


def _megapixels(n_pixels: int) -> str:
    mp = n_pixels / 1e6
    return f"{mp:.0f} megapixels" if mp >= 10 else f"{mp:.2g} megapixels"


def _to_rgb(image: Image.Image) -> Image.Image:
    """Any mode -> RGB; transparency is composited on white (screenshots, stickers)."""
    if image.mode == "RGB":
        return image
    if image.mode in ("RGBA", "LA", "PA") or (image.mode == "P" and "transparency" in image.info):
        rgba = image.convert("RGBA")
        background = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        return Image.alpha_composite(background, rgba).convert("RGB")
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):
        arr = np.asarray(image, dtype=np.float64)
        arr = 255.0 * (arr - arr.min()) / max(1.0, float(arr.max() - arr.min()))
        return Image.fromarray(arr.astype(np.uint8)).convert("RGB")
    return image.convert("RGB")
