"""The kernels' warm-up (metrology/core/compiled.py): what it compiles is what measurements use."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from metrology.core.compiled import STEREO_KERNEL_MODULES, warm_stereo
from metrology.core.geometry.base import GeometryOptions
from metrology.core.measure import MeasureOptions, measure
from metrology.core.scenes import make_scene
from metrology.core.simulate.stereo import render_stereo_capture
from tests.stereo_rig import CALIBRATED_RIG, PLACEMENT, PROJECTOR, RIG, codec


def compiled_signatures() -> dict[str, int]:
    """How many signatures each kernel of the stereo model's modules has compiled (or loaded)."""
    counts = {}
    for name in STEREO_KERNEL_MODULES:
        for attribute, value in vars(importlib.import_module(name)).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == name:
                counts[f"{name}.{attribute}"] = len(value.overloads)
    return counts


@pytest.mark.slow
def test_after_warm_stereo_measuring_another_rig_and_scene_compiles_nothing_more() -> None:
    """``warm_stereo`` measures a tiny rig of its own; measuring the tests' 320x256 rig (another size,
    distortion, projector and plane), with a u-only and a two-axis codec, both matches, with and
    without a calibrated projector and sigma, then adds no signature to any stereo kernel: the test
    script's warm-up leaves the pytest workers nothing to compile."""
    warm_stereo()
    warmed = compiled_signatures()
    assert sum(warmed.values()) >= 10, warmed  # the entry kernels of both matches, the fusion, the depths
    plane = make_scene("plane", z_mm=10.0)
    for axes, match in (("u", "epipolar"), ("uv", "2d")):
        the_codec = codec(axes)
        capture = render_stereo_capture(CALIBRATED_RIG, plane, the_codec, placement=PLACEMENT, projector=PROJECTOR)
        for rig in (RIG, CALIBRATED_RIG):
            for sigma in (False, True):
                options = MeasureOptions(geometry=GeometryOptions(match=match), sigma=sigma)
                assert np.isfinite(measure(rig, capture.images, the_codec, options=options).z_mm).mean() > 0.5
    assert compiled_signatures() == warmed
