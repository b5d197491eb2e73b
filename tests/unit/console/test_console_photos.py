"""Goal-photo ingestion: formats, EXIF orientation, limits and every unusable input."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from console.photos import PhotoError, PhotoLimits, decode_photo, dhash, hamming
from tests.helpers.console_testkit import encode, textured_rgb


@pytest.mark.parametrize("fmt", ["JPEG", "PNG", "WEBP"])
def test_common_formats_decode(fmt: str) -> None:
    rgb = textured_rgb(96, 128)
    photo = decode_photo(encode(rgb, fmt))
    assert photo.rgb.shape == (96, 128, 3) and photo.rgb.dtype == np.uint8
    assert photo.source_format == fmt
    assert photo.original_size_px == (128, 96)


def test_heic_decodes() -> None:
    import pillow_heif  # noqa: F401  (registers the HEIF plugin, also for saving)

    rgb = textured_rgb(96, 128)
    photo = decode_photo(encode(rgb, "HEIF", quality=90))
    assert photo.source_format == "HEIF" and photo.extension == "heic"
    assert photo.rgb.shape == (96, 128, 3)
    assert np.abs(photo.rgb.astype(int) - rgb.astype(int)).mean() < 25


def test_exif_orientation_is_applied() -> None:
    rgb = textured_rgb(60, 100)  # landscape pixels...
    exif = Image.Exif()
    exif[0x0112] = 6  # ...stored by a phone held upright: "rotate 90 CW to display"
    photo = decode_photo(encode(rgb, "JPEG", exif=exif.tobytes(), quality=95))
    assert photo.rgb.shape == (100, 60, 3)  # upright: portrait
    expected = np.rot90(rgb, k=-1)
    assert np.abs(photo.rgb.astype(int) - expected.astype(int)).mean() < 20


def test_rgba_and_grey_are_converted() -> None:
    rgba = np.dstack([textured_rgb(64, 64), np.full((64, 64), 128, np.uint8)])
    assert decode_photo(encode(rgba, "PNG")).rgb.shape == (64, 64, 3)
    grey = textured_rgb(64, 64)[:, :, 0]
    assert decode_photo(encode(grey, "PNG")).rgb.shape == (64, 64, 3)


def test_large_photo_is_downscaled_for_the_agent() -> None:
    photo = decode_photo(encode(textured_rgb(1500, 2000), "JPEG"), PhotoLimits(max_side_for_agent_px=512))
    assert max(photo.rgb.shape[:2]) == 512
    assert photo.original_size_px == (2000, 1500)


def expect(status: int, code: str, data: bytes, limits: PhotoLimits = PhotoLimits()) -> PhotoError:
    with pytest.raises(PhotoError) as info:
        decode_photo(data, limits)
    assert (info.value.status, info.value.code) == (status, code), str(info.value)
    assert str(info.value)
    return info.value


def test_empty() -> None:
    expect(400, "empty", b"")


def test_not_an_image() -> None:
    expect(415, "unsupported_format", b"%PDF-1.4 definitely not a photo" * 10)


def test_unsupported_image_format() -> None:
    expect(415, "unsupported_format", encode(textured_rgb(64, 64), "BMP"))
    expect(415, "unsupported_format", encode(textured_rgb(64, 64), "GIF"))


def test_truncated_jpeg() -> None:
    data = encode(textured_rgb(200, 200), "JPEG")
    expect(422, "corrupt", data[: len(data) // 3])


def test_too_many_bytes() -> None:
    expect(413, "too_large", encode(textured_rgb(64, 64), "PNG"), PhotoLimits(max_bytes=100))


def _png_header_only(width: int, height: int) -> bytes:
    """A valid PNG declaring width x height with almost no data: a decompression bomb's header."""

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return (
            struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF)
        )

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    )


def test_decompression_bomb_rejected_from_header() -> None:
    err = expect(413, "too_many_pixels", _png_header_only(100_000, 100_000))
    assert "pixels" in str(err)


def test_pixel_limit() -> None:
    expect(413, "too_many_pixels", encode(textured_rgb(200, 200), "PNG"), PhotoLimits(max_pixels=10_000))


def test_too_small() -> None:
    expect(422, "too_small", encode(textured_rgb(16, 16), "PNG"))


def test_flat_image_rejected() -> None:
    expect(422, "blank", encode(np.full((64, 64, 3), 127, np.uint8), "PNG"))


def test_dhash_survives_reencoding_and_resizing() -> None:
    rgb = textured_rgb(256, 256, seed=3)
    again = decode_photo(encode(rgb, "JPEG", quality=70)).rgb
    smaller = np.asarray(Image.fromarray(rgb).resize((180, 180)))
    other = textured_rgb(256, 256, seed=4)
    assert hamming(dhash(rgb), dhash(again)) <= 6
    assert hamming(dhash(rgb), dhash(smaller)) <= 6
    assert hamming(dhash(rgb), dhash(other)) > 12


@pytest.mark.parametrize("colour", [(200, 100, 50), (0, 0, 255), (128, 128, 128)])
def test_flat_coloured_image_is_blank(colour: tuple[int, int, int]) -> None:
    """Each channel is checked: a solid orange has a large spread over all values together."""
    solid = np.full((64, 64, 3), colour, np.uint8)
    with pytest.raises(PhotoError) as err:
        decode_photo(encode(solid, "PNG"))
    assert err.value.status == 422 and err.value.code == "blank"


def test_image_far_over_the_pixel_limit_gets_our_message_not_pils() -> None:
    """A 20000 x 20000 PNG is beyond PIL's own bomb limit, which fires before our check."""
    data = _png_header_only(20000, 20000)
    with pytest.raises(PhotoError) as err:
        decode_photo(data)
    assert err.value.status == 413 and err.value.code == "too_many_pixels"
    message = str(err.value)
    assert "50 megapixels" in message and "DOS" not in message and "decompression" not in message.lower()


def test_image_over_the_pixel_limit_names_both_sizes() -> None:
    data = _png_header_only(8000, 7000)  # 56 MP: under PIL's bomb limit, over ours
    with pytest.raises(PhotoError) as err:
        decode_photo(data)
    assert err.value.code == "too_many_pixels"
    assert "8000x7000 = 56 megapixels" in str(err.value) and "limit is 50 megapixels" in str(err.value)
