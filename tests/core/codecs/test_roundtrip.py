"""Round trips: codec -> virtual-rig rendering (render_codec) -> decode_codec, against the true (u, v).

Noise-free 16-bit renders (no blur, sinusoids unless said) must decode every lit pixel to within
0.01 projector px of the truth, with no slip. Square waves with the realistic preset's projector
blur: within 0.05 px for N >= 12. Realistic 8-bit renders: the coordinate noise within 1.2x of
``P / (2 pi) sqrt(2 / N) sigma / B`` and fewer than 1 pixel in 10,000 off by half a period.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import builtin_codec, codec_from_dict, render_codec
from metrology.core.codecs.decode import decode_codec
from metrology.core.codecs.render import default_projector_blur_px, square_wave_bias_px
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, crossed_rig_truth, render_stack
from tests.core.codecs.roundtrips import (
    PROJ_H,
    affine_truth,
    assert_round_trip,
    axis_spec,
    bits_for,
    decode_inner,
    make_codec,
    truth_maps,
)

U, V = truth_maps()


def test_gcps_v1_round_trip() -> None:
    codec = builtin_codec("gcps-v1")
    u, _ = truth_maps(proj_w=1024, proj_h=768)
    assert_round_trip(codec, u, np.full_like(u, np.nan))


@pytest.mark.parametrize("steps", [3, 4, 12, 18])
def test_n_steps_with_gray_word_equal_to_period(steps: int) -> None:
    u, n = axis_spec(0, steps, 16.0, bits=bits_for(16.0))
    assert_round_trip(make_codec(u, None, n), U, V)


@pytest.mark.parametrize("order", ["msb_first", "lsb_first"])
@pytest.mark.parametrize("inverse", [False, True])
def test_gray_orders_and_inverse_pairs(order: str, inverse: bool) -> None:
    u, n = axis_spec(0, 4, 16.0, bits=bits_for(8.0), word=8.0, order=order, inverse=inverse)
    assert_round_trip(make_codec(u, None, n), U, V)


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.25])
def test_gray_word_fractions_of_the_period(fraction: float) -> None:
    word = 24.0 * fraction
    u, n = axis_spec(0, 6, 24.0, bits=bits_for(word), word=word, gray_origin=-0.5 - 3.0)
    v, n = axis_spec(n, 6, 24.0, bits=bits_for(word, PROJ_H), word=word, shift=-1, origin=2.0)
    assert_round_trip(make_codec(u, v, n), U, V)


def test_single_pixel_gray_word_with_phase() -> None:
    u, n = axis_spec(0, 8, 8.0, bits=bits_for(1.0), word=1.0, inverse=True)
    assert_round_trip(make_codec(u, None, n), U, V)


def test_white_black_threshold_and_inverted_code() -> None:
    u, n = axis_spec(0, 3, 32.0, bits=bits_for(32.0), inverted=True)
    v, n = axis_spec(n, 3, 32.0, bits=bits_for(32.0, PROJ_H), order="lsb_first")
    assert_round_trip(make_codec(u, v, n + 2, white=[n], black=[n + 1]), U, V)


def test_two_frequency_heterodyne_both_axes() -> None:
    def axis(first: int, p_short: float, p_long: float) -> dict[str, Any]:
        return {
            "phase": [
                {"frames": list(range(first, first + 4)), "period": p_short, "origin": 0.3},
                {"frames": list(range(first + 4, first + 8)), "period": p_long, "origin": -1.0},
            ],
            "unwrap": ["beat:0,1", "phase:1", "phase:0"],
        }

    # beats: 16 * 17 / (17 - 16) = 272 >= 256 and 12 * 13 / 1 = 156... too short for 192: use 14, 15 -> 210
    codec = make_codec(axis(0, 16.0, 17.0), axis(8, 14.0, 15.0), 16)
    assert_round_trip(codec, U, V)


def test_gray_only_axis_gives_the_word_centre() -> None:
    u, n = axis_spec(0, None, 0.0, bits=bits_for(1.0), word=1.0, inverse=True)
    codec = make_codec(u, None, n)
    images = render_codec(codec, U, None)
    axis = decode_codec(images, codec).axes["u"]
    lit = np.isfinite(U)
    np.testing.assert_array_equal(axis.coordinate[lit], np.floor(U[lit] + 0.5))
    assert axis.valid[lit].all() and not axis.valid[~lit].any()


def test_crossed_axes_virtual_rig_truth_round_trip() -> None:
    rig = PAPER_RIG
    rendered = render_stack(rig, make_scene("sphere"))
    u, v = crossed_rig_truth(rendered, rig, 1024, 768)
    lit = np.isfinite(u)
    assert lit.mean() > 0.5 and np.isfinite(v[lit]).all()
    assert np.nanmin(u) >= -0.5 and np.nanmax(u) <= 1023.5
    ua, n = axis_spec(0, 12, 32.0, bits=bits_for(32.0, 1024))
    va, n = axis_spec(n, 12, 32.0, bits=bits_for(32.0, 768))
    codec = codec_from_dict(
        {"codec": "gcps-codec/1", "frames": n, "projector": {"width": 1024, "height": 768}, "axes": {"u": ua, "v": va}}
    )
    images = render_codec(codec, u, v)
    decoded = decode_codec(images, codec)
    for name, truth in (("u", u), ("v", v)):
        axis = decoded.axes[name]
        assert np.abs(axis.coordinate[axis.valid] - truth[axis.valid]).max() < 0.01
        assert axis.valid[lit].mean() > 0.999


# ---------------------------------------------------------------- square waves
def square_error(steps: int, period: float) -> float:
    """Largest |error| of a square-wave sequence of ``steps`` frames with the realistic projector blur."""
    u_spec, n = axis_spec(0, steps, period, bits=bits_for(period), waveform="square")
    codec = make_codec(u_spec, None, n)
    opts = SimulationOptions.noise_free_16bit(
        projector_defocus_codes=SimulationOptions.realistic_8bit().projector_defocus_codes
    )
    assert default_projector_blur_px(opts) == pytest.approx(1.2)
    images = render_codec(codec, U, None, opts)
    axis = decode_codec(images, codec).axes["u"]
    return float(np.abs(axis.coordinate[axis.valid] - U[axis.valid]).max())


@pytest.mark.parametrize("period", [16.0, 32.0])
@pytest.mark.parametrize("steps", [12, 18])
def test_square_waves_with_projector_blur_n_at_least_12(steps: int, period: float) -> None:
    assert square_error(steps, period) < 0.05


@pytest.mark.slow
def test_square_wave_bias_for_small_n_is_as_documented() -> None:
    # docs/codecs.md: the aliased odd harmonics m = k N +- 1 bound the bias (1.2 px projector blur)
    for period in (16.0, 32.0, 64.0):
        for steps in (3, 4, 6, 8, 12):
            bound = square_wave_bias_px(steps, period, 1.2)
            measured = square_error(steps, period)
            assert measured < 1.05 * bound + 1e-3, (period, steps, measured, bound)
            if bound < 0.3 * period / (2 * math.pi):  # first order holds for small errors: the bound is reached
                assert measured > 0.8 * bound - 1e-3, (period, steps, measured, bound)


# ---------------------------------------------------------------- realistic 8-bit
@pytest.mark.parametrize(("steps", "word_fraction"), [(4, 0.5), (12, 0.5), (18, 1.0)])
def test_realistic_8bit_noise_matches_the_derived_limit(steps: int, word_fraction: float) -> None:
    opts = SimulationOptions.realistic_8bit()
    height, width = 120, 120
    period = 16.0
    u_fine, u_centre = affine_truth(height, width, opts.supersample, 2.0, 2.05, 0.1)
    word = period * word_fraction
    u_spec, n = axis_spec(0, steps, period, bits=bits_for(word), word=word)
    codec = make_codec(u_spec, None, n)
    repeats = []
    for seed in range(3):
        images = render_codec(codec, u_fine, None, opts, seed=seed)
        axis, valid = decode_inner(images, codec)
        error = axis.coordinate[valid] - u_centre[valid]
        far = np.abs(error) > period / 2
        assert far.mean() < 1e-4, (far.sum(), axis.slips_repaired)
        sigma_grey = math.sqrt(opts.noise_grey**2 + 1 / 12)  # camera noise and 8-bit rounding
        b = axis.modulation[valid].astype(np.float64)
        predicted = period / (2 * math.pi) * math.sqrt(2 / steps) * sigma_grey / b
        repeats.append((float(np.sqrt(np.mean(error[~far] ** 2))), float(np.sqrt(np.mean(predicted**2)))))
    measured = math.sqrt(np.mean([m**2 for m, _ in repeats]))
    limit = math.sqrt(np.mean([p**2 for _, p in repeats]))
    print(f"N={steps}: measured {measured:.4f} px, limit {limit:.4f} px, ratio {measured / limit:.3f}")
    assert measured / limit < 1.2 and measured / limit > 1 / 1.2, (measured, limit)


@pytest.mark.slow
def test_gcps_v1_codec_agrees_with_the_gcps_v1_decoder() -> None:
    """A realistic gcps-v1 capture of the virtual rig: the codec decoder's u, as light codes
    ``l = (u + 0.5) nlp / width``, equals the paper decoder's codes where both decode."""
    from metrology.core.decode import decode_stack

    rendered = render_stack(PAPER_RIG, make_scene("sphere"), SimulationOptions.realistic_8bit())
    codec = builtin_codec("gcps-v1")
    ours = decode_codec(rendered.images, codec).axes["u"]
    theirs = decode_stack(rendered.images, nlp=PAPER_RIG.nlp)
    both = ours.valid & theirs.mask
    assert both.sum() > 0.9 * theirs.mask.sum()
    codes = codec.light_codes(ours.coordinate[both].astype(np.float64), PAPER_RIG.nlp)
    assert np.abs(codes - theirs.codes[both]).max() < 2e-3


