"""The gcps-v1 pattern set (docs/conventions.md) and the paper's Table 1."""

import numpy as np
import pytest

from metrology.core.patterns import (
    PATTERN_NAMES,
    binary_from_gray,
    gray_code_table,
    gray_from_binary,
    pattern_intensity,
    projector_patterns,
)

# Table 1 of the paper, n = 4 (the copy lost some cells of rows r0-r2; they follow from the code)
TABLE_1 = np.array(
    [
        [0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1],
        [0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0],
        [0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1, 0, 0],
        [0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0],
    ]
)


def test_table_1_reproduced():
    np.testing.assert_array_equal(gray_code_table(4), TABLE_1)


def test_gray_words_differ_by_one_bit():
    g = gray_from_binary(np.arange(128))
    flips = np.bitwise_count((g[1:] ^ g[:-1]).astype(np.uint8))
    assert np.all(flips == 1)


def test_gray_binary_round_trip():
    w = np.arange(128)
    np.testing.assert_array_equal(binary_from_gray(gray_from_binary(w)), w)


def test_names_and_order():
    assert PATTERN_NAMES == ("GC_0", "GC_1", "GC_2", "GC_3", "GC_4", "GC_5", "GC_6", "PS_0", "PS_1", "PS_2", "PS_3")


def test_gray_patterns_spell_the_word():
    codes = np.arange(128) + 0.5
    bits = np.stack([pattern_intensity(codes, f"GC_{k}") for k in range(7)]).astype(int)
    gray = (bits * (1 << np.arange(6, -1, -1))[:, None]).sum(axis=0)
    np.testing.assert_array_equal(binary_from_gray(gray), np.arange(128))


def test_phase_patterns_eq1():
    codes = np.linspace(0, 128, 1001)
    for i in range(4):
        expected = 0.5 + 0.5 * np.cos(np.pi / 2 * codes - i * np.pi / 2)
        np.testing.assert_allclose(pattern_intensity(codes, f"PS_{i}"), expected, atol=1e-15)
    square = pattern_intensity(codes, "PS_0", square=True)
    assert set(np.unique(square)) == {0.0, 1.0}


def test_projector_images():
    images = projector_patterns(1024, 768)
    assert images.shape == (11, 768, 1024) and images.dtype == np.uint8
    assert np.all(images[:, 0, :] == images[:, -1, :])  # fringes parallel to Y
    assert images[0, 0, 511] == 0 and images[0, 0, 512] == 255  # MSB switches mid-width


def test_bad_pattern_name():
    with pytest.raises(ValueError, match="unknown pattern name 'GC_7'"):
        pattern_intensity([1.0], "GC_7")
