"""Decoding (Eqs. 1-3, docs/conventions.md), against ideal stacks rendered from exact codes."""

import itertools

import numpy as np
import pytest

from metrology.core.decode import DPHI_TABLE, decode_stack
from metrology.core.geometry.crossed_axes import Rig, height_from_codes
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity
from metrology.core.tiling import row_tiles
from tests.core.ideal_stacks import RIG, ideal_stack, plane_codes


def test_dphi_table_follows_from_the_principle():
    """Combined code = the phase period nearest the gray cell centre l^ + 0.5 (docs/conventions.md)."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        true_code = rng.uniform(8, 120)
        word = int(np.floor(true_code)) + rng.integers(-1, 2)  # gray word off by one at transitions
        t = ((true_code + 2) % 4) - 2  # (2/pi) Phi
        quadrant = min(3, int(np.floor(t + 2)))
        entry = DPHI_TABLE[word % 4, quadrant]
        if abs(true_code - (word + 0.5)) < 1.5 and not np.isnan(entry):
            combined = word + (2 / np.pi) * (np.pi / 2 * t + entry)
            assert combined == pytest.approx(true_code, abs=1e-9)
    # the diagonal of opposite quadrants is invalid, every other entry a multiple of pi/2
    assert np.isnan(DPHI_TABLE[[0, 1, 2, 3], [0, 1, 2, 3]]).all()
    finite = DPHI_TABLE[np.isfinite(DPHI_TABLE)] / (np.pi / 2)
    np.testing.assert_allclose(finite, np.round(finite), atol=1e-12)


@pytest.mark.parametrize("z_mm", [0.0, 13.7, 80.0])
def test_noise_free_round_trip_is_exact(z_mm):
    codes = plane_codes(RIG, z_mm)
    decoded = decode_stack(ideal_stack(codes))
    inside = (codes > 0.01) & (codes < RIG.nlp - 0.01)
    assert decoded.mask[inside].all()
    np.testing.assert_allclose(decoded.codes[inside], codes[inside], atol=5e-5)
    assert np.isnan(decoded.codes[(codes < -0.01) | (codes > RIG.nlp + 0.01)]).all()


def test_noise_free_heights_well_under_a_micrometre():
    ref = decode_stack(ideal_stack(plane_codes(RIG, 0.0)))
    obj = decode_stack(ideal_stack(plane_codes(RIG, 40.0)))
    z = height_from_codes(RIG, ref.codes.astype(np.float64), obj.codes.astype(np.float64))
    valid = np.isfinite(z)
    assert valid.mean() > 0.9
    assert np.abs(z[valid] - 40.0).max() < 1e-3


def test_gray_only_codes_are_cell_centres():
    codes = plane_codes(RIG, 0.0)
    decoded = decode_stack(ideal_stack(codes))
    inside = (codes > 0.05) & (codes < 127.95) & (np.abs(codes - np.round(codes)) > 0.05)
    np.testing.assert_array_equal(decoded.gray_codes[inside], np.floor(codes[inside]) + 0.5)


def test_noise_gives_phase_limited_code_error():
    codes = plane_codes(RIG, 20.0)
    decoded = decode_stack(ideal_stack(codes, bits=8, noise=1.5, seed=4))
    error = decoded.codes - codes
    # b = 0.4 * 255 grey levels: sigma_l = (2/pi) sigma / (sqrt(2) b) = 0.0066 code units
    expected_sigma = (2 / np.pi) * 1.5 / (np.sqrt(2) * 0.4 * 255)
    assert np.nanstd(error) == pytest.approx(expected_sigma, rel=0.1)
    assert np.nanmax(np.abs(error)) < 0.1  # no wrong-period errors


def test_dark_and_inconsistent_pixels_are_invalid():
    codes = plane_codes(RIG, 0.0)
    stack = ideal_stack(codes)
    stack[:, :, :40] = 3000  # no modulation: shadow
    # phase half a period away from what the gray word says: opposite quadrant, two codes off
    stack[7:, :, 100:110] = stack[[9, 10, 7, 8], :, 100:110]
    decoded = decode_stack(stack)
    assert not decoded.mask[:, :40].any()
    assert np.isnan(decoded.gray_codes[:, :40]).all()
    assert not decoded.mask[:, 100:110].any()
    assert decoded.modulation[:, :40].max() == 0


def test_gray_word_off_by_one_is_corrected_by_the_phase():
    codes = plane_codes(RIG, 0.0)
    stack = ideal_stack(codes)
    near_transition = np.abs(codes - np.round(codes)) < 0.2
    # threshold errors at stripe transitions: the changing bit read wrong, the word off by one
    words = np.round(codes).astype(int)
    with np.errstate(divide="ignore"):  # word 0 has no changing bit; it is outside the tested range
        changing_bit = 6 - np.log2(words & -words).clip(0, 6).astype(int)
    for k in range(7):
        flip = near_transition & (changing_bit == k)
        stack[k][flip] = 65535 - stack[k][flip]
    decoded = decode_stack(stack)
    inside = (codes > 1) & (codes < 127) & near_transition
    assert inside.sum() > 500
    np.testing.assert_allclose(decoded.codes[inside], codes[inside], atol=5e-5)


def test_float_and_integer_inputs_agree():
    stack = ideal_stack(plane_codes(RIG, 10.0))
    a = decode_stack(stack)
    b = decode_stack(stack.astype(np.float32), min_modulation=0.04 * 65535)
    np.testing.assert_allclose(a.codes, b.codes, atol=1e-4, equal_nan=True)


def test_8bit_fast_path_agrees_with_the_exact_path():
    """The 8-bit kernel takes OpenCV's atan2 (max error 1.7e-4 rad = 1.1e-4 code units); the
    float path numpy's exact one. Same validity, same gray words, codes within that error."""
    codes = plane_codes(RIG, 25.0)
    stack = ideal_stack(codes, bits=8, noise=1.5, seed=7)
    fast = decode_stack(stack)
    exact = decode_stack(stack.astype(np.float32), min_modulation=0.04 * 255)
    assert fast.mask.mean() > 0.9
    disagree = fast.mask != exact.mask
    assert disagree.mean() < 1e-3  # only pixels on a threshold's edge can differ
    both = fast.mask & exact.mask
    np.testing.assert_allclose(fast.codes[both], exact.codes[both], rtol=0, atol=1.2e-4)
    np.testing.assert_array_equal(fast.gray_codes, exact.gray_codes)
    np.testing.assert_allclose(fast.modulation, exact.modulation, rtol=1e-5)
    np.testing.assert_allclose(fast.visibility, exact.visibility, rtol=1e-5)


