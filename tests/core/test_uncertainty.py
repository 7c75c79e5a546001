"""Coordinate sigma of a codec's final unwrapping stage (metrology.core.uncertainty), against the
first-order variance of the least-squares phase: ``var(theta) = (2 / N) sigma_I^2 / B^2``."""

import math

import numpy as np
import pytest

from metrology.core.codecs.model import Codec, codec_from_dict
from metrology.core.uncertainty import coordinate_sigma, stage_coordinate_sigma


def _codec(unwrap: list[str] | None, periods: tuple[float, float] = (32.0, 33.0)) -> Codec:
    axis: dict[str, object] = {
        "phase": [
            {"frames": [0, 1, 2, 3], "period": periods[0], "shift": 1, "origin": 0.0, "waveform": "sine"},
            {"frames": list(range(4, 12)), "period": periods[1], "shift": 1, "origin": 0.0, "waveform": "sine"},
        ]
    }
    if unwrap is not None:
        axis["unwrap"] = unwrap
    return codec_from_dict(
        {"codec": "gcps-codec/1", "frames": 12, "projector": {"width": 1024, "height": 768}, "axes": {"u": axis}}
    )


def test_a_chain_ending_on_a_beat_adds_the_phase_variances_over_the_beat_period() -> None:
    """theta_b = theta_s - theta_l: sigma_b = P_b / (2 pi) * sqrt(2/4 + 2/8) * sigma_I / B, P_b = 32*33/1."""
    codec = _codec(["beat:0,1"])
    noise, modulation = np.full((9, 9), 2.0, np.float32), np.full((9, 9), 100.0, np.float32)
    got = stage_coordinate_sigma(codec, "u", noise, modulation)
    expected = 1056.0 / (2 * math.pi) * math.sqrt(2 / 4 + 2 / 8) * 2.0 / 100.0
    np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_a_chain_ending_on_a_phase_sequence_is_its_n_step_sigma() -> None:
    codec = _codec(["beat:0,1", "phase:1"])
    noise, modulation = np.full((9, 9), 1.5, np.float32), np.full((9, 9), 80.0, np.float32)
    got = stage_coordinate_sigma(codec, "u", noise, modulation)
    np.testing.assert_allclose(got, 33.0 / (2 * math.pi) * math.sqrt(2 / 8) * 1.5 / 80.0, rtol=1e-6)
    np.testing.assert_allclose(got, coordinate_sigma(33.0, 8, 1.5, 80.0), rtol=1e-6)


def test_no_noise_estimate_for_three_steps_is_an_error() -> None:
    with pytest.raises(ValueError, match="steps"):
        coordinate_sigma(16.0, 2, 1.0, 100.0)