def test_float_stacks_decode_like_integer_ones() -> None:
    u_spec, n = axis_spec(0, 4, 16.0, bits=bits_for(8.0), word=8.0, inverse=True)
    codec = make_codec(u_spec, None, n)
    images = render_codec(codec, U, None).astype(np.float32) / np.float32(65535)  # [0, 1] grey
    axis = decode_codec(images, codec).axes["u"]
    lit = np.isfinite(U)
    assert axis.valid[lit].all() and not axis.valid[~lit].any()
    assert np.abs(axis.coordinate[lit] - U[lit]).max() < 0.01
    assert decode_codec(images, codec).options.saturation_level == np.inf


def test_gray_only_chain_thresholded_at_a_phase_mean() -> None:
    u_spec, n = axis_spec(0, 4, 16.0, bits=bits_for(2.0), word=2.0)
    u_spec["unwrap"] = ["gray"]
    codec = make_codec(u_spec, None, n)
    axis = decode_codec(render_codec(codec, U, None), codec).axes["u"]
    lit = np.isfinite(U)
    assert axis.valid[lit].all()
    np.testing.assert_allclose(axis.coordinate[lit], 2.0 * np.floor((U[lit] + 0.5) / 2.0) + 0.5, atol=1e-4)


def test_noisy_renders_reuse_the_noise_free_render_without_changing_an_image() -> None:
    """The renderer keeps a scene's blurred-pattern tables and noise-free frames, so a Monte Carlo
    over seeds draws only noise: every image equals the one rendered with nothing kept."""
    from metrology.core.codecs import render

    codec = builtin_codec("gcps-v1")
    u = np.linspace(-3.0, codec.projector_width + 3.0, 96 * 129).reshape(96, 129)
    options = SimulationOptions.realistic_8bit()
    kept = [render_codec(codec, u, None, options, seed=seed) for seed in (1, 2, 1)]
    render._CLEAN.clear()
    render._TABLES.clear()
    fresh = render_codec(codec, u, None, options, seed=2)
    assert np.array_equal(kept[0], kept[2]) and np.array_equal(kept[1], fresh)
    assert not np.array_equal(kept[0], kept[1])  # the noise is drawn anew
    other_scene = render_codec(codec, u + 0.25, None, options, seed=2)  # another scene: not the kept render
    assert np.abs(other_scene.astype(int) - fresh.astype(int)).max() > 10
