"""Acceptance on realistic virtual captures (issue 2, "Must show"): 8-bit, 1.5 grey levels of
noise, slight defocus, 500 mm field, 640x480, every scene with depth discontinuities."""

import numpy as np
import pytest
from scipy import ndimage

from metrology.core.filters import FilterOptions
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.measure import MeasureOptions, measure, prepare_reference
from metrology.core.precision import height_sigma_mm, median_abs_error_mm
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack

NOISE_GREY = 1.5
SCENES = ["plane", "block", "staircase", "sphere", "two_spheres", "face", "flowerpot"]


@pytest.fixture(scope="module")
def reference_images():
    rendered = render_stack(PAPER_RIG, make_scene("reference", PAPER_RIG), SimulationOptions.realistic_8bit(seed=11))
    return rendered.images


@pytest.fixture(scope="module")
def reference(reference_images):
    return prepare_reference(PAPER_RIG, reference_images)


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_realistic_capture_meets_acceptance(reference, reference_images, scene):
    rendered = render_stack(PAPER_RIG, make_scene(scene, PAPER_RIG), SimulationOptions.realistic_8bit(seed=12))
    result = measure(PAPER_RIG, rendered.images, reference=reference)
    z, truth = result.z_mm, rendered.truth_mm
    reported = np.isfinite(z)
    truly_valid = np.isfinite(truth)

    # fewer than 1 reported pixel in 10,000 off by more than 1 mm (reported where the truth has
    # no height counts as off)
    off = reported & (~truly_valid | (np.abs(z - truth) > 1.0))
    assert off.sum() < 1e-4 * reported.sum(), f"{off.sum()} of {reported.sum()} pixels off by > 1 mm"

    # at least 99 % of truly valid pixels measured outside a 3-pixel band along shadows, field
    # edges (the image border is the coded field's edge on the reference) and discontinuities
    seeds = rendered.edges | ~truly_valid
    seeds[[0, -1], :] = seeds[:, [0, -1]] = True
    band = ndimage.binary_dilation(seeds, ndimage.generate_binary_structure(2, 1), iterations=3)
    core = truly_valid & ~band
    assert reported[core].mean() >= 0.99

    # median absolute error within 1.2x of the phase-noise limit (precision.py)
    both = reported & truly_valid
    sigma = height_sigma_mm(
        PAPER_RIG,
        reference.codes[both],
        result.codes[both],
        _modulation(reference_images)[both],
        _modulation(rendered.images)[both],
        NOISE_GREY,
    )
    limit = median_abs_error_mm(sigma)
    measured = float(np.median(np.abs(z[both] - truth[both])))
    assert measured <= 1.2 * limit, f"median |error| {measured * 1e3:.1f} um vs limit {limit * 1e3:.1f} um"
    assert 0.05 < limit < 0.1  # ~75 um on this rig: the derivation's order of magnitude


def _modulation(images):
    i = images[7:].astype(np.float32)
    return np.hypot(i[1] - i[3], i[0] - i[2])


@pytest.mark.slow
def test_gray_code_only_vs_gcps_resolution_on_the_flowerpot(reference):
    """The paper's Fig. 11: GCPS resolves the decoration (0.4 mm ridges) that gray code cannot."""
    scene = make_scene("flowerpot", PAPER_RIG)
    rendered = render_stack(PAPER_RIG, scene, SimulationOptions.realistic_8bit(seed=13))
    result = measure(PAPER_RIG, rendered.images, reference=reference)
    ok = np.isfinite(result.z_mm) & np.isfinite(result.gray_z_mm) & np.isfinite(rendered.truth_mm)
    gcps_rms = float(np.sqrt(np.mean((result.z_mm - rendered.truth_mm)[ok] ** 2)))
    gray_rms = float(np.sqrt(np.mean((result.gray_z_mm - rendered.truth_mm)[ok] ** 2)))
    # gray code quantises to one code word (~3.9 mm on R, ~11 mm in height): ~3 mm rms;
    # GCPS is at the phase-noise limit, ~0.1 mm rms
    assert gcps_rms < 0.15
    assert gray_rms > 10 * gcps_rms


