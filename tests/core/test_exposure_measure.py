"""Multi-exposure captures measured (issue 26, docs/exposures.md): on the virtual rig's high-dynamic-
range scene (a specular patch on a dark matte part, 1000:1), single exposures measure at most
85 % of the lit pixels, three fused exposures at least 99 % at the noise predicted for the exposures
used; noise-free 16-bit renders saturating at 65535 within 1 um; a multi-exposure object against a
single-exposure reference and the reverse on the paper's crossed-axes rig."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from metrology.core.codecs.stack import ExposureStack
from metrology.core.filters import FilterOptions
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.io.exposures import Exposure
from metrology.core.measure import MeasureOptions, measure
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, SimulationOptions
from metrology.core.simulate.exposures import HdrReflectance, render_exposures
from tests.core.exposure_scene import CODEC, EXPOSURES, NOISE_GREY, RIG, Z0


def test_hdr_reflectance_spans_1000_to_1() -> None:
    rho = HdrReflectance(x0_mm=0.0, x1_mm=10.0, patch_x_mm=5.0, patch_y_mm=0.0, patch_radius_mm=1.0)
    assert rho.dynamic_range == pytest.approx(1000.0)
    values = rho(np.array([-1.0, 0.0, 10.0, 5.0]), np.array([0.0, 3.0, 3.0, 0.5]))
    np.testing.assert_allclose(values, [0.001, 0.001, 0.03, 1.0])


@pytest.fixture(scope="module")
def realistic() -> Any:
    """8-bit, 1.5 grey levels of noise, 3x3 sub-rays, projector blur; no camera defocus (a 0.7 px
    defocus spills the patch's light onto the matte pixels around it: docs/exposures.md)."""
    options = SimulationOptions.realistic_8bit(seed=3, camera_defocus_px=0.0)
    return render_exposures(
        RIG, make_scene("plane"), EXPOSURES, CODEC, options, placement=ScenePlacement.facing_camera(Z0)
    )


def _points(result: Any) -> np.ndarray:
    return result.points_mm().astype(np.float64)


def test_each_single_exposure_measures_at_most_85_percent(realistic: Any) -> None:
    lit = realistic.truth.lit
    assert np.nanmax(realistic.reflectance) / np.nanmin(realistic.reflectance) >= 990  # the lit part spans ~1000:1
    for images in realistic.stack.images:
        options = MeasureOptions(allow_inconsistent_codec=True)
        measured = np.isfinite(measure(RIG, images, CODEC, options=options).z_mm) & lit
        assert measured.sum() <= 0.85 * lit.sum()


def test_three_fused_exposures_measure_99_percent_at_the_predicted_noise(realistic: Any) -> None:
    lit = realistic.truth.lit
    result = measure(RIG, realistic.stack, CODEC, options=MeasureOptions(sigma=True))
    points = _points(result)
    measured = np.isfinite(points[..., 2]) & lit
    assert measured.sum() >= 0.99 * lit.sum()
    truth = realistic.truth.points_mm
    error_3d = np.linalg.norm(points - truth, axis=-1)[measured]
    assert np.count_nonzero(error_3d > 1.0) <= 1e-4 * measured.sum()
    # the error along the ray against the sigma of the exposure each pixel used, at the render's
    # noise (sigma scales with the decoder's noise estimate: sigma * NOISE_GREY / noise)
    along = np.abs(np.linalg.norm(points, axis=-1) - np.linalg.norm(truth, axis=-1))[measured]
    decoded = result.decoding.axes["u"]
    assert result.sigma_mm is not None
    predicted = (result.sigma_mm * (NOISE_GREY / decoded.noise))[measured]
    ratio = float(np.median(along / predicted)) / 0.6745  # a unit normal's median |x| is 0.6745
    assert ratio <= 1.15, ratio
    used = np.bincount(result.decoding.exposure["u"][measured], minlength=3)
    assert (used[:3] > 0.1 * measured.sum()).all()  # every exposure measures its share


@pytest.mark.parametrize("scene", ["plane", "sphere", "staircase"])
def test_noise_free_16_bit_multi_exposure_within_a_micrometre(scene: str) -> None:
    rendered = render_exposures(
        RIG, make_scene(scene), EXPOSURES, CODEC, SimulationOptions(), placement=ScenePlacement.facing_camera(Z0)
    )
    saturated = [(images == 65535).any(axis=0).mean() for images in rendered.stack.images]
    assert saturated[0] == 0 and saturated[1] > 0.1 and saturated[2] > 0.3  # the longer exposures saturate
    result = measure(RIG, rendered.stack, CODEC, options=MeasureOptions(filters=FilterOptions(edge_band_px=0)))
    points = _points(result)
    measured = np.isfinite(points[..., 2]) & rendered.truth.lit
    assert measured.mean() > 0.85
    error = np.linalg.norm(points - rendered.truth.points_mm, axis=-1)[measured]
    assert error.max() < 1e-3


SMALL_PAPER_RIG = PAPER_RIG.with_parameters(width_px=160, height_px=120, fw_mm=160 * 0.78125)


@pytest.mark.parametrize("multi", ["object", "reference", "both"])
def test_multi_and_single_exposure_captures_measure_together_on_the_paper_rig(multi: str) -> None:
    """gcps-v1 on a crossed-axes rig: a multi-exposure capture goes through the codec path (the
    fused gcps-v1 kernel reads single stacks) and gives the single stacks' heights."""
    exposures = (Exposure("short", 1000.0), Exposure("long", 2000.0))
    options = SimulationOptions()
    obj = render_exposures(SMALL_PAPER_RIG, make_scene("sphere", SMALL_PAPER_RIG), exposures, None, options)
    ref = render_exposures(SMALL_PAPER_RIG, make_scene("reference", SMALL_PAPER_RIG), exposures, None, options)
    single = measure(SMALL_PAPER_RIG, obj.stack.images[0], reference=ref.stack.images[0])
    obj_capture = obj.stack if multi in ("object", "both") else obj.stack.images[0]
    ref_capture = ref.stack if multi in ("reference", "both") else ref.stack.images[0]
    fused = measure(SMALL_PAPER_RIG, obj_capture, reference=ref_capture)
    assert fused.decoding is not None and fused.decoding.exposure_names
    both = np.isfinite(single.z_mm) & np.isfinite(fused.z_mm)
    assert both.sum() > 0.8 * np.isfinite(single.z_mm).sum()
    assert np.abs(single.z_mm[both] - fused.z_mm[both]).max() < 1e-3
    assert isinstance(obj.stack, ExposureStack)


def test_exposures_rendered_from_a_kept_cast_are_those_cast_anew() -> None:
    """``render_exposures(cast=cast_exposures(...))`` (the virtual camera's HDR frames at each
    exposure of a bracket) gives, bit for bit, the images and truth of a render that casts the scene
    itself; a cast of another sub-pixel count is refused."""
    from metrology.core.simulate.exposures import cast_exposures

    scene = make_scene("plane", z_mm=0.0)
    where = ScenePlacement.facing_camera(Z0)
    options = SimulationOptions.realistic_8bit(seed=5, supersample=2)
    cast = cast_exposures(RIG, scene, CODEC, 2, where)
    anew = render_exposures(RIG, scene, EXPOSURES, CODEC, options, placement=where)
    kept = render_exposures(RIG, scene, EXPOSURES, CODEC, options, placement=where, cast=cast)
    assert len(kept.stack.images) == len(EXPOSURES)
    for got, want in zip(kept.stack.images, anew.stack.images, strict=True):
        assert np.ptp(want) > 100
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(kept.truth.points_mm, anew.truth.points_mm)
    with pytest.raises(ValueError, match="per pixel side"):
        render_exposures(RIG, scene, EXPOSURES, CODEC, options.with_changes(supersample=1), placement=where, cast=cast)
