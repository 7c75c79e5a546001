"""Multi-level gray codes: base-L reflected gray digits shown as grey levels d / (L - 1), L = 2..8.

- the code: neighbouring words differ in one digit by one level; L = 2 is ``n ^ (n >> 1)``;
- validation names the field (levels, levels ** digits, inverse frames and ``inverted``);
- noise-free 16-bit round trips (L = 3, 4, 8; white/black or phase references) within 0.01 px;
- the projector's gamma 2.2 still decodes a 4-level code (level centres from the data);
- realistic 8-bit renders: the coordinate scatter at the decoder's own noise estimate, no pixel
  a period off, and few refused;
- a wrong level count in the description refuses the axis with a message naming the field.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import Codec, CodecError, codec_from_dict, codec_patterns, render_codec
from metrology.core.codecs.decode import REASON_LEVEL_AMBIGUOUS, decode_codec
from metrology.core.codecs.gray import centre_lut, gray_digits, words_from_gray
from metrology.core.simulate import SimulationOptions
from metrology.core.uncertainty import stage_coordinate_sigma
from tests.core.codecs.roundtrips import PROJ_W, affine_truth, assert_round_trip, multilevel_codec, truth_maps

U, V = truth_maps()


# ---------------------------------------------------------------- the code
@pytest.mark.parametrize("levels", [2, 3, 4, 5, 8])
def test_reflected_gray_digits(levels: int) -> None:
    digits = 3
    n = np.arange(levels**digits)
    g = gray_digits(n, levels, digits)
    assert g.shape == (n.size, digits) and g.min() == 0 and g.max() == levels - 1
    # neighbours differ in one digit by one level; every word is distinct; the inverse recovers n
    np.testing.assert_array_equal(np.abs(np.diff(g, axis=0)).sum(axis=1), 1)
    assert len({tuple(row) for row in g}) == n.size
    np.testing.assert_array_equal(words_from_gray(g, levels), n)
    if levels == 2:
        np.testing.assert_array_equal(g @ (2 ** np.arange(digits - 1, -1, -1)), n ^ (n >> 1))
    # the rule: digit i is b_i when the higher gray digits sum to an even number, else L - 1 - b_i
    b = np.stack([(n // levels ** (digits - 1 - i)) % levels for i in range(digits)], axis=-1)
    higher = np.cumsum(g, axis=1) - g
    np.testing.assert_array_equal(g, np.where(higher % 2 == 0, b, levels - 1 - b))


def test_centre_lut_indexes_by_gray_digits() -> None:
    codec = multilevel_codec(3, 4, 8.0)
    gray = codec.axes["u"].gray
    assert gray is not None
    lut = centre_lut(gray)
    n = np.arange(81)
    index = gray_digits(n, 3, 4) @ (3 ** np.arange(3, -1, -1))
    np.testing.assert_allclose(lut[index], -0.5 + (n + 0.5) * 8.0)


def test_patterns_show_the_grey_levels() -> None:
    codec = multilevel_codec(4, 3, 4.0, period=None)
    images = codec_patterns(codec)
    assert set(np.unique(images[:3]).tolist()) == {0, 85, 170, 255}
    # column x lies in word n = floor((x + 0.5) / 4); frame 0 (msb first) shows its most significant gray digit
    x = np.arange(PROJ_W)
    n = np.floor((x + 0.5) / 4).astype(int)
    np.testing.assert_array_equal(images[0, 0], np.round(255 * gray_digits(n, 4, 3)[:, 0] / 3))
    np.testing.assert_array_equal(images[2, 0], np.round(255 * gray_digits(n, 4, 3)[:, 2] / 3))


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"levels": 1}, r"axes.u.gray.levels must be an integer from 2 to 8, got 1"),
        ({"levels": 9}, r"axes.u.gray.levels must be an integer from 2 to 8, got 9"),
        ({"levels": "4"}, r"axes.u.gray.levels must be an integer from 2 to 8, got '4'"),
        ({"levels": 3.0}, r"axes.u.gray.levels must be an integer"),
        ({"inverted": True}, r"axes.u.gray.inverted applies to levels = 2 only, not 4"),
    ],
)
def test_bad_levels_name_the_field(change: dict[str, Any], message: str) -> None:
    data = multilevel_codec(4, 3, 8.0).to_dict()
    data["axes"]["u"]["gray"].update(change)
    with pytest.raises(CodecError, match=message):
        codec_from_dict(data)


def test_too_many_words_and_inverse_frames_are_refused() -> None:
    with pytest.raises(CodecError, match=r"axes.u.gray.frames: 6 digits of 8 levels make 262144 words"):
        multilevel_codec(8, 6, 1.0)
    data = multilevel_codec(4, 3, 8.0).to_dict()
    data["frames"] += 3
    data["axes"]["u"]["gray"]["inverse_frames"] = [data["frames"] - 3, data["frames"] - 2, data["frames"] - 1]
    with pytest.raises(CodecError, match=r"axes.u.gray.inverse_frames applies to levels = 2 only, not 4"):
        codec_from_dict(data)


def test_levels_round_trip_through_json_and_binary_stays_as_it_was() -> None:
    codec = multilevel_codec(4, 3, 8.0)
    data = codec.to_dict()
    assert data["axes"]["u"]["gray"]["levels"] == 4
    assert codec_from_dict(data) == codec
    binary = multilevel_codec(2, 5, 8.0)
    assert "levels" not in binary.to_dict()["axes"]["u"]["gray"]


# ---------------------------------------------------------------- noise-free round trips
@pytest.mark.parametrize(("levels", "digits"), [(3, 4), (4, 3), (8, 2)])
@pytest.mark.parametrize("white_black", [True, False])
@pytest.mark.parametrize("order", ["msb_first", "lsb_first"])
def test_noise_free_round_trip(levels: int, digits: int, white_black: bool, order: str) -> None:
    codec = multilevel_codec(levels, digits, 8.0, white_black=white_black, order=order)
    assert_round_trip(codec, U, V)


def test_noise_free_round_trip_of_the_v_axis_with_gamma() -> None:
    codec = multilevel_codec(4, 3, 4.0, period=8.0, axis="v")
    assert_round_trip(codec, U, V, options=SimulationOptions(projector_gamma=2.2))


def test_gray_only_multilevel_axis_gives_the_word_centre() -> None:
    codec = multilevel_codec(4, 4, 1.0, period=None)
    axis = decode_codec(render_codec(codec, U, None), codec).axes["u"]
    lit = np.isfinite(U)
    assert axis.valid[lit].all() and not axis.valid[~lit].any()
    np.testing.assert_array_equal(axis.coordinate[lit], np.floor(U[lit] + 0.5))


@pytest.mark.parametrize("white_black", [True, False])
def test_projector_gamma_2_2_decodes_a_4_level_code(white_black: bool) -> None:
    # levels emitted at (d / 3)^2.2 = 0, 0.089, 0.41, 1: thresholds at (d + 1/2) / 3 would misread digit 1
    codec = multilevel_codec(4, 3, 8.0, white_black=white_black)
    images = render_codec(codec, U, None, SimulationOptions(projector_gamma=2.2))
    decoded = decode_codec(images, codec)
    levels = decoded.summary()["gray_levels"]["u"]
    assert levels["status"] == "estimated"
    if white_black:
        np.testing.assert_allclose(levels["centres"], [(d / 3) ** 2.2 for d in range(4)], atol=2e-3)
    axis = decoded.axes["u"]
    lit = np.isfinite(U)
    assert axis.valid[lit].mean() > 0.999
    # the 8-step phase of a gamma-distorted sinusoid keeps a small harmonic bias
    assert np.abs(axis.coordinate[axis.valid] - U[axis.valid]).max() < 0.01


# ---------------------------------------------------------------- realistic 8-bit
def realistic_case(codec: Codec, gamma: float = 1.0, seed: int = 0) -> tuple[Any, np.ndarray, np.ndarray]:
    """A realistic 8-bit render of an affine map of ~1 projector px per camera px: (axis, valid, error)."""
    opts = SimulationOptions.realistic_8bit(projector_gamma=gamma)
    u_fine, u_centre = affine_truth(30, 200, opts.supersample, 20.0, 1.0, 0.1)
    axis, valid = decode_inner_lenient(render_codec(codec, u_fine, None, opts, seed=seed), codec)
    return axis, valid, axis.coordinate[valid] - u_centre[valid]


def decode_inner_lenient(images: np.ndarray, codec: Codec) -> tuple[Any, np.ndarray]:
    """Decode; the valid pixels 3 px from the border (the caller says how many must be valid)."""
    axis = decode_codec(images, codec).axes["u"]
    inner = np.zeros(axis.coordinate.shape, bool)
    inner[3:-3, 3:-3] = True
    return axis, axis.valid & inner


@pytest.mark.parametrize(("levels", "digits"), [(3, 4), (4, 3), (8, 2)])
def test_realistic_noise_at_the_decoders_estimate(levels: int, digits: int) -> None:
    codec = multilevel_codec(levels, digits, 8.0)
    measured, predicted = [], []
    for seed in range(2):
        axis, valid, error = realistic_case(codec, seed=seed)
        inner_count = (axis.coordinate.shape[0] - 6) * (axis.coordinate.shape[1] - 6)
        # digits near a threshold at blurred word edges read the neighbouring word: kept (the
        # 16-px phase unwraps either reading of 8-px words alike)
        assert valid.sum() > 0.999 * inner_count
        assert np.abs(error).max() < 8.0  # no pixel half a period off
        sigma = stage_coordinate_sigma(codec, "u", axis.noise, axis.modulation)[valid].astype(np.float64)
        measured.append(float(np.mean(error**2)))
        predicted.append(float(np.mean(sigma**2)))
    ratio = math.sqrt(np.mean(measured) / np.mean(predicted))
    print(f"L={levels}: scatter {math.sqrt(np.mean(measured)):.4f} px, estimate {math.sqrt(np.mean(predicted)):.4f} px")
    assert 1 / 1.2 < ratio < 1.2


def test_realistic_gamma_2_2_decodes_a_4_level_code() -> None:
    _, valid, error = realistic_case(multilevel_codec(4, 3, 8.0), gamma=2.2)
    assert valid.sum() > 0.999 * (24 * 194)
    assert np.abs(error).max() < 1.0


# ---------------------------------------------------------------- a wrong level count
@pytest.mark.parametrize(
    ("true_levels", "true_digits", "described", "shown"),
    [
        (4, 3, 3, "at least 4"),
        (3, 4, 4, "3 separable grey levels"),
        (8, 2, 4, "at least 5"),
        (2, 5, 4, "2 separable grey levels"),
        (4, 3, 8, "4 separable grey levels"),
    ],
)
def test_a_wrong_level_count_is_refused_naming_the_field(
    true_levels: int, true_digits: int, described: int, shown: str
) -> None:
    truth = multilevel_codec(true_levels, true_digits, 8.0)
    wrong = multilevel_codec(described, true_digits, 8.0)
    decoded = decode_codec(render_codec(truth, U, None), wrong)
    axis = decoded.axes["u"]
    lit = np.isfinite(U)
    assert not axis.valid.any()
    assert (axis.reason[lit] == REASON_LEVEL_AMBIGUOUS).all()
    levels = decoded.summary()["gray_levels"]["u"]
    assert levels["status"] == "refused"
    assert f"axes.u.gray.levels = {described}" in levels["message"] and shown in levels["message"]
    assert levels["levels_shown"] == int(shown.split()[-1] if shown.startswith("at least") else shown.split()[0])


@pytest.mark.parametrize(("true_levels", "described"), [(4, 3), (3, 4), (2, 4)])
def test_a_wrong_level_count_is_refused_on_realistic_renders(true_levels: int, described: int) -> None:
    digits = {2: 5, 3: 4, 4: 3}[true_levels]
    truth = multilevel_codec(true_levels, digits, 8.0)
    wrong = multilevel_codec(described, digits, 8.0)
    opts = SimulationOptions.realistic_8bit()
    u_fine, _ = affine_truth(30, 200, opts.supersample, 20.0, 1.0, 0.1)
    decoded = decode_codec(render_codec(truth, u_fine, None, opts), wrong)
    assert not decoded.axes["u"].valid.any()
    assert "axes.u.gray.levels" in decoded.summary()["gray_levels"]["u"]["message"]


def test_ambiguous_digits_are_refused_without_a_phase_to_settle_them() -> None:
    # word = period: a digit read as its neighbour's moves the pixel by a whole period, so digits
    # near a threshold are refused (reason 7); with the phase at twice the word they are kept
    opts = SimulationOptions.realistic_8bit()
    u_fine, _ = affine_truth(30, 200, opts.supersample, 20.0, 1.0, 0.1)
    refused = {}
    for period in (8.0, 16.0):
        codec = multilevel_codec(4, 3, 8.0, period=period)
        axis = decode_codec(render_codec(codec, u_fine, None, opts), codec).axes["u"]
        refused[period] = float((axis.reason[3:-3, 3:-3] == REASON_LEVEL_AMBIGUOUS).mean())
    assert refused[8.0] > 0.01 and refused[16.0] < 0.001, refused
