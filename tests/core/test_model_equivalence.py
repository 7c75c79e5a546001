"""The paper's crossed-axes rig and the same rig written as a pinhole rig give the same heights.

:func:`~metrology.core.geometry.crossed_axes.equivalent_pinhole` writes the paper's geometry
(Eqs. 7, 12-15) as a pinhole camera and projector. Measured through the one measurement entry
(:func:`metrology.core.measure.measure`), noise-free 16-bit gcps-v1 renders of the paper's rig give
the same heights with either model: the crossed-axes rig by the fused gcps-v1 kernel against the
captured reference's codes (Eq. 16), the pinhole rig by the codec decoder and the light planes of
u against the plane fitted to the reference capture. Tolerance 1 um (the issue's), on the pixels
both report.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.codecs import gcps_v1_codec
from metrology.core.geometry.crossed_axes import PAPER_RIG, codes_of_points, equivalent_pinhole
from metrology.core.measure import MeasureOptions, measure, prepare_reference
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack

PROJECTOR = (1024, 768)
"""The built-in gcps-v1 codec's projector: 128 light codes of 8 columns."""


def test_the_equivalent_projector_sees_the_papers_light_codes():
    pinhole = equivalent_pinhole(PAPER_RIG, *PROJECTOR)
    prepared = pinhole.prepare(pinhole.shape, PROJECTOR)
    rng = np.random.default_rng(3)
    X, Y, Z = rng.uniform(150, 550, 50), rng.uniform(-180, 180, 50), rng.uniform(0, 90, 50)
    u, _ = prepared.projector_coordinates(np.stack([X - PAPER_RIG.d_mm, Y, PAPER_RIG.L_mm - Z], axis=-1))
    np.testing.assert_allclose((u + 0.5) * PAPER_RIG.nlp / PROJECTOR[0], codes_of_points(PAPER_RIG, X, Z), atol=1e-9)
    assert pinhole.auto_axis() == "u"


@pytest.fixture(scope="module")
def reference_images() -> np.ndarray:
    return render_stack(PAPER_RIG, make_scene("reference"), SimulationOptions.noise_free_16bit()).images


@pytest.mark.parametrize(("scene", "params"), [("plane", {"z_mm": 40.0}), ("sphere", {}), ("staircase", {})])
def test_crossed_axes_and_equivalent_pinhole_heights_agree_within_1um(scene, params, reference_images):
    rendered = render_stack(PAPER_RIG, make_scene(scene, **params), SimulationOptions.noise_free_16bit())
    options = MeasureOptions(gray_only=False)
    crossed = measure(PAPER_RIG, rendered.images, reference=reference_images, options=options)
    pinhole_rig = equivalent_pinhole(PAPER_RIG, *PROJECTOR)
    codec = gcps_v1_codec(*PROJECTOR)
    kept = prepare_reference(pinhole_rig, reference_images, codec, options)
    pinhole = measure(pinhole_rig, rendered.images, codec, reference=kept, options=options)
    both = np.isfinite(crossed.z_mm) & np.isfinite(pinhole.z_mm)
    assert both.sum() > 0.8 * np.isfinite(crossed.z_mm).sum() > 0
    difference = np.abs(crossed.z_mm[both].astype(np.float64) - pinhole.z_mm[both])
    assert difference.max() < 1e-3, f"largest difference {difference.max() * 1e3:.3f} um"
    # and both are the truth (the renders are exact)
    truth = rendered.truth_mm[both]
    assert np.abs(pinhole.z_mm[both] - truth).max() < 1e-3
