"""The stereo model through the one measurement path, on the virtual rig (issue 24).

Noise-free 16-bit renders through a distorted stereo rig whose projector is not calibrated (the
render takes a projector of its own, distorted too): the points of a plane, a sphere and a
staircase, with vertical fringes only and with both axes coded, lie within 1 um of the truth
(median) and 5 um (99th percentile) on the measured pixels whose surface faces both cameras within
60 degrees. Realistic 8-bit renders of a plane: the predicted sigma is the scatter within 20 %.
The matching and the sampling are checked on hand-worked rows and maps.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from metrology.core.codecs import Codec, codec_from_dict
from metrology.core.codecs.decode import decode_codec
from metrology.core.geometry.base import GeometryError, GeometryOptions
from metrology.core.geometry.stereo_kernels import SAMPLE_TRIANGLE
from metrology.core.geometry.stereo_match import Bilinear, match_rows, prepare_stereo
from metrology.core.measure import MeasureOptions, measure
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions
from metrology.core.simulate.render import default_placement
from metrology.core.simulate.stereo import ProjectorPlacement, StereoCapture, cast_stereo, render_stereo_capture
from metrology.core.uncertainty import stage_coordinate_sigma
from tests.stereo_rig import PLACEMENT, PROJECTOR, RIG, codec, facing_both, lit_in_both, turned_projector

SCENES = {"plane": {"z_mm": 0.0}, "sphere": {"radius_mm": 50.0}, "staircase": {}}


# --------------------------------------------------------------------------- hand-worked pieces
def test_a_row_is_matched_inside_its_monotone_run_without_pixel_locking():
    u1 = np.array([[10.0, 12.0, 14.0, 16.0, 18.0]], np.float32)
    u0 = np.array([[11.0, 12.5, 13.0, 17.9]], np.float32)
    m = match_rows(u0, u1, 0.0, 100.0)
    np.testing.assert_allclose(m.x1[0], [0.5, 1.25, 1.5, 3.95], atol=1e-6)
    np.testing.assert_allclose(m.slope[0], 2.0)


def test_ambiguous_and_inconsistent_matches_are_refused():
    # camera 1's row folds back over two pixels: 13 lies in two segments (x 1..2 and 4..5), 21 in one
    u1 = np.array([[10.0, 12.0, 14.0, 16.0, 12.5, 13.5, 20.0, 22.0]], np.float32)
    u0 = np.array([[13.0, 21.0]], np.float32)
    m = match_rows(u0, u1, 0.0, 100.0)
    assert np.isnan(m.x1[0, 0]) and m.x1[0, 1] == pytest.approx(6.5)
    # camera 0's row folds back over two pixels after its first: 19, 20, 15 and 17 would match back
    # to two places of it (left-right inconsistent); 11 and 21 are unique there
    u0 = np.array([[11.0, 19.0, 20.0, 15.0, 17.0, 21.0]], np.float32)
    u1 = np.array([[10.0, 12.0, 14.0, 16.0, 18.0, 20.0, 22.0]], np.float32)
    m = match_rows(u0, u1, 0.0, 100.0)
    assert m.x1[0, 0] == pytest.approx(0.5) and m.x1[0, 5] == pytest.approx(5.5)
    assert np.isnan(m.x1[0, 1:5]).all()
    # undecoded neighbours never give a position
    u1 = np.array([[10.0, np.nan, 14.0, 16.0]], np.float32)
    m = match_rows(np.array([[11.0, 15.0]], np.float32), u1, 0.0, 100.0)
    assert np.isnan(m.x1[0, 0]) and m.x1[0, 1] == pytest.approx(2.5)


def test_a_bending_row_is_matched_by_its_cubic_not_its_chord():
    """Inside a monotone run the position solves the cubic through four samples: exact for a cubic
    row, where linear interpolation errs by ``s (1 - s) u'' / (2 u')`` (0.012 px mid-segment here);
    at the run's ends (no outer sample) the parabola through three samples."""
    x = np.arange(10, dtype=np.float64)
    row = 10 + 2 * x + 0.05 * x**2 + 0.002 * x**3
    want = np.array([0.5, 2.25, 4.5, 6.75, 8.5])
    q = 10 + 2 * want + 0.05 * want**2 + 0.002 * want**3
    m = match_rows(q[None].astype(np.float32), row[None].astype(np.float32), 0.0, 100.0)
    np.testing.assert_allclose(m.x1[0, 1:4], want[1:4], atol=2e-5)  # cubic: exact
    np.testing.assert_allclose(m.x1[0, [0, 4]], want[[0, 4]], atol=2e-3)  # parabola at the ends
    chord = 4 + (q[2] - row[4]) / (row[5] - row[4])
    assert abs(chord - 4.5) > 0.005  # what linear interpolation gave
    slope = 2 + 0.1 * want[1:4] + 0.006 * want[1:4] ** 2
    np.testing.assert_allclose(m.slope[0, 1:4], slope, rtol=1e-4)  # the slope at the match
    # a run of two samples (undecoded around it) stays linear
    m = match_rows(np.array([[11.0]], np.float32), np.array([[np.nan, 10.0, 14.0, np.nan]], np.float32), 0.0, 100.0)
    assert m.x1[0, 0] == pytest.approx(1.25)


@pytest.mark.parametrize("outlier", [40.0, 1.0])
def test_an_isolated_out_of_order_value_refuses_itself_only(outlier: float) -> None:
    """One spike (or dip) in a monotone row, in either camera, is refused alone: before the fix a
    spike refused every pixel right of it (none was above it), a dip every pixel left of it."""
    ramp = np.arange(10.0, 30.0, 2.0, dtype=np.float32)  # 10, 12, ..., 28 at x 0..9
    q = np.arange(10.5, 27.5, 2.0, dtype=np.float32)  # 10.5, 12.5, ..., 26.5: x1 = 0.25, 1.25, ...
    want = (q - 10.0) / 2.0
    # camera 0: pixel 4 (18.5) replaced by the outlier
    u0 = q.copy()
    u0[4] = outlier
    m = match_rows(u0[None], ramp[None], 0.0, 100.0)
    assert np.isnan(m.x1[0, 4])
    np.testing.assert_allclose(np.delete(m.x1[0], 4), np.delete(want, 4), atol=1e-6)
    # camera 1: pixel 5 (20) replaced: the two segments beside it give nothing, the rest as before
    u1 = ramp.copy()
    u1[5] = outlier
    m = match_rows(q[None], u1[None], 0.0, 100.0)
    lost = (want > 4) & (want < 6)  # the segments x 4..5 and 5..6
    assert lost.sum() == 2 and np.isnan(m.x1[0, lost]).all()
    np.testing.assert_allclose(m.x1[0, ~lost], want[~lost], atol=1e-6)


def test_sampling_is_exact_for_a_quadratic_map_and_never_blends_nan():
    yy, xx = np.mgrid[0:12, 0:15].astype(np.float64)
    image = (3 + 0.5 * xx - 0.25 * yy + 0.02 * xx * xx + 0.03 * xx * yy - 0.01 * yy * yy).astype(np.float32)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(1.2, 12.8, 200), rng.uniform(1.2, 9.8, 200)
    sampler = Bilinear.at(x, y, image.shape)
    got = sampler.sample(image, curvature=True)
    want = 3 + 0.5 * x - 0.25 * y + 0.02 * x * x + 0.03 * x * y - 0.01 * y * y
    np.testing.assert_allclose(got, want, atol=2e-5)
    holed = image.copy()
    holed[5, 7] = np.nan
    near = Bilinear.at(np.array([6.5, 7.0, 3.0]), np.array([4.5, 5.0, 3.0]), image.shape).sample(holed)
    assert np.isnan(near[0]) and np.isnan(near[1]) and np.isfinite(near[2])
    outside = Bilinear.at(np.array([-0.1, 14.0]), np.array([3.0, 11.0]), image.shape).sample(image)
    assert np.isnan(outside[0]) and np.isfinite(outside[1])


def test_the_parabolic_terms_hold_at_the_edges_and_beside_missing_samples():
    """Where a sample beyond the cell is missing (the image's edge, an undecoded pixel) the second
    differences are one-sided, so the sampling stays exact for a quadratic map there too; bilinear
    interpolation alone would err by up to ``(c_xx + c_yy) / 8`` = 0.015 here (on the 160x120 rig's
    noise-free sphere that was 32 um of depth at the cap's edge: docs/stereo.md)."""
    yy, xx = np.mgrid[0:12, 0:15].astype(np.float64)
    image = (3 + 0.5 * xx - 0.25 * yy + 0.02 * xx * xx + 0.03 * xx * yy + 0.04 * yy * yy).astype(np.float32)
    holed = image.copy()
    holed[5, 7] = np.nan  # beyond the cells right of, left of, above and below it
    holed[2, 0:4] = np.nan  # beyond the cells below this row
    holed[6, 2] = np.nan  # with the image's edge, on both sides of the cell (0..1, 6..7) along its top row
    # edges left, right, top, bottom; beside the holes; the lower row's curvature; inside
    x = np.array([0.3, 13.6, 6.5, 4.4, 8.5, 5.6, 7.2, 7.2, 0.5, 2.6, 0.5, 5.5])
    y = np.array([4.5, 7.2, 0.4, 10.7, 5.5, 5.4, 3.5, 6.3, 3.5, 3.4, 6.5, 9.6])
    want = 3 + 0.5 * x - 0.25 * y + 0.02 * x * x + 0.03 * x * y + 0.04 * y * y
    bilinear = Bilinear.at(x, y, image.shape).sample(holed)
    assert np.abs(bilinear - want).max() > 3e-3  # what the parabolic terms must remove at these positions
    got = Bilinear.at(x, y, image.shape).sample(holed, curvature=True)
    np.testing.assert_allclose(got, want, atol=2e-5)


def test_a_sample_with_one_neighbour_missing_takes_the_plane_of_the_other_three():
    """Camera maps are rectified with :data:`SAMPLE_TRIANGLE`: a cell with one undecoded pixel gives
    the plane through its other three (exact for an affine map), a cell with two gives NaN."""
    yy, xx = np.mgrid[0:10, 0:12].astype(np.float64)
    image = (7 + 0.75 * xx - 0.5 * yy).astype(np.float32)
    holed = image.copy()
    holed[4, 5] = np.nan
    x, y = np.array([4.3, 5.6, 4.9, 5.2, 6.5]), np.array([3.2, 3.7, 4.8, 4.4, 6.5])
    got = Bilinear.at(x, y, image.shape, SAMPLE_TRIANGLE).sample(holed)
    np.testing.assert_allclose(got, 7 + 0.75 * x - 0.5 * y, atol=2e-5)
    assert np.isnan(Bilinear.at(x, y, image.shape).sample(holed)[:4]).all()  # the strict sampling: NaN
    holed[4, 6] = np.nan  # the cell (5..6, 3..4) now lacks two
    assert np.isnan(Bilinear.at(np.array([5.5]), np.array([3.5]), image.shape, SAMPLE_TRIANGLE).sample(holed)).all()


def test_every_decoded_camera0_pixel_camera1_sees_is_matched():
    """Exact projector coordinates of a plane (the cast, no decoding), about 0.8 % of each camera's
    pixels dropped at random, each alone (a cluster of dropped camera-1 pixels still costs the
    camera-0 pixels matched into it: docs/stereo.md): the resampling chain (camera 0's map onto the
    rectified grid and the disparity back) needs four decoded neighbours, so it loses camera 0's
    border and the neighbours of every dropped pixel; those pixels are matched at their own
    positions (docs/stereo.md). Every decoded
    camera-0 pixel whose point camera 1 sees on a decoded pixel (1 px inside its border) is
    measured, the points within 1 um (median) and 5 um (99th percentile) of the truth."""
    scene = make_scene("plane", z_mm=0.0)
    cast = cast_stereo(RIG, scene, codec("u"), PLACEMENT, projector=PROJECTOR)
    rng = np.random.default_rng(5)
    maps = []
    for truth in cast.truths:
        u = truth.u.astype(np.float32)
        drop = rng.random(u.shape) < 0.01
        alone = ndimage.convolve(drop.astype(np.int32), np.ones((5, 5), np.int32), mode="constant") == 1
        u[drop & alone] = np.nan  # isolated: no other dropped pixel within 2 px
        maps.append(u)
    truth = cast.truths[0].points_mm
    seen = lit_in_both(truth, np.isfinite(maps[0]), np.isfinite(maps[1]))
    prepared = prepare_stereo(RIG, "u")
    points = np.empty((*RIG.shape, 3), np.float32)
    prepared.triangulate_rows(
        slice(0, RIG.shape[0]), prepared.combine([{"u": maps[0]}, {"u": maps[1]}]).u, None, points_out=points
    )
    measured = np.isfinite(points[..., 2])
    assert not (measured & np.isnan(maps[0])).any()  # camera 0's undecoded pixels stay unmeasured
    missed = seen & ~measured
    print(f"{seen.sum()} px seen by both, {missed.sum()} not measured")
    assert missed.sum() <= 5e-4 * seen.sum()  # 18 of 80349: partners within a pixel of camera 1's border
    error = np.linalg.norm(points.astype(np.float64) - truth, axis=-1)[seen & measured]
    assert np.median(error) <= 1e-3 and np.percentile(error, 99) <= 5e-3


# --------------------------------------------------------------------------- the virtual rig
@pytest.mark.parametrize(
    "scene",
    [
        "plane",
        pytest.param("sphere", marks=pytest.mark.slow),
        pytest.param("staircase", marks=pytest.mark.slow),
    ],
)
@pytest.mark.parametrize("axes", ["u", "uv"])
def test_noise_free_renders_measure_within_1um(scene: str, axes: str) -> None:
    the_scene = make_scene(scene, **SCENES[scene])
    the_codec = codec(axes)
    capture = render_stereo_capture(RIG, the_scene, the_codec, placement=PLACEMENT, projector=PROJECTOR)
    m = measure(RIG, capture.images, the_codec)
    assert m.z_kind == "depth" and m.z_mm.shape == RIG.shape
    points = m.points_mm().astype(np.float64)
    assert np.array_equal(np.isnan(points).any(axis=-1), np.isnan(m.z_mm))
    truth = capture.points_mm
    judged = facing_both(the_scene, truth) & np.isfinite(m.z_mm)
    facing = facing_both(the_scene, truth)
    assert judged.sum() > 0.75 * facing.sum() > 0, f"{judged.sum()} of {facing.sum()} facing pixels measured"
    error = np.linalg.norm(points - truth, axis=-1)[judged]
    median, p99 = np.median(error), np.percentile(error, 99)
    print(f"{scene} {axes}: {judged.sum()} px, median {median * 1e3:.3f} um, p99 {p99 * 1e3:.3f} um")
    assert median <= 1e-3 and p99 <= 5e-3
    # the depth is camera 0's Z
    np.testing.assert_allclose(m.z_mm[judged], points[judged][:, 2], rtol=1e-6)


def test_the_wide_rig_measures_a_plane_within_its_sampling_bound() -> None:
    """The wide 160x120 rig (focal lengths 160 px: pixels of 3.1 mm at 500 mm), as the application
    renders it: the scene facing camera 0, the default projector aimed at camera 0's field. Camera
    1's decoded coordinate bends along its rectified rows by ``|u''/u'|`` = 0.0012 / px here (0.0072
    / px with the projector aimed 352 mm off camera 0's axis, as it was), so linear interpolation
    between its pixels would misplace the matches by up to ``u''/(8 u')`` px, 1.6 um of depth at
    10.4 mm per px (9.4 um before; 7.5 um median measured). The cubic of the monotone run leaves
    0.06 um median and 0.23 um at the 99th percentile (0.98 um when the resampling lost its
    parabolic terms at the image's edge; docs/stereo.md, "The wide rig")."""
    from tests.app.stereo_stacks import WIDE_CODEC, WIDE_RIG

    the_codec = codec_from_dict(WIDE_CODEC)
    scene = make_scene("plane", z_mm=0.0)
    capture = render_stereo_capture(WIDE_RIG, scene, the_codec, placement=default_placement(WIDE_RIG))
    truth = capture.points_mm
    assert np.isfinite(truth).all(axis=-1).mean() > 0.95  # the projector lights camera 0's field
    m = measure(WIDE_RIG, capture.images, the_codec)
    facing = facing_both(scene, truth)
    judged = facing & np.isfinite(m.z_mm)
    assert judged.sum() > 0.85 * facing.sum() > 0
    error = np.linalg.norm(m.points_mm().astype(np.float64) - truth, axis=-1)[judged]
    median, p99 = np.median(error), np.percentile(error, 99)
    print(f"wide plane: {judged.sum()} px, median {median * 1e3:.3f} um, p99 {p99 * 1e3:.3f} um")
    assert median <= 0.2e-3 and p99 <= 0.5e-3


@pytest.mark.parametrize(
    "scene",
    ["plane", pytest.param("sphere", marks=pytest.mark.slow), pytest.param("staircase", marks=pytest.mark.slow)],
)
def test_the_2d_match_without_rectification_measures_within_1um(scene: str) -> None:
    """Both axes coded, ``match="2d"``: each camera-0 pixel's (u, v) found in camera 1's image
    (no rectification, no resampling of camera 0), the rays meeting by their midpoint."""
    the_scene = make_scene(scene, **SCENES[scene])
    the_codec = codec("uv")
    capture = render_stereo_capture(RIG, the_scene, the_codec, placement=PLACEMENT, projector=PROJECTOR)
    options = MeasureOptions(geometry=GeometryOptions(match="2d"))
    m = measure(RIG, capture.images, the_codec, options=options)
    points = m.points_mm().astype(np.float64)
    truth = capture.points_mm
    facing = facing_both(the_scene, truth)
    judged = facing & np.isfinite(m.z_mm)
    assert judged.sum() > 0.75 * facing.sum() > 0, f"{judged.sum()} of {facing.sum()} facing pixels measured"
    error = np.linalg.norm(points - truth, axis=-1)[judged]
    median, p99 = np.median(error), np.percentile(error, 99)
    print(f"2d {scene}: {judged.sum()} px, median {median * 1e3:.3f} um, p99 {p99 * 1e3:.3f} um")
    assert median <= 1e-3 and p99 <= 5e-3
    with pytest.raises(ValueError, match="does not code the projector's v axis"):
        measure(RIG, capture.images, codec("u"), options=options)


def _sigma_fit(
    the_codec: Codec, options: MeasureOptions, seed: int, projector: ProjectorPlacement = PROJECTOR, n: int = 10
) -> tuple[float, int, float, StereoCapture]:
    """``n`` realistic 8-bit renders of a plane (one cast, noise drawn anew from ``seed``) measured
    with ``options`` (sigma on): the median over pixels of the predicted sigma over the per-pixel
    scatter of the depth along camera 0's ray, the pixels measured in every render, the median
    scatter (mm) and the last capture."""
    simulation = SimulationOptions.realistic_8bit()
    scene = make_scene("plane", z_mm=0.0)
    cast = cast_stereo(RIG, scene, the_codec, PLACEMENT, projector=projector, supersample=simulation.supersample)
    ranges = np.empty((n, *RIG.shape), np.float32)
    predicted = np.empty((n, *RIG.shape), np.float32)
    for i in range(n):
        noisy = SimulationOptions.realistic_8bit(seed=seed + i)
        capture = render_stereo_capture(RIG, scene, the_codec, noisy, placement=PLACEMENT, cast=cast)
        m = measure(RIG, capture.images, the_codec, options=options)
        ranges[i] = np.linalg.norm(m.points_mm(), axis=-1)
        assert m.sigma_mm is not None
        predicted[i] = m.sigma_mm
    ok = np.isfinite(ranges).all(axis=0)
    assert ok.mean() > 0.5
    observed = ranges[:, ok].astype(np.float64).std(axis=0, ddof=1)
    ratio = np.median(predicted[:, ok], axis=0) / observed
    return float(np.median(ratio)), int(ok.sum()), float(np.median(observed)), capture


@pytest.mark.slow
def test_predicted_sigma_matches_the_scatter_of_realistic_renders() -> None:
    """10 realistic 8-bit renders of a plane (one cast, noise drawn anew): the predicted per-point
    sigma (both cameras' decoder noise -> the disparity's sigma -> along camera 0's ray) is the
    observed per-pixel scatter of the depth along the ray within 20 % (median over pixels)."""
    ratio, count, observed, _ = _sigma_fit(codec("u"), MeasureOptions(sigma=True), 500)
    print(f"predicted/observed {ratio:.3f} over {count} px, sigma {observed * 1e3:.1f} um")
    assert abs(ratio - 1) < 0.2


@pytest.mark.slow
def test_the_2d_match_sigma_reads_each_axis_noise() -> None:
    """10 realistic 8-bit renders of a plane with both axes coded, ``v`` with fringes three times as
    wide as ``u``'s (its decoder sigma 2.5 times ``u``'s), the projector turned 45 degrees about its
    axis so that both axes' noise moves the 2-D match's disparity: the predicted sigma, from each
    camera's and axis's decoder sigma, is the per-pixel scatter of the depth along the ray within 20 %
    (median over pixels). Taking ``v``'s noise equal to ``u``'s (the model's fallback without
    ``other_sigma``) predicted 0.55 times the scatter here; the measured noise, 1.04 times."""
    the_codec = codec("uv", {"v": 48.0})
    assert prepare_stereo(RIG, "u", "2d").noise_axes == ("u", "v")
    options = MeasureOptions(sigma=True, geometry=GeometryOptions(match="2d"))
    ratio, count, observed, capture = _sigma_fit(the_codec, options, 700, turned_projector(45.0))
    decoded = decode_codec(capture.images[0], the_codec, with_noise=True).axes
    sigma_u, sigma_v = (stage_coordinate_sigma(the_codec, a, decoded[a].noise, decoded[a].modulation) for a in "uv")
    ratio_v = float(np.nanmedian(sigma_v) / np.nanmedian(sigma_u))
    print(
        f"2d, v sigma {ratio_v:.2f} x u's, projector turned 45 deg: predicted/observed {ratio:.3f} "
        f"over {count} px, sigma {observed * 1e3:.1f} um"
    )
    assert ratio_v > 2.0, f"v's decoder sigma is {ratio_v:.2f} times u's"
    assert abs(ratio - 1) < 0.2


def test_a_single_camera_model_refuses_the_2d_match() -> None:
    pinhole = PROJECTOR.pinhole_rig(RIG.camera0, np.eye(3), np.zeros(3))
    size = (pinhole.projector.width, pinhole.projector.height)
    pinhole.check_codec(size, ("u", "v"), GeometryOptions())
    with pytest.raises(GeometryError, match="match '2d' is for stereo rigs"):
        pinhole.check_codec(size, ("u", "v"), GeometryOptions(match="2d"))
    assert GeometryOptions.from_dict(GeometryOptions(match="2d").to_dict()).match == "2d"
    with pytest.raises(ValueError, match="match must be one of"):
        GeometryOptions(match="3d")


def test_renders_of_kept_casts_are_those_cast_anew() -> None:
    """A kept cast rendered again (its albedo maps kept between renders) gives the images of a
    render with nothing kept, bit for bit: two casts of two scenes of different reflectances
    alternated (each render finds the other's albedo kept, or its own)."""
    from metrology.core.simulate import frames

    the_codec = codec("u")
    scenes = (make_scene("plane", z_mm=0.0), make_scene("plane", z_mm=5.0, reflectance=0.5))
    casts = [cast_stereo(RIG, scene, the_codec, PLACEMENT, projector=PROJECTOR) for scene in scenes]
    options = [SimulationOptions(bit_depth=8, noise_grey=1.5, seed=seed) for seed in (1, 2)]
    anew = {}
    for k, (scene, cast) in enumerate(zip(scenes, casts, strict=True)):
        for seed, noisy in enumerate(options):
            frames._ALBEDOS.clear()
            rendered = render_stereo_capture(RIG, scene, the_codec, noisy, placement=PLACEMENT, cast=cast)
            anew[k, seed] = rendered.images
    for seed, noisy in enumerate(options):
        for k, (scene, cast) in enumerate(zip(scenes, casts, strict=True)):
            kept = render_stereo_capture(RIG, scene, the_codec, noisy, placement=PLACEMENT, cast=cast)
            for got, want in zip(kept.images, anew[k, seed], strict=True):
                assert np.ptp(want) > 100
                np.testing.assert_array_equal(got, want)