def test_threads_and_tiles_do_not_change_the_result():
    stack = np.tile(ideal_stack(plane_codes(RIG, 10.0), bits=8, noise=1.5), (1, 17, 1))  # 408 x 320: 4 tiles
    one, two = decode_stack(stack, threads=1), decode_stack(stack, threads=2)
    for name in ("codes", "gray_codes", "modulation", "mask", "visibility"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name))
    tiles = row_tiles(1000, 1280)
    assert tiles[0].start == 0 and tiles[-1].stop == 1000
    assert all(a.stop == b.start for a, b in itertools.pairwise(tiles))


def test_square_waves_need_smoothing():
    """Square fringes integrated over each pixel (8x8 sub-samples), decoded with and without smoothing."""
    fine = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=320 * 8, height_px=1)
    fine_codes = plane_codes(fine, 0.0)
    images = np.stack([0.05 + 0.8 * pattern_intensity(fine_codes, n, square=True) for n in PATTERN_NAMES])
    stack = np.round(images.reshape(11, 1, 320, 8).mean(-1) * 65535).astype(np.uint16)
    codes = plane_codes(RIG, 0.0)[:1]
    core = slice(20, -20)  # away from the field edges, where smoothing mixes in the dark surround
    raw = np.abs(decode_stack(stack).codes - codes)[:, core]
    # fringe period here is ~10 px; sigma ~0.2 period kills the 3rd harmonic, keeps 40 % of the fundamental
    smooth = np.abs(decode_stack(stack, smoothing_px=2.2).codes - codes)[:, core]
    assert np.nanmean(raw) > 0.05  # the 4-step algorithm aliases the square wave's odd harmonics
    assert np.nanmean(smooth) < np.nanmean(raw) / 4
    assert np.nanmax(smooth) < 0.06


@pytest.mark.parametrize(
    ("images", "kwargs", "message"),
    [
        (np.zeros((10, 4, 4), np.uint8), {}, r"shape \(11, H, W\)"),
        (np.zeros((11, 4, 4), np.int32), {}, "dtype int32"),
        (np.zeros((11, 4, 4), np.uint8), {"nlp": 0}, "nlp"),
        (np.zeros((11, 4, 4), np.uint8), {"consistency_codes": -1}, "consistency_codes"),
        (np.zeros((11, 4, 4), np.uint8), {"smoothing_px": -1}, "smoothing_px"),
    ],
)
def test_bad_inputs(images, kwargs, message):
    with pytest.raises(ValueError, match=message):
        decode_stack(images, **kwargs)
