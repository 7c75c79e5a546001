"""The compiled gcps-v1 kernel (metrology.core.decode_kernels) against the numpy kernel: the same
float32 numbers, bit for bit, on every 8-bit pair of phase differences and through measure()."""

import cv2
import numpy as np
import pytest

from metrology.core import decode as decode_module
from metrology.core import decode_kernels, kernel_choice
from metrology.core.codecs.check import sampled_rows
from metrology.core.decode import decode_sampled_rows, decode_tile, use_compiled
from metrology.core.filters import FilterOptions
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.measure import MeasureOptions, check_gcps_v1_sample, measure, prepare_reference
from metrology.core.patterns import binary_from_gray
from tests.core.ideal_stacks import RIG, ideal_stack, plane_codes

OUTPUTS = ("codes", "gray_codes", "visibility", "z_mm")


def every_difference_stack(seed: int = 1) -> np.ndarray:
    """An (11, 511, 511) uint8 stack whose pixels take every pair ``s = I1 - I3``, ``c = I0 - I2``
    in -255..255 once, with random phase frames under that constraint and gray frames within 3
    grey levels of the phase mean (so that every bit pattern occurs)."""
    rng = np.random.default_rng(seed)
    s, c = (a.ravel() for a in np.meshgrid(np.arange(-255, 256), np.arange(-255, 256), indexing="ij"))
    p3 = rng.integers(np.maximum(0, -s), np.minimum(255, 255 - s) + 1)
    p2 = rng.integers(np.maximum(0, -c), np.minimum(255, 255 - c) + 1)
    phase = np.stack([p2 + c, p3 + s, p2, p3]).reshape(4, 511, 511)
    mean = phase.sum(axis=0) // 4
    gray = np.clip(mean[None] + rng.integers(-3, 4, (7, 511, 511)), 0, 255)
    return np.concatenate([gray, phase]).astype(np.uint8)


def decode_both_ways(stack: np.ndarray, compiled: bool) -> dict[str, np.ndarray]:
    """Every output of the fused path's tile decoder on ``stack`` (two tiles), heights against a
    random reference with holes."""
    _, height, width = stack.shape
    rig = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=width, height_px=height)
    prepared = rig.prepare(None, None)
    rng = np.random.default_rng(7)
    ref_codes = np.where(rng.random((height, width)) < 0.1, np.nan, rng.uniform(0, 128, (height, width)))
    surface = prepared.reference(ref_codes.astype(np.float32), None)
    out = {name: np.full((height, width), -7.0, np.float32) for name in OUTPUTS}
    for rows in (slice(0, 200), slice(200, height)):
        done = decode_tile(
            stack,
            stack[7:],
            rows,
            128,
            10.2,
            0.35,
            0.5,
            out["codes"],
            compiled=compiled,
            gray_codes=out["gray_codes"],
            visibility=out["visibility"],
            heights=prepared.height_terms(surface),
            z_mm=out["z_mm"],
        )
        assert done == compiled
        if not done:
            prepared.triangulate_rows(rows, out["codes"][rows], None, reference=surface, height_out=out["z_mm"][rows])
    return out


def test_compiled_kernel_equals_numpy_kernel_on_every_difference_pair():
    stack = every_difference_stack()
    numpy_out, compiled_out = decode_both_ways(stack, False), decode_both_ways(stack, True)
    for name in OUTPUTS:
        np.testing.assert_array_equal(compiled_out[name], numpy_out[name], err_msg=name)
    # the test covers every branch: valid and invalid codes, modulated and not
    valid = np.isfinite(numpy_out["codes"]).mean()
    assert 0.2 < valid < 0.8 and np.isnan(numpy_out["gray_codes"]).any()


