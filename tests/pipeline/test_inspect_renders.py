"""Issue 25's "Must show" on virtual-rig renders: a nominal part placed in the rig's frame, rendered
(render_capture), measured with sigma (metrology.pipeline.measure), inspected from an automatic
start (metrology.pipeline.inspect, ``init="auto"``, nothing told).

- The part: the inspection tests' asymmetric block (60 x 40 x 20 mm with a post, a lug and a
  cone), tilted so that its top and two sides face a pinhole rig with lens distortion 600 mm
  away (a camera of 528 x 416 px seeing about 80 mm across, 0.15 mm between pixels).
- Edge rule: pixels within 2 px (8-connected dilation, 2 steps) of a pixel the renderer marks as
  a depth discontinuity (``RenderedCapture.edges``: a jump of more than ``EDGE_JUMP_MM`` to a
  4-neighbour or a lit/unlit boundary) or of an unlit pixel are excluded from the statistics
  (they still get a deviation).
- Noise-free 16-bit: every deviation (99th percentile of ``|dev|``) within 2 um; also on the
  paper's crossed-axes rig (the part on its plane R).
- Realistic 8-bit (0.25 grey levels of noise, the realistic camera's defocus and 3 x 3 sub-rays),
  a dent 0.1 mm deep and 4 mm wide planted in the top: on a flat region of the top away from the
  dent and the edges the deviations' standard deviation is within 20 % of the RMS of the
  predicted u; the dent's mean deviation within 0.5 mm of its centre is within 10 um of the
  truth's mean there (the truth: each pixel's true point's signed distance to the nominal), those
  points are nonconforming at a 0.05 mm tolerance, and the points where the truth lies within
  ``k u`` of the tolerance (the dent's flanks) include undecided ones.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.geometry.pinhole import PinholeCamera, look_at_rig
from metrology.core.inspection import alignment, conformance
from metrology.core.inspection.distance import SurfaceDistance
from metrology.core.inspection.scan import scan_from_point_map
from metrology.core.measure import MeasureOptions
from metrology.core.scenes import MeshScene
from metrology.core.simulate import ScenePlacement, SimulationOptions, render_capture
from metrology.core.simulate.parts import Defect, plant_defects
from metrology.pipeline.inspect import InspectOptions, inspect
from metrology.pipeline.measure import measure
from tests.core.inspection.parts import asymmetric_part, pose_error
from tests.pinhole_stacks import CODEC, PROJECTOR

pytestmark = pytest.mark.slow

DISTANCE_MM = 600.0


def _rig(width: int, height: int, field_mm: float):
    """The pinhole tests' projector and a camera of ``width x height`` px seeing ``field_mm`` across
    at ``DISTANCE_MM``, with lens distortion."""
    f = width * DISTANCE_MM / field_mm
    camera = PinholeCamera(
        width,
        height,
        ((f, 0.0, (width - 1) / 2 + 0.3), (0.0, 1.002 * f, (height - 1) / 2 - 0.2), (0.0, 0.0, 1.0)),
        (-0.1, 0.03, 0.0005, -0.0004, 0.0),
    )
    return look_at_rig(camera, PROJECTOR, (-220.0, 6.0, 15.0), (0.0, 0.0, DISTANCE_MM))


RIG = _rig(528, 416, 80.0)
SMALL_RIG = _rig(320, 256, 100.0)
# the part upside down (its top towards the camera) and tilted; its point (30, 20, 25) on the axis
POSE = alignment.rotation_matrix(np.array([np.pi, 0.0, 0.0])) @ alignment.rotation_matrix(np.radians([20, -15, 30]))
SHIFT = np.array([0.0, 0.0, DISTANCE_MM]) - POSE @ np.array([30.0, 20.0, 25.0])
TRUTH = alignment.rigid_transform(POSE.T, -POSE.T @ SHIFT)
"""x_nominal = TRUTH x_camera."""
DENT = Defect("dent", (31.0, 28.0, 20.0), width_mm=4.0, depth_mm=0.1)
TOLERANCE_MM, K = 0.05, 2.0


def _edges(rendered) -> np.ndarray:
    """Pixels within 2 px of a depth discontinuity or an unlit pixel (module docstring)."""
    return ndimage.binary_dilation(rendered.edges | ~rendered.lit, structure=np.ones((3, 3), bool), iterations=2)


def _run(model, scene, options, codec=None, placement=None):
    rendered = render_capture(model, scene, codec, options, placement=placement)
    reference = None
    if placement is not None and codec is None:  # the paper's rig measures against its plane R
        from metrology.core.scenes import make_scene
        from metrology.core.simulate import render_stack

        reference = render_stack(model, make_scene("reference"), options).images
    measured = measure(model, reference, rendered.images, MeasureOptions(sigma=True), codec=codec)
    points = measured.points_mm(np.float64)
    assert measured.sigma_mm is not None
    result = inspect(
        asymmetric_part(),
        scan_from_point_map(points, measured.sigma_mm),
        InspectOptions(init="auto", tolerance_mm=TOLERANCE_MM, k=K),
    )
    return rendered, result


@pytest.fixture(scope="module")
def noise_free():
    part = asymmetric_part()
    scene = MeshScene(vertices_mm=part.vertices, faces=part.faces, rotation=POSE, translation_mm=SHIFT)
    return _run(RIG, scene, SimulationOptions.noise_free_16bit(), codec_from_dict(CODEC))


@pytest.fixture(scope="module")
def realistic():
    """The realistic camera as it is (8-bit, 1.5 grey levels of noise, defocus, 3 x 3 sub-rays), a smaller view."""
    part = asymmetric_part()
    scene = MeshScene(vertices_mm=part.vertices, faces=part.faces, rotation=POSE, translation_mm=SHIFT)
    rendered, result = _run(SMALL_RIG, scene, SimulationOptions.realistic_8bit(), codec_from_dict(CODEC))
    truth_nominal = alignment.apply(TRUTH, np.nan_to_num(rendered.points_mm.reshape(-1, 3)))
    return rendered, result, truth_nominal.reshape(rendered.points_mm.shape)


@pytest.fixture(scope="module")
def dented():
    part = asymmetric_part()
    planted = plant_defects(part.vertices, part.faces, [DENT])
    scene = MeshScene(vertices_mm=planted.vertices_mm, faces=planted.faces, rotation=POSE, translation_mm=SHIFT)
    options = SimulationOptions.realistic_8bit(noise_grey=0.12)
    rendered, result = _run(RIG, scene, options, codec_from_dict(CODEC))
    truth_nominal = alignment.apply(TRUTH, np.nan_to_num(rendered.points_mm.reshape(-1, 3)))
    truth_dev = SurfaceDistance(part).deviations(truth_nominal).distance_mm.reshape(rendered.lit.shape)
    return rendered, result, truth_nominal.reshape(rendered.points_mm.shape), np.where(rendered.lit, truth_dev, np.nan)


def test_noise_free_render_inspected_within_2um(noise_free):
    rendered, result = noise_free
    deviation = result.deviation_map()
    used = np.isfinite(deviation) & ~_edges(rendered)
    rotation_deg, moved_mm = pose_error(result.fit.transform, TRUTH, asymmetric_part().vertices)
    p99 = float(np.percentile(np.abs(deviation[used]), 99))
    print(
        f"noise-free pinhole: {np.isfinite(deviation).sum()} points measured, {used.sum()} away from edges; "
        f"|dev| p99 {p99 * 1e3:.3f} um; pose {rotation_deg:.2e} deg, {moved_mm * 1e3:.3f} um; {result.timings_s}"
    )
    assert np.isfinite(deviation).sum() > 95_000
    assert result.start["method"] == "auto" and result.fit.symmetric_dof == []
    assert p99 < 2e-3
    assert rotation_deg < 1e-3 and moved_mm < 5e-3


def test_noise_free_crossed_axes_render_inspected_within_2um():
    """The paper's rig: the part on its plane R (model frame: X, Y on R, Z up), top up and turned."""
    part = asymmetric_part()
    pose = alignment.rotation_matrix(np.radians([8.0, -6.0, 35.0]))
    shift = np.array([352.0, 0.0, 2.0]) - pose @ np.array([30.0, 20.0, 0.0])
    scene = MeshScene(vertices_mm=part.vertices, faces=part.faces, rotation=pose, translation_mm=shift)
    options = SimulationOptions.noise_free_16bit()
    rendered, result = _run(PAPER_RIG, scene, options, placement=ScenePlacement.model_plane())
    deviation = result.deviation_map()
    used = np.isfinite(deviation) & ~_edges(rendered)
    truth = alignment.rigid_transform(pose.T, -pose.T @ shift)
    rotation_deg, moved_mm = pose_error(result.fit.transform, truth, part.vertices)
    p99 = float(np.percentile(np.abs(deviation[used]), 99))
    print(
        f"noise-free crossed axes: {np.isfinite(deviation).sum()} points, {used.sum()} away from edges; "
        f"|dev| p99 {p99 * 1e3:.3f} um; pose {rotation_deg:.2e} deg, {moved_mm * 1e3:.3f} um"
    )
    assert used.sum() > 1500
    assert p99 < 2e-3


