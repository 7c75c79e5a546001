"""Stored point maps (metrology.core.io.points): the measured pixels' points and a bit mask, read back
bit for bit, at 12 bytes per stored pixel and 1 bit per pixel; the dense .npy stored before reads too."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.core.io import read_point_map, write_point_map
from metrology.core.io.points import NOT_MEASURED_BITS, stored_mask


def stored(points: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    write_point_map(buffer, points)
    return buffer.getvalue()


def bits(points: np.ndarray) -> np.ndarray:
    return points.view(np.uint32)


def sample_points(height: int, width: int, measured: float, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, 200.0, (height, width, 3)).astype(np.float32)
    points[rng.random((height, width)) >= measured] = np.nan
    return points


@pytest.mark.parametrize(("height", "width", "measured"), [(7, 13, 0.17), (120, 160, 0.5), (5, 3, 1.0), (4, 4, 0.0)])
def test_round_trip_is_bit_exact_and_sized_12_bytes_a_point_and_a_bit_a_pixel(height, width, measured):
    points = sample_points(height, width, measured)
    data = stored(points)
    back = read_point_map(data)
    assert back.dtype == np.float32 and back.shape == (height, width, 3)
    assert np.array_equal(bits(back), bits(points))
    n = int(np.isfinite(points[..., 0]).sum())
    mask_bytes = 0 if n == height * width else -(-height * width // 8)
    with np.load(io.BytesIO(data)) as npz:
        assert sorted(npz.files) == ["points", "shape", "valid_bits"]
        assert npz["points"].shape == (n, 3) and npz["valid_bits"].nbytes == mask_bytes
        assert npz["shape"].tolist() == [height, width]
    # the arrays' bytes and 776 bytes of headers: shape (16), three .npy headers (3 x 128), the zip's (376)
    assert len(data) == 12 * n + mask_bytes + 776


def test_unusual_values_are_stored_as_they_are():
    points = np.full((2, 3, 3), np.nan, np.float32)
    points[0, 0] = [1.0, np.nan, 2.0]  # partly NaN
    points[0, 1] = [np.inf, -np.inf, 0.0]
    points[0, 2] = -points[0, 2]  # NaN with the sign bit
    points[1, 0].view(np.uint32)[:] = 0x7FC00001  # another NaN payload
    points[1, 1] = [-0.0, 0.0, -0.0]
    mask = stored_mask(points)
    assert mask.tolist() == [[True, True, True], [True, True, False]]
    back = read_point_map(stored(points))
    assert np.array_equal(bits(back), bits(points))
    assert int(bits(back)[1, 2, 0]) == int(NOT_MEASURED_BITS)


def test_dense_npy_stored_before_reads_as_it_is():
    points = sample_points(6, 5, 0.4)
    buffer = io.BytesIO()
    np.save(buffer, points)
    assert np.array_equal(bits(read_point_map(buffer.getvalue())), bits(points))
    buffer = io.BytesIO()
    np.save(buffer, points.astype(np.float64))
    assert read_point_map(buffer.getvalue()).dtype == np.float32


def test_bad_input_is_refused_with_a_message():
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        stored(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="float32"):
        stored(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="not a point map"):
        read_point_map(b"junk")
    buffer = io.BytesIO()
    np.save(buffer, np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match=r"expected a \(H, W, 3\) float array"):
        read_point_map(buffer.getvalue())
    buffer = io.BytesIO()
    np.savez(buffer, shape=np.array([2, 2]), valid_bits=np.array([0b11100000], np.uint8), points=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"points must be \(N, 3\) float32"):
        read_point_map(buffer.getvalue())
    buffer = io.BytesIO()
    np.savez(
        buffer, shape=np.array([2, 2]), valid_bits=np.array([0b11100000], np.uint8), points=np.zeros((2, 3), np.float32)
    )
    with pytest.raises(ValueError, match="2 points for 3 stored pixels"):
        read_point_map(buffer.getvalue())
    buffer = io.BytesIO()
    np.savez(buffer, other=np.zeros(1))
    with pytest.raises(ValueError, match="members"):
        read_point_map(buffer.getvalue())
