"""The fused measurement path against the plain Eqs. 14-17 path, and mixed-pixel filtering."""

import numpy as np
import pytest

from metrology.core.decode import decode_stack
from metrology.core.filters import FilterOptions, unreliable_mask
from metrology.core.geometry.crossed_axes import height_from_codes
from metrology.core.measure import MeasureOptions, height_statistics, measure, prepare_reference
from tests.core.ideal_stacks import RIG, ideal_stack, plane_codes


def test_fused_path_equals_decode_then_triangulate():
    ref_stack = ideal_stack(plane_codes(RIG, 0.0), bits=8, noise=1.5, seed=1)
    obj_stack = ideal_stack(plane_codes(RIG, 25.0), bits=8, noise=1.5, seed=2)
    options = MeasureOptions(filters=FilterOptions(edge_band_px=0, field_margin_codes=0.0, blur_variance_px2=0.0))
    result = measure(RIG, obj_stack, reference=ref_stack, options=options)
    ref_codes, obj_codes = decode_stack(ref_stack).codes, decode_stack(obj_stack).codes
    expected = height_from_codes(RIG, ref_codes.astype(np.float64), obj_codes.astype(np.float64))
    # float32 throughout, but D_R = slope (l - r) / (1 + q l) subtracts codes, not two ~500 mm
    # abscissae: within 20 nm of the float64 heights (plain float32 Eqs. 14-17: 0.44 um here)
    np.testing.assert_allclose(result.z_mm, expected, rtol=0, atol=2e-5, equal_nan=True)
    assert result.z_mm.dtype == np.float32
    assert abs(np.nanmedian(result.z_mm) - 25.0) < 0.02
    assert result.gray_z_mm is not None and np.nanstd(result.gray_z_mm - 25.0) > 1.0  # code-unit steps
    stats = height_statistics(result.z_mm)
    assert stats["valid_pixels"] == int(np.isfinite(result.z_mm).sum())


def test_kept_reference_gives_the_same_heights():
    ref_stack = ideal_stack(plane_codes(RIG, 0.0))
    obj_stack = ideal_stack(plane_codes(RIG, 60.0))
    reference = prepare_reference(RIG, ref_stack)
    options = MeasureOptions(gray_only=False)
    a = measure(RIG, obj_stack, reference=reference, options=options)
    b = measure(RIG, obj_stack, reference=ref_stack, options=options)
    np.testing.assert_array_equal(a.z_mm, b.z_mm)
    assert a.gray_z_mm is None
    valid = np.isfinite(a.z_mm)
    assert np.abs(a.z_mm[valid] - 60.0).max() < 1e-3  # float32 fast path: 0.17 um here


def test_shape_unlike_the_rig_is_refused():
    stack = ideal_stack(plane_codes(RIG, 0.0))
    with pytest.raises(ValueError, match="object frames are 320x10 px but the rig's camera is 320x24 px"):
        measure(RIG, stack[:, :10], reference=stack)


def test_unreliable_mask_drops_a_band_at_jumps_and_holes():
    codes = np.tile(np.linspace(10, 20, 30, dtype=np.float32), (7, 1))
    codes[:, 15:] += 3.0  # a depth step of 3 code units between columns 14 and 15
    codes[3, 5] = np.nan  # a hole
    drop = unreliable_mask(codes, 1.0, 1)
    assert drop[:, 13:17].all() and not drop[:, 17:].any() and not drop[:, 8:13].any()
    assert drop[3, 4] and drop[3, 6] and drop[2, 5] and drop[4, 5] and not drop[3, 5]  # NaN is not "dropped"
    assert not drop[1, 4]  # 4-connected band
    wide = unreliable_mask(codes, 1.0, 2)
    assert wide[:, 12:18].all() and not wide[:, 19:].any() and wide[2, 4] and wide[3, 3] and not wide[1, 4]
    assert not unreliable_mask(codes, 1.0, 0).any()
    assert not unreliable_mask(codes, 0.0, 1)[:, 17:].any()  # no jump seeds: only the hole's band
    with pytest.raises(ValueError, match="edge_band_px"):
        FilterOptions(edge_band_px=-1)


def test_unreliable_mask_drops_a_crease_with_a_one_pixel_band():
    """Beside a crease of the codes (the slope goes from 0.2 to 0.7 code/px at x = 20.5, steps of
    0.7 code: no jump seed), the blur's bias s2/2 laplacian(l) reaches 0.045 code at s2 = 0.5:
    the four columns whose 5x5 window sees the crease (19-22) are marked, with their
    4-neighbours (18-23), whatever the edge band; nothing else."""
    x = np.arange(40, dtype=np.float32)
    codes = np.tile(0.2 * x + 0.5 * np.maximum(x - 20.5, 0), (12, 1)).astype(np.float32)
    for band in (1, 3):
        drop = unreliable_mask(codes, 1.0, band, blur_variance_px2=0.5, max_blur_bias_codes=0.015)
        assert drop[2:-2, 18:24].all() and not drop[:, :18].any() and not drop[:, 24:].any()
        assert drop[1, 19:23].all() and not drop[0].any()  # rows 0-1 are not tested: band from row 2
    assert not unreliable_mask(codes, 1.0, 2).any()  # the test off (no blur variance given)
    assert not unreliable_mask(codes, 1.0, 2, blur_variance_px2=0.5, max_blur_bias_codes=0.05).any()
    tall = np.tile(codes, (170, 1))  # 2040 x 40 px: three row tiles on two threads
    tiled = unreliable_mask(tall, 1.0, 2, threads=2, blur_variance_px2=0.5, max_blur_bias_codes=0.015)
    expected = unreliable_mask(tall, 1.0, 2, threads=1, blur_variance_px2=0.5, max_blur_bias_codes=0.015)
    np.testing.assert_array_equal(tiled, expected)
    assert tiled[2:-2, 18:24].all() and not tiled[:, 24:].any()  # tiles see their neighbours' rows
    with pytest.raises(ValueError, match="max_blur_bias_codes"):
        FilterOptions(max_blur_bias_codes=-0.01)


def test_height_statistics_are_numpys_float64_figures_to_the_bit():
    rng = np.random.default_rng(5)
    z = rng.normal(40.0, 7.0, (64, 96)).astype(np.float32)
    z[rng.random(z.shape) < 0.3] = np.nan
    values = z[np.isfinite(z)].astype(np.float64)
    stats = height_statistics(z)
    assert stats["valid_pixels"] == values.size and stats["valid_fraction"] == values.size / z.size
    assert (stats["min_mm"], stats["max_mm"]) == (values.min(), values.max())
    assert (stats["mean_mm"], stats["std_mm"]) == (values.mean(), values.std())  # not approximately
    assert stats["mean_mm"] == pytest.approx(40.0, abs=0.5) and stats["std_mm"] == pytest.approx(7.0, rel=0.05)
    assert height_statistics(np.full((3, 3), np.nan, np.float32))["mean_mm"] is None
