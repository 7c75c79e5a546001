"""The codec self-check in measurements: every measurement carries the object's ``codec_check``
(the fused gcps-v1 path from the fused kernel's values on 8 pairs of rows), and a capture
``inconsistent`` with its codec fails with the check's message unless the options say
``allow_inconsistent_codec``."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import Codec, codec_from_dict, render_codec
from metrology.core.geometry.crossed_axes import PAPER_RIG as RIG
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, crossed_rig_truth, render_stack
from metrology.pipeline.measure import MeasureOptions, measure

PROJ_W, PROJ_H = 1024, 768


def codec(origin: float = -0.5) -> Codec:
    """u: 4-step sine of 32 px (phase origin ``origin``) + a 6-bit gray code of 16-px words; white, black."""
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 12,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "white": [10],
            "black": [11],
            "axes": {
                "u": {
                    "phase": [{"frames": [0, 1, 2, 3], "period": 32.0, "origin": origin}],
                    "gray": {"frames": list(range(4, 10)), "word": 16.0, "origin": -0.5},
                }
            },
        }
    )


@pytest.fixture(scope="module")
def renders() -> dict[str, Any]:
    options = SimulationOptions.noise_free_16bit()
    out: dict[str, Any] = {}
    for name in ("reference", "sphere"):
        rendered = render_stack(RIG, make_scene(name), options)
        u, _ = crossed_rig_truth(rendered, RIG, PROJ_W, PROJ_H)
        out[name] = (rendered.images, render_codec(codec(), u, None, options))
    return out


def test_gcps_v1_measurements_carry_a_consistent_check(renders: dict[str, Any]) -> None:
    result = measure(RIG, renders["reference"][0], renders["sphere"][0], MeasureOptions(gray_only=False))
    check = result.to_dict()["codec_check"]
    assert check["u"]["status"] == "consistent" and check["u"]["message"] == ""
    assert "measure.codec_check_s" in result.timings_s


def test_gcps_v1_with_a_wrong_stack_fails_naming_the_check(renders: dict[str, Any]) -> None:
    obj = renders["sphere"][0].copy()
    obj[7:] = obj[7:][[2, 3, 0, 1]]  # the phase frames half a turn off: the origin by half a period
    with pytest.raises(ValueError, match=r"does not match its codec.*axis u: .*allow_inconsistent_codec"):
        measure(RIG, renders["reference"][0], obj, MeasureOptions(gray_only=False))
    allowed = measure(RIG, renders["reference"][0], obj, MeasureOptions(gray_only=False, allow_inconsistent_codec=True))
    assert allowed.to_dict()["codec_check"]["u"]["status"] == "inconsistent"


def test_a_codec_capture_measures_when_consistent_and_fails_when_not(renders: dict[str, Any]) -> None:
    reference, obj = renders["reference"][1], renders["sphere"][1]
    right = measure(RIG, reference, obj, MeasureOptions(), codec=codec())
    assert right.to_dict()["codec_check"]["u"]["status"] == "consistent"
    wrong = codec(origin=-0.5 + 8.0)  # a quarter period off
    with pytest.raises(ValueError, match=r"(?i)origin should be -0\.5, not 7\.5"):
        measure(RIG, reference, obj, MeasureOptions(), codec=wrong)
    options = MeasureOptions(allow_inconsistent_codec=True)
    result = measure(RIG, reference, obj, options, codec=wrong)
    assert result.to_dict()["codec_check"]["u"]["status"] == "inconsistent"
    assert np.isfinite(result.z_mm).any()


def test_the_option_round_trips_and_is_checked() -> None:
    options = MeasureOptions(allow_inconsistent_codec=True)
    assert MeasureOptions.from_dict(copy.deepcopy(options.to_dict())) == options
    assert MeasureOptions.from_dict({}).allow_inconsistent_codec is False
    with pytest.raises(ValueError, match="allow_inconsistent_codec"):
        MeasureOptions(allow_inconsistent_codec="yes")  # type: ignore[arg-type]
