"""The parts of a frame's conversion (issue 32) give exactly what the plain formulas give."""

from __future__ import annotations

import numpy as np

from sim.camera import Render, depth_buffer_to_metres, rgba_to_rgb


def _plain_depth(buf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """The formula with its temporaries, as ``depth_buffer_to_metres`` was before issue 32."""
    b = np.asarray(buf, dtype=np.float64)
    depth = far_m * near_m / (far_m - (far_m - near_m) * b)
    depth[b >= 1.0 - 1e-7] = 0.0
    return depth.astype(np.float32)


def test_depth_in_place_is_bit_identical_to_the_formula() -> None:
    rng = np.random.default_rng(0)
    buf = rng.uniform(0.0, 1.0, (64, 36)).astype(np.float32)
    buf[0, :6] = [1.0, np.float32(1.0 - 1e-7), np.nextafter(np.float32(1.0), np.float32(0.0)), 0.0, 0.5, 0.9999]
    for near, far in ((0.05, 30.0), (0.1, 10.0)):
        for b in (buf, buf.astype(np.float64), buf[::2, ::3]):
            kept = b.copy()
            out = depth_buffer_to_metres(b, near, far)
            ref = _plain_depth(b, near, far)
            assert out.dtype == np.float32 and out.tobytes() == ref.tobytes()
            assert np.array_equal(b, kept)  # the caller's buffer is left alone


def test_rgb_drops_alpha_exactly() -> None:
    rng = np.random.default_rng(1)
    rgba = rng.integers(0, 256, (40, 24, 4), dtype=np.uint8)
    for a in (rgba, rgba[::2, ::3]):
        rgb = rgba_to_rgb(a)
        assert rgb.dtype == np.uint8 and rgb.flags.c_contiguous
        assert np.array_equal(rgb, a[:, :, :3])


def test_mask_of_equals_the_instance_id_image() -> None:
    rng = np.random.default_rng(2)
    # raw ids -1..9 and some out of the table's range; raw 3 and 7 both map to instance 2
    lut = np.full(12, -1, dtype=np.int32)
    lut[1 + 1], lut[3 + 1], lut[7 + 1], lut[5 + 1] = 0, 2, 2, 4
    seg = rng.integers(-3, 14, (30, 20)).astype(np.int32)
    for table in (lut, None):
        for iid in (-1, 0, 1, 2, 4, 99):
            r = Render(np.zeros((30, 20, 3), np.uint8), np.zeros((30, 20), np.float32), seg, table)
            mask = r.mask_of(iid)
            assert mask.dtype == bool and np.array_equal(mask, r.instance_ids == iid)
            fresh = Render(r.rgb, r.depth_m, seg, table)  # before the instance-id image exists
            assert np.array_equal(fresh.mask_of(iid), mask)


def test_copy_has_arrays_of_its_own() -> None:
    r = Render(np.ones((2, 3, 3), np.uint8), np.ones((2, 3), np.float32), np.zeros((2, 3), np.int32))
    c = r.copy()
    c.rgb[:] = 0
    c.depth_m[:] = 0
    c.seg_raw[:] = 5
    assert r.rgb.min() == 1 and r.depth_m.min() == 1.0 and r.seg_raw.max() == 0