@pytest.mark.parametrize("which", ["realistic", "dented"])
def test_realistic_render_deviation_spread_matches_u(which, request):
    rendered, result, truth_nominal = request.getfixturevalue(which)[:3]
    deviation = result.deviation_map()
    u = result.uncertainty_mm.reshape(deviation.shape)
    x, y, z = truth_nominal[..., 0], truth_nominal[..., 1], truth_nominal[..., 2]
    away = np.hypot(x - DENT.centre_mm[0], y - DENT.centre_mm[1]) > DENT.width_mm
    flat = np.isfinite(deviation) & ~_edges(rendered) & (np.abs(z - 20.0) < 0.2) & away
    flat &= (x > 26.0) & (x < 40.0) & (y > 3.0) & (y < 26.0)  # the top between the post, the cone and the lug
    spread, predicted = float(np.std(deviation[flat])), float(np.sqrt(np.mean(u[flat] ** 2)))
    print(f"{which} flat top: {flat.sum()} points, std {spread * 1e3:.2f} um, predicted u {predicted * 1e3:.2f} um")
    assert flat.sum() > 1500
    assert abs(spread / predicted - 1.0) < 0.2


def test_planted_dent_found_and_decided(dented):
    rendered, result, truth_nominal, truth_dev = dented
    deviation = result.deviation_map()
    u = result.uncertainty_mm.reshape(deviation.shape)
    assert result.decision is not None
    decision = result.decision.reshape(deviation.shape)
    r = np.hypot(truth_nominal[..., 0] - DENT.centre_mm[0], truth_nominal[..., 1] - DENT.centre_mm[1])
    top = np.isfinite(deviation) & (np.abs(truth_nominal[..., 2] - 20.0) < 0.2) & rendered.lit
    centre = top & (r < 0.5)
    found, truth = float(np.mean(deviation[centre])), float(np.mean(truth_dev[centre]))
    flank = top & (r < DENT.width_mm / 2) & (np.abs(np.abs(truth_dev) - TOLERANCE_MM) < K * u)
    undecided = flank & (decision == conformance.UNDECIDED)
    print(
        f"dent: {centre.sum()} points within 0.5 mm, mean deviation {found * 1e3:.2f} um, truth {truth * 1e3:.2f} um; "
        f"{flank.sum()} flank points within k u of the tolerance, {undecided.sum()} undecided"
    )
    assert np.nanmin(truth_dev[top]) == pytest.approx(-0.1, abs=2e-3)
    assert centre.sum() >= 20
    assert abs(found - truth) < 0.010
    assert np.all(decision[centre] == conformance.NONCONFORMING)
    assert undecided.sum() >= 5 and undecided.sum() >= 0.5 * flank.sum()
    # a decided point is right about the truth: no conforming point whose truth is out of tolerance
    assert not np.any(top & (decision == conformance.CONFORMING) & (np.abs(truth_dev) > TOLERANCE_MM))
