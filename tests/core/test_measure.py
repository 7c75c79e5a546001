"""The fused measurement path against the plain Eqs. 14-17 path, and mixed-pixel filtering."""

import numpy as np
import pytest

from metrology.core.decode import decode_stack
from metrology.core.measure import DecodeOptions, discontinuity_mask, measure_height, prepare_reference
from metrology.core.triangulate import height_from_codes
from tests.core.test_decode import RIG, ideal_stack, plane_codes


def test_fused_path_equals_decode_then_triangulate():
    ref_stack = ideal_stack(plane_codes(RIG, 0.0), bits=8, noise=1.5, seed=1)
    obj_stack = ideal_stack(plane_codes(RIG, 25.0), bits=8, noise=1.5, seed=2)
    result = measure_height(RIG, ref_stack, obj_stack)
    expected = height_from_codes(RIG, decode_stack(ref_stack).codes, decode_stack(obj_stack).codes)
    np.testing.assert_allclose(result.z_mm, expected, atol=2e-4, equal_nan=True)
    assert result.z_mm.dtype == np.float32
    assert abs(np.nanmedian(result.z_mm) - 25.0) < 0.02
    assert result.gray_z_mm is not None and np.nanstd(result.gray_z_mm - 25.0) > 1.0  # code-unit steps
    stats = result.statistics()
    assert stats["valid_pixels"] == int(np.isfinite(result.z_mm).sum())


def test_kept_reference_gives_the_same_heights():
    ref_stack = ideal_stack(plane_codes(RIG, 0.0))
    obj_stack = ideal_stack(plane_codes(RIG, 60.0))
    reference = prepare_reference(RIG, ref_stack)
    a = measure_height(RIG, reference, obj_stack, gray_only=False)
    b = measure_height(RIG, ref_stack, obj_stack, gray_only=False)
    np.testing.assert_array_equal(a.z_mm, b.z_mm)
    assert a.gray_z_mm is None
    valid = np.isfinite(a.z_mm)
    assert np.abs(a.z_mm[valid] - 60.0).max() < 1e-3  # float32 fast path: exact to ~0.5 um


def test_shape_unlike_the_rig_is_refused():
    stack = ideal_stack(plane_codes(RIG, 0.0))
    with pytest.raises(ValueError, match="rig is 320x24"):
        measure_height(RIG, stack, stack[:, :10])


def test_discontinuity_mask_drops_both_sides_of_a_jump():
    codes = np.tile(np.linspace(10, 20, 30, dtype=np.float32), (5, 1))
    codes[:, 15:] += 3.0  # a step of 3 code units
    codes[2, 5] = np.nan
    drop = discontinuity_mask(codes, 1.0)
    assert drop[:, 14].all() and drop[:, 15].all()
    assert not drop[:, 16:].any() and not drop[:, :4].any()
    assert drop[2, 4] and drop[2, 6] and drop[1, 5] and not drop[2, 5]  # NaN neighbours count
    assert DecodeOptions(discontinuity_codes=1.0).to_dict()["discontinuity_codes"] == 1.0