@pytest.mark.parametrize("gray_only", [False, True])
def test_measure_with_the_compiled_kernel_equals_numpy(monkeypatch, gray_only):
    ref_stack = ideal_stack(plane_codes(RIG, 0.0), bits=8, noise=1.5, seed=1)
    obj_stack = ideal_stack(plane_codes(RIG, 25.0), bits=8, noise=1.5, seed=2)
    options = MeasureOptions(filters=FilterOptions(blur_variance_px2=0.0), gray_only=gray_only)
    reference = prepare_reference(RIG, ref_stack, None, options)
    terms = RIG.prepare(None, None).height_terms(reference.surface)
    # what the compiled kernel needs, or it would fall back to numpy's and the test prove nothing
    assert terms is not None and terms.ref_codes.flags.c_contiguous and obj_stack.flags.c_contiguous
    results = {}
    for compiled in (False, True):
        monkeypatch.setattr(kernel_choice, "COMPILED", compiled)
        assert use_compiled(np.uint8, 100) is compiled
        results[compiled] = measure(RIG, obj_stack, reference=reference, options=options)
    for name in ("z_mm", "codes", "gray_z_mm"):
        a, b = getattr(results[False], name), getattr(results[True], name)
        if a is None:
            assert b is None and not gray_only
            continue
        np.testing.assert_array_equal(b, a, err_msg=name)
    assert abs(np.nanmedian(results[True].z_mm) - 25.0) < 0.02


def test_use_compiled_is_for_8_bit_stacks_only(monkeypatch):
    monkeypatch.setattr(kernel_choice, "COMPILED", True)
    assert not use_compiled(np.uint16, 100) and use_compiled(np.uint8, 100)
    monkeypatch.setattr(kernel_choice, "COMPILED", None)
    assert use_compiled(np.uint8, kernel_choice.COMPILED_MIN_PX)


def test_closed_forms_equal_the_numpy_kernels_tables():
    """dPhi, the binary word and the quadrant, computed in the compiled kernel, against the tables and
    the OpenCV rounding of the numpy kernel, entry for entry."""
    for row in range(4):
        for quadrant in range(5):
            expected = decode_module._K_LUT[8 * row + quadrant]
            got = decode_kernels.dphi_codes(np.int32(quadrant), np.int32(row))
            assert (np.isnan(got) and np.isnan(expected)) or np.float32(got) == expected, (row, quadrant)
    words = np.arange(128)
    assert [decode_kernels.binary_word(np.int32(g)) for g in words] == binary_from_gray(words).tolist()
    phase, bounds = decode_kernels.phase_tables()
    quadrant = cv2.convertScaleAbs(phase, alpha=2 / np.pi, beta=-0.5).ravel()
    np.testing.assert_array_equal((phase[:, None] >= bounds[None, :]).sum(axis=1), quadrant)
    assert set(np.unique(quadrant)) <= {0, 1, 2, 3, 4} and np.all(np.diff(bounds) >= 0)
    squares = np.arange(2 * 255**2 + 1)
    modulation = np.sqrt(squares.astype(np.float32))
    for min_modulation in (0.0, 3.0, 10.0, 10.2, 12.000001, 360.62445, 361.0):
        n = decode_kernels.min_square(min_modulation)
        np.testing.assert_array_equal(
            squares >= n, modulation >= np.float32(min_modulation), err_msg=str(min_modulation)
        )


def test_compiled_sample_of_the_codec_self_check_equals_numpy(monkeypatch):
    stack = every_difference_stack()
    rows = sampled_rows(stack.shape[1], pairs=8)
    outputs = {}
    for compiled in (False, True):
        monkeypatch.setattr(kernel_choice, "COMPILED", compiled)
        outputs[compiled] = [np.full((rows.size, stack.shape[2]), -7.0, np.float32) for _ in range(3)]
        decode_sampled_rows(stack, rows, 128, 10.2, *outputs[compiled])
    for name, a, b in zip(("fraction", "word", "modulation"), outputs[False], outputs[True], strict=True):
        np.testing.assert_array_equal(b, a, err_msg=name)
    assert np.isnan(outputs[True][0]).any() and np.isfinite(outputs[True][0]).any()
    ideal = ideal_stack(plane_codes(RIG, 10.0), bits=8, noise=1.5, seed=3)
    checks = {}
    for compiled in (False, True):
        monkeypatch.setattr(kernel_choice, "COMPILED", compiled)
        checks[compiled] = check_gcps_v1_sample(ideal, None, RIG.nlp)["u"]
    assert checks[True] == checks[False] and checks[True].status == "consistent"