@pytest.mark.slow
def test_sphere_probing_error_vdi_vde_2634(reference):
    """Issue 3: a sphere of radius 50 mm at realistic noise, probing error size under 50 um; form
    error reported with and without the standard's 0.3 % outlier rejection."""
    from metrology.core.acceptance import points_from_height_map, probing_error

    rendered = render_stack(
        PAPER_RIG, make_scene("sphere", PAPER_RIG, radius_mm=50.0), SimulationOptions.realistic_8bit(seed=21)
    )
    z = measure(PAPER_RIG, rendered.images, reference=reference).z_mm
    on_sphere = np.isfinite(z) & (rendered.truth_mm > 0.5)
    result = probing_error(points_from_height_map(PAPER_RIG, z, mask=on_sphere), 100.0)
    assert abs(result["size_error_mm"]) < 0.050
    assert result["form_error_rejected_mm"] < result["form_error_mm"]
    assert result["n_rejected"] == pytest.approx(0.003 * result["n_points"], abs=2)


def _off_and_coverage(z: np.ndarray, rendered) -> tuple[int, int, float]:
    """Pixels reported off by more than 1 mm (or where the truth has no height), pixels reported,
    and the fraction of truly valid pixels reported outside a 3-pixel band along shadows, field
    edges and discontinuities (as in test_realistic_capture_meets_acceptance)."""
    truth = rendered.truth_mm
    reported, truly_valid = np.isfinite(z), np.isfinite(truth)
    off = reported & (~truly_valid | (np.abs(z - truth) > 1.0))
    seeds = rendered.edges | ~truly_valid
    seeds[[0, -1], :] = seeds[:, [0, -1]] = True
    band = ndimage.binary_dilation(seeds, ndimage.generate_binary_structure(2, 1), iterations=3)
    core = truly_valid & ~band
    return int(off.sum()), int(reported.sum()), float(reported[core].mean())


@pytest.fixture(scope="module")
def references_by_camera():
    """Reference planes of the realistic camera, area-sampled (the default) and centre-sampled."""
    return {
        sampling: prepare_reference(
            PAPER_RIG,
            render_stack(
                PAPER_RIG,
                make_scene("reference", PAPER_RIG),
                SimulationOptions.realistic_8bit(seed=11, camera_sampling=sampling),
            ).images,
        )
        for sampling in ("area", "centre")
    }


@pytest.mark.slow
@pytest.mark.parametrize(
    ("sampling", "step_mm"),
    [
        ("centre", 10.0),  # issue 9 item 8: 34 of 289,898 off before; 0 of 288,163 after, coverage 99.999 %
        ("centre", 5.0),  # 465 of 298,156 off before (15.6 in 10,000); 0 of 291,035 after, 100 %
        ("area", 5.0),  # 985 of 298,333 off before (33 in 10,000); 2 of 290,711 after, 100 %
    ],
)
def test_mixed_pixels_at_risers_are_dropped_whatever_the_camera_model(references_by_camera, sampling, step_mm):
    """Issue 9 item 8, "Must show": a staircase seen by the realistic camera (8-bit, 1.5 grey
    levels of noise, 640x480, projector blur 0.15 code, camera blur 0.7 px), rendered by
    sampling each pixel at its centre and then blurring with the Gaussian (or averaging its area,
    the default camera, for 5 mm risers): fewer than 1 reported pixel in 10,000 off by more than
    1 mm, and at least 99 % of the truly valid pixels reported outside a 3-pixel band at the
    risers. The filter without the blur-bias bound (max_blur_bias_codes = 0, the filter before
    the issue) fails the first criterion on every one of these renders."""
    options = SimulationOptions.realistic_8bit(seed=12, camera_sampling=sampling)
    rendered = render_stack(PAPER_RIG, make_scene("staircase", PAPER_RIG, step_height_mm=step_mm), options)
    reference = references_by_camera[sampling]

    off, reported, coverage = _off_and_coverage(measure(PAPER_RIG, rendered.images, reference=reference).z_mm, rendered)
    assert off < 1e-4 * reported, f"{off} of {reported} pixels off by > 1 mm"
    assert coverage >= 0.99

    unbounded = MeasureOptions(filters=FilterOptions(max_blur_bias_codes=0.0))
    before = measure(PAPER_RIG, rendered.images, reference=reference, options=unbounded).z_mm
    off_before, reported_before, _ = _off_and_coverage(before, rendered)
    assert off_before >= 1e-4 * reported_before, f"{off_before} of {reported_before} off without the bound"
