"""A stereo rig with a calibrated projector: the camera-projector pairs fused with the camera pair
(issue 24, Deliver 1 and the second half of "Realistic renders").

The rig of ``tests/stereo_rig.py`` with its projector calibrated (the one that lights the renders):
each pair's equations against the exact truth, noise-free renders measured within 1 um (median) and
5 um (99th percentile), the pixels camera 1 cannot see (behind the risers of a staircase) measured by
camera 0 and the projector alone, and the fused cloud's scatter over realistic renders of a plane
against the camera pair's, at the ratio the error model predicts. Each through both matches: the
epipolar one (vertical fringes) and the 2-D one (``match="2d"``, both axes coded), which feed the
same fusion.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metrology.core.codecs import Codec
from metrology.core.distortion import project_normalized
from metrology.core.geometry.base import GeometryOptions
from metrology.core.geometry.stereo_fusion import (
    PAIR_CAMERA0_PROJECTOR,
    PAIR_CAMERA1_PROJECTOR,
    PAIR_CAMERAS,
    pair_combination,
    points_per_pairs,
)
from metrology.core.measure import MeasureOptions, measure
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions
from metrology.core.simulate.stereo import ProjectorPlacement, cast_stereo, render_stereo_capture
from tests.stereo_rig import CALIBRATED_RIG, PLACEMENT, PROJECTOR, RIG, codec, facing_both

ALL = PAIR_CAMERAS | PAIR_CAMERA0_PROJECTOR | PAIR_CAMERA1_PROJECTOR


def test_the_pairs_map_names_its_combinations() -> None:
    assert pair_combination(ALL) == "camera0-camera1+camera0-projector+camera1-projector"
    assert pair_combination(PAIR_CAMERA0_PROJECTOR) == "camera0-projector" and pair_combination(0) == "none"
    pairs = np.array([[0, 1, 7], [2, 7, 7]], np.uint8)
    assert points_per_pairs(pairs) == {
        "camera0-camera1": 1,
        "camera0-projector": 1,
        "camera0-camera1+camera0-projector+camera1-projector": 3,
    }


def test_each_pair_gives_the_true_depth_from_true_inputs() -> None:
    """The camera 0 - projector plane (the pinhole model's code) and camera 1's ray meeting it (the
    closed form of stereo_fusion's docstring), fed the exact projector coordinate and disparity of
    points on a tilted plane, give their depth to float32 rounding."""
    prepared = CALIBRATED_RIG.prepare()
    fusion = prepared.fusion  # type: ignore[attr-defined]
    assert fusion is not None and RIG.prepare().fusion is None  # type: ignore[attr-defined]
    xn, yn = prepared.xn, prepared.yn  # type: ignore[attr-defined]
    t = 480.0 + 0.2 * xn * 500.0 - 0.1 * yn * 500.0  # camera Z of a tilted plane, mm
    points = np.stack([t * xn, t * yn, t], axis=-1)
    q = prepared.projector_coordinates(points)[0].astype(np.float32)  # type: ignore[attr-defined]
    inside = np.isfinite(q)
    assert inside.mean() > 0.9
    t0p, xp = fusion.camera0_projector(q)
    d = prepared.k.astype(np.float64) / t  # type: ignore[attr-defined]
    t1p = fusion.camera1_projector(slice(0, RIG.shape[0]), xp, d)
    for name, got in (("camera 0 - projector", t0p), ("camera 1 - projector", t1p)):
        error = np.abs(got - t)[inside]
        print(f"{name}: median {np.median(error) * 1e3:.3f} um, max {error.max() * 1e3:.3f} um")
        assert np.isfinite(error).all() and np.median(error) < 1e-4 and error.max() < 5e-4, name


MATCHES = ["epipolar", "2d"]
"""The matches that feed the fusion; the 2-D one reads a codec of both axes."""


def _codec_options(match: str) -> tuple[Codec, MeasureOptions]:
    """The codec a match reads (``"u"`` epipolar, ``"uv"`` 2-D) and the measurement options naming it."""
    return codec("uv" if match == "2d" else "u"), MeasureOptions(geometry=GeometryOptions(match=match))


@pytest.mark.parametrize("match", MATCHES)
@pytest.mark.parametrize("scene", ["plane", pytest.param("sphere", marks=pytest.mark.slow)])
def test_noise_free_fused_points_within_1um(scene: str, match: str) -> None:
    the_scene = make_scene(scene, **({"z_mm": 0.0} if scene == "plane" else {"radius_mm": 50.0}))
    the_codec, options = _codec_options(match)
    capture = render_stereo_capture(CALIBRATED_RIG, the_scene, the_codec, placement=PLACEMENT, projector=PROJECTOR)
    m = measure(CALIBRATED_RIG, capture.images, the_codec, options=options)
    pairs = m.pairs_map()
    assert pairs is not None and pairs.dtype == np.uint8
    assert np.array_equal(pairs > 0, np.isfinite(m.z_mm))
    truth = capture.points_mm
    judged = facing_both(the_scene, truth) & np.isfinite(m.z_mm)
    assert (pairs[judged] == ALL).mean() > 0.8  # the three pairs measured most facing pixels
    error = np.linalg.norm(m.points_mm(np.float64) - truth, axis=-1)[judged]
    median, p99 = np.median(error), np.percentile(error, 99)
    print(f"fused {scene} ({match}): {judged.sum()} px, median {median * 1e3:.3f} um, p99 {p99 * 1e3:.3f} um")
    assert median <= 1e-3 and p99 <= 5e-3
    # the uncalibrated rig measures the camera pair alone: the pixels of bit 0, and fewer
    alone = measure(RIG, capture.images, the_codec, options=options)
    assert alone.points_per_pairs() == {"camera0-camera1": int(np.isfinite(alone.z_mm).sum())}
    assert np.array_equal(pairs & PAIR_CAMERAS > 0, np.isfinite(alone.z_mm))
    assert np.isfinite(m.z_mm).sum() > np.isfinite(alone.z_mm).sum()


@pytest.mark.parametrize("match", MATCHES)
def test_pixels_camera1_does_not_see_are_measured_from_camera0_and_the_projector(match: str) -> None:
    """A staircase of 20 mm risers: behind each riser a band of camera 0's pixels is hidden from
    camera 1 (at x = +150 mm) but lit by the projector (at x = +75 mm). The camera pair measures
    none of them; with the calibrated projector they are measured by camera 0 and the projector."""
    scene = make_scene("staircase", step_height_mm=20.0)
    the_codec, options = _codec_options(match)
    capture = render_stereo_capture(CALIBRATED_RIG, scene, the_codec, placement=PLACEMENT, projector=PROJECTOR)
    truth = capture.points_mm
    # hidden: the truth's projection into camera 1 lands where camera 1 sees another point
    R, T = np.asarray(RIG.R), np.asarray(RIG.T)
    in1 = truth @ R.T + T
    cam1 = RIG.camera1
    with np.errstate(invalid="ignore", divide="ignore"):
        x, y = project_normalized(
            np.asarray(cam1.K), cam1.distortion, in1[..., 0] / in1[..., 2], in1[..., 1] / in1[..., 2]
        )
    h1, w1 = RIG.camera_shapes[1]
    inside = (x >= 0) & (x <= w1 - 1) & (y >= 0) & (y <= h1 - 1)
    j = np.clip(np.rint(np.nan_to_num(x)), 0, w1 - 1).astype(int)
    k = np.clip(np.rint(np.nan_to_num(y)), 0, h1 - 1).astype(int)
    seen = capture.cameras[1].points_mm[k, j]
    hidden = inside & np.isfinite(truth).all(axis=-1) & ~(np.linalg.norm(seen - in1, axis=-1) < 2.0)
    assert hidden.sum() > 1000
    alone = measure(RIG, capture.images, the_codec, options=options)
    assert np.isfinite(alone.z_mm[hidden]).sum() == 0
    m = measure(CALIBRATED_RIG, capture.images, the_codec, options=options)
    pairs = m.pairs_map()
    assert pairs is not None
    measured = hidden & np.isfinite(m.z_mm)
    assert measured.sum() > 0.6 * hidden.sum()
    assert (pairs[measured] == PAIR_CAMERA0_PROJECTOR).all()
    error = np.linalg.norm(m.points_mm(np.float64) - truth, axis=-1)[measured]
    print(
        f"hidden from camera 1 ({match}): {hidden.sum()} px, {measured.sum()} measured, median "
        f"{np.median(error) * 1e3:.3f} um, p99 {np.percentile(error, 99) * 1e3:.3f} um"
    )
    assert np.median(error) <= 1e-3 and np.percentile(error, 99) <= 5e-3


@pytest.mark.slow
@pytest.mark.parametrize("match", MATCHES)
def test_the_fused_scatter_is_the_predicted_fraction_of_the_camera_pairs(match: str) -> None:
    """20 realistic 8-bit renders of a plane (one cast, noise drawn anew), each measured with the
    projector calibrated (fused) and not (the camera pair): per pixel the scatter of the range along
    camera 0's ray; the fused scatter is no higher than the pair's, the ratio of the two (median over
    pixels) within 10 % of the ratio of their predicted sigmas, and each sigma (the pair's, the fused)
    predicts its scatter within 20 %."""
    options = SimulationOptions.realistic_8bit()
    scene = make_scene("plane", z_mm=0.0)
    the_codec, measure_options = _codec_options(match)
    measure_options = measure_options.with_sigma()
    cast = cast_stereo(RIG, scene, the_codec, PLACEMENT, projector=PROJECTOR, supersample=options.supersample)
    n = 20
    ranges = {name: np.empty((n, *RIG.shape)) for name in ("pair", "fused")}
    predicted = {name: np.empty((n, *RIG.shape)) for name in ("pair", "fused")}
    for i in range(n):
        noisy = SimulationOptions.realistic_8bit(seed=900 + i)
        capture = render_stereo_capture(RIG, scene, the_codec, noisy, placement=PLACEMENT, cast=cast)
        for name, rig in (("pair", RIG), ("fused", CALIBRATED_RIG)):
            m = measure(rig, capture.images, the_codec, options=measure_options)
            assert m.sigma_mm is not None
            ranges[name][i] = np.linalg.norm(m.points_mm(np.float64), axis=-1)
            predicted[name][i] = m.sigma_mm
    ok = np.isfinite(ranges["pair"]).all(axis=0) & np.isfinite(ranges["fused"]).all(axis=0)
    assert ok.mean() > 0.5
    observed = {name: r[:, ok].std(axis=0, ddof=1) for name, r in ranges.items()}
    sigma = {name: np.median(p[:, ok], axis=0) for name, p in predicted.items()}
    observed_ratio = float(np.median(observed["fused"] / observed["pair"]))
    predicted_ratio = float(np.median(sigma["fused"] / sigma["pair"]))
    fused_fit = float(np.median(sigma["fused"] / observed["fused"]))
    pair_fit = float(np.median(sigma["pair"] / observed["pair"]))
    print(
        f"{match}: fused/pair scatter {observed_ratio:.3f} (predicted {predicted_ratio:.3f}) over {ok.sum()} px; "
        f"pair {np.median(observed['pair']) * 1e3:.1f} um, fused {np.median(observed['fused']) * 1e3:.1f} um, "
        f"predicted/observed pair {pair_fit:.3f}, fused {fused_fit:.3f}"
    )
    assert observed_ratio <= 1.0
    assert abs(observed_ratio / predicted_ratio - 1) < 0.1
    assert abs(fused_fit - 1) < 0.2 and abs(pair_fit - 1) < 0.2
    # where camera 1 does not see (the edge of camera 0's field): camera 0 and the projector alone
    # (camera 0's border rows and columns that camera 1 sees are the camera pair's, matched directly)
    edge = np.isfinite(ranges["fused"]).all(axis=0) & np.isnan(ranges["pair"]).all(axis=0)
    assert edge.sum() > 200
    edge_scatter = ranges["fused"][:, edge].std(axis=0, ddof=1)
    edge_fit = float(np.median(np.median(predicted["fused"][:, edge], axis=0) / edge_scatter))
    scatter_um = np.median(edge_scatter) * 1e3
    print(f"camera 0 - projector alone: {edge.sum()} px, {scatter_um:.1f} um, predicted/observed {edge_fit:.3f}")
    assert abs(edge_fit - 1) < 0.2


@pytest.mark.parametrize("match", MATCHES)
def test_the_projectors_rows_matched_between_the_cameras_are_fused_too(match: str) -> None:
    """The projector turned 90 degrees about its axis, so its rows (v) run along the cameras'
    baseline: a codec of v alone (both axes for the 2-D match), matched on v (``triangulate='v'``:
    the light planes of v), measures a noise-free plane through the three pairs within 1 um (median)
    and 5 um (99th percentile); camera 0 and the projector alone measure the pixels camera 1 does
    not match."""
    R0 = np.asarray(PROJECTOR.R, np.float64)
    centre = -R0.T @ np.asarray(PROJECTOR.T, np.float64)
    turned = np.stack([R0[1], -R0[0], R0[2]])  # x' = y, y' = -x: the rows now run along camera 0's x
    T = -turned @ centre
    projector = ProjectorPlacement(projector=PROJECTOR.projector, R=turned, T=T)
    rig = replace(
        CALIBRATED_RIG,
        projector=replace(CALIBRATED_RIG.projector, R=tuple(map(tuple, turned)), T=tuple(T)),
    )
    the_codec = codec("uv" if match == "2d" else "v")
    options = MeasureOptions(geometry=GeometryOptions(match=match, triangulate="v"))
    scene = make_scene("plane", z_mm=0.0)
    capture = render_stereo_capture(rig, scene, the_codec, placement=PLACEMENT, projector=projector)
    m = measure(rig, capture.images, the_codec, options=options)
    counts = m.points_per_pairs()
    measured = np.isfinite(m.z_mm)
    error = np.linalg.norm(m.points_mm(np.float64) - capture.points_mm, axis=-1)[measured]
    print(f"v matched ({match}): {measured.sum()} px, {counts}, median {np.median(error) * 1e3:.3f} um")
    assert counts.get(pair_combination(ALL), 0) > 0.9 * measured.sum() and counts.get("camera0-projector", 0) > 100
    assert np.median(error) <= 1e-3 and np.percentile(error, 99) <= 5e-3
