"""Procam calibration on virtual-rig board renders of a known distorted pinhole rig (issue 13 must-shows).

8 chessboard poses (9x6 inner corners, 20 mm squares) placed the way a careful user places them:
each brings the board's outer corner as near as both images allow to a point on the projector
image's edge (:func:`~metrology.core.procam.virtual.plan_board_poses`), tilted by 20 to 30
degrees in four directions and turned by 20 to 25 degrees in its plane, 330 to 690 mm away. They
are rendered through the pinhole virtual rig with realistic 8-bit noise (1.5 grey levels, camera
and projector defocus, 2x2 sub-rays), coded by an 8-step phase (period 32 px) + gray code on both
axes. The calibration must give: focal lengths within 0.2 %, principal points within 1 px, the
distortion's point displacements within 0.1 px over the WHOLE image of both devices (a 41 x 31
grid), the rotation within 0.05 degrees and the baseline within 0.1 %. The camera never sees the
projector image's top 48 to 133 px (12 % of it) at 300 to 1000 mm, so the projector's distortion
there is extrapolated whatever the poses. Then each failure cause, produced on purpose, gives its
warning, the coverage warning among them for the 8 central poses this test used before.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from metrology.core.distortion import project_normalized
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.procam import calibrate_procam, parse_board
from metrology.core.procam.calibrate import PoseObservation
from metrology.core.procam.observe import observe_pose
from metrology.core.procam.virtual import (
    BoardPose,
    board_in_view,
    edge_angles_deg,
    render_board,
    true_corners,
)

from .virtual_rig import (
    BOARD,
    CAMERA,
    CENTRAL,
    CODEC,
    OPTIONS,
    PROJECTOR,
    RIG,
    make_codec,
    plane_flatness_mm,
    planned_poses,
    pose,
    rendered_pose,
)

# the renders of the poses are shared with tests/pipeline/test_pipeline_procam.py (virtual_rig.rendered_pose)
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("procam-board-renders")]


@pytest.fixture(scope="module")
def rendered() -> tuple[list[PoseObservation], np.ndarray]:
    observations = []
    first_images = None
    for i in range(len(planned_poses())):
        images = rendered_pose(i)
        if i == 0:
            first_images = images
        observations.append(observe_pose(f"pose{i}", images, CODEC, BOARD))
    assert first_images is not None
    return observations, first_images


def fresh(observations: list[PoseObservation]) -> list[PoseObservation]:
    return [replace(p, reason=None, cause=None) for p in observations]


def calibrate(observations: list[PoseObservation], board=BOARD, size=(1024, 768)):  # type: ignore[no-untyped-def]
    return calibrate_procam(fresh(observations), board, (800, 600), size, fix_k3=True)


def displacement(K: np.ndarray, dist: tuple[float, ...] | list[float], xn: np.ndarray, yn: np.ndarray) -> np.ndarray:
    from metrology.core.distortion import Distortion, check_dist

    u, v = project_normalized(K, Distortion(check_dist(list(dist) or None)), xn, yn)
    return np.stack([u - (K[0, 0] * xn + K[0, 2]), v - (K[1, 1] * yn + K[1, 2])], axis=-1)


def distortion_error_px(got, truth) -> float:  # type: ignore[no-untyped-def]
    """Largest difference of the distortion's point displacements, pixels, over a 41 x 31 grid of
    the whole image: ``D(K, dist, x, y) - (f x + c)`` for both devices at the same normalized
    points ``(x, y) = K_true^-1 (u, v)``."""
    K, Kt = np.asarray(got.K), np.asarray(truth.K)
    width = getattr(truth, "width_px", None) or truth.width
    height = getattr(truth, "height_px", None) or truth.height
    xs, ys = np.meshgrid(np.linspace(0, width - 1, 41), np.linspace(0, height - 1, 31))
    xn, yn = (xs - Kt[0, 2]) / Kt[0, 0], (ys - Kt[1, 2]) / Kt[1, 1]
    diff = displacement(K, got.dist, xn, yn) - displacement(Kt, truth.dist, xn, yn)
    return float(np.abs(diff).max())


def tilt_deg(p: BoardPose) -> float:
    """Angle between the board's normal and the camera's axis, degrees."""
    return math.degrees(math.acos(min(1.0, abs(float(p.R[2, 2])))))


def edge_gaps(points: list[np.ndarray], width: int, height: int) -> tuple[float, float, float, float]:
    """Left, right, top, bottom: distance from the image edge to the nearest point over its size."""
    pts = np.concatenate(points)
    return (
        (pts[:, 0].min() + 0.5) / width,
        (width - 0.5 - pts[:, 0].max()) / width,
        (pts[:, 1].min() + 0.5) / height,
        (height - 0.5 - pts[:, 1].max()) / height,
    )


def test_poses_reach_the_edges_of_both_images() -> None:
    """The planned poses: whole board seen and lit, tilted 20 to 30 degrees, its edges 13 to 32
    degrees off the pixel rows and columns, corners near every edge of both images that the other
    device allows (the projector's top: the camera never sees its first 48 to 133 rows)."""
    cam = [true_corners(RIG, BOARD, p)[0] for p in planned_poses()]
    prj = [true_corners(RIG, BOARD, p)[1] for p in planned_poses()]
    for p in planned_poses():
        assert board_in_view(RIG, BOARD, p)
        assert 19 <= tilt_deg(p) <= 31
        angles = edge_angles_deg(RIG, BOARD, p)
        assert angles.min() >= 13 and angles.max() <= 32, (angles.min(), angles.max())
    left, right, top, bottom = edge_gaps(prj, PROJECTOR.width, PROJECTOR.height)
    assert left < 0.065 and right < 0.065 and top < 0.16 and bottom < 0.11, (left, right, top, bottom)
    assert max(edge_gaps(cam, CAMERA.width_px, CAMERA.height_px)) < 0.17
    left, right, top, bottom = edge_gaps([true_corners(RIG, BOARD, p)[1] for p in CENTRAL], 1024, 768)
    assert left > 0.19 and right > 0.17 and top > 0.27  # the central poses stopped short of 3 edges


def test_corners_found_and_mapped_into_the_projector(rendered) -> None:  # type: ignore[no-untyped-def]
    observations, _ = rendered
    for i, p in enumerate(observations):
        assert p.reason is None and p.camera_px is not None and p.projector_px is not None
        cam, prj = true_corners(RIG, BOARD, pose(i))
        # the detector may number a 180-degree-symmetric grid from the other end
        if np.abs(p.camera_px - cam).max() > np.abs(p.camera_px[::-1] - cam).max():
            cam, prj = cam[::-1], prj[::-1]
        assert np.abs(p.camera_px - cam).max() < 0.1, i
        assert np.abs(p.projector_px - prj).max() < 0.15, i


def test_recovers_the_rig(rendered) -> None:  # type: ignore[no-untyped-def]
    observations, _ = rendered
    result = calibrate(observations)
    report = result.report
    assert report["warnings"] == [], report["warnings"]
    assert report["poses_used"] == 8
    for key in ("camera_rms_px", "projector_rms_px", "stereo_rms_px"):
        assert 0 < report[key] < 0.2, (key, report[key])
    rig: PinholeRig = result.rig
    for got, truth, name in ((rig.camera, CAMERA, "camera"), (rig.projector, PROJECTOR, "projector")):
        K, Kt = np.asarray(got.K), np.asarray(truth.K)
        assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.002 and abs(K[1, 1] / Kt[1, 1] - 1) < 0.002, (name, K)
        assert abs(K[0, 2] - Kt[0, 2]) < 1.0 and abs(K[1, 2] - Kt[1, 2]) < 1.0, (name, K)
        # over the whole image of both devices (the central poses gave 0.45 px at the projector's
        # far corners, where its distortion was extrapolated from corners 18 to 28 % of it away)
        assert distortion_error_px(got, truth) < 0.1, name
    R, Rt = np.asarray(rig.R), np.asarray(RIG.R)
    angle = math.degrees(math.acos(min(1.0, (np.trace(R @ Rt.T) - 1) / 2)))
    assert angle < 0.05
    baseline, truth_baseline = np.linalg.norm(rig.T), np.linalg.norm(RIG.T)
    assert abs(baseline / truth_baseline - 1) < 0.001
    # the report's coverage: no warning, every edge of both images within 20 % of a corner
    coverage = report["coverage"]
    assert coverage["camera"] > 0.6 and coverage["projector"] > 0.6, coverage
    for device in ("camera", "projector"):
        assert max(coverage["edge_gaps"][device].values()) < 0.2, coverage["edge_gaps"]
    # per-pose and per-corner contract
    for entry in report["poses"]:
        assert entry["used"] and entry["rms_px"] < 0.25 and len(entry["corners"]) == BOARD.count
        c = entry["corners"][0]
        assert set(c) >= {"camera_px", "projector_px", "residual_camera_px", "residual_projector_px"}


def causes(result) -> set[str]:  # type: ignore[no-untyped-def]
    return {w["cause"] for w in result.report["warnings"]}


def test_flipped_corner_order_is_found(rendered) -> None:  # type: ignore[no-untyped-def]
    observations = fresh(rendered[0])
    assert observations[3].projector_px is not None
    observations[3] = replace(observations[3], projector_px=observations[3].projector_px[::-1].copy())
    result = calibrate(observations)
    assert "corner_order_flipped" in causes(result)
    assert [p["name"] for p in result.report["poses"] if not p["used"]] == ["pose3"]
    assert result.report["stereo_rms_px"] < 0.2  # left out, the rest calibrates as before


def test_wrong_square_size_is_found(rendered) -> None:  # type: ignore[no-untyped-def]
    wrong = parse_board("chessboard:9x6:2")  # 2 cm squares given as 2
    result = calibrate([replace(p, object_mm=None) for p in rendered[0]], board=wrong)
    assert "board_unit" in causes(result)


def test_half_shadowed_pose_is_left_out(rendered) -> None:  # type: ignore[no-untyped-def]
    s = OPTIONS.supersample
    shadow = np.zeros((600 * s, 800 * s), bool)
    shadow[:, : 400 * s] = True
    images = render_board(RIG, BOARD, CENTRAL[0], CODEC, OPTIONS.with_changes(ambient=0.4), seed=20, shadow=shadow)
    extra = observe_pose("shadowed", images, CODEC, BOARD)
    result = calibrate([*rendered[0], extra])
    assert "poorly_decoded" in causes(result) or "board_not_found" in causes(result)
    left_out = [p["name"] for p in result.report["poses"] if not p["used"]]
    assert left_out == ["shadowed"]


def test_near_identical_poses_are_found(rendered) -> None:  # type: ignore[no-untyped-def]
    nudge = BoardPose.from_angles(0.5, 0.3, 0.2, (0.0, 0.0, 0.0)).R
    twin = BoardPose(R=pose(0).R @ nudge, t=pose(0).t + np.array([1.0, 0.5, 1.0]))
    images = render_board(RIG, BOARD, twin, CODEC, OPTIONS, seed=30)
    extra = observe_pose("twin", images, CODEC, BOARD)
    result = calibrate([*rendered[0], extra])
    pairs = [w for w in result.report["warnings"] if w["cause"] == "similar_poses"]
    assert len(pairs) == 1 and pairs[0]["poses"] == ["pose0", "twin"] and pairs[0]["pairs"] == [["pose0", "twin"]]


def test_poses_around_the_middle_give_the_coverage_warning() -> None:
    """The central poses (corners of exact projections, 0.01 px noise) leave 20 %, 18 % and 28 % of
    the projector image free at its left, right and top edges: the report names the top edge
    (beyond 20 %), and nothing about the camera, whose corners come within 17 % of its edges."""
    rng = np.random.default_rng(0)
    observations = []
    for i, p in enumerate(CENTRAL):
        cam, prj = true_corners(RIG, BOARD, p)
        cam, prj = cam + 0.01 * rng.standard_normal(cam.shape), prj + 0.01 * rng.standard_normal(prj.shape)
        observations.append(PoseObservation(f"central{i}", cam, prj))
    result = calibrate(observations)
    coverage = [w for w in result.report["warnings"] if w["cause"] == "coverage"]
    assert len(coverage) == 1, result.report["warnings"]
    message = coverage[0]["message"]
    assert message.startswith(
        "in the projector image the corners come no nearer than 28% of its height to its top edge"
    )
    assert not any(word in message for word in ("camera", "left", "right", "bottom")), message
    gaps = result.report["coverage"]["edge_gaps"]["projector"]
    assert gaps["top"] == pytest.approx(0.278, abs=0.002) and gaps["left"] == pytest.approx(0.196, abs=0.002)


def test_too_few_poses_are_found(rendered) -> None:  # type: ignore[no-untyped-def]
    result = calibrate(rendered[0][:3])
    assert "too_few_poses" in causes(result)


def test_wrong_projector_size_is_found(rendered) -> None:  # type: ignore[no-untyped-def]
    wrong = make_codec(640, 520)  # same frames, smaller projector declared
    extra = observe_pose("pose0", rendered[1], wrong, BOARD)
    assert extra.mismatch_fraction is not None and extra.mismatch_fraction > 0.02
    observations = [extra, *rendered[0][1:]]
    result = calibrate(observations, size=(640, 520))
    assert "projector_mismatch" in causes(result)


def test_gamma_is_found() -> None:
    images = render_board(RIG, BOARD, CENTRAL[0], CODEC, OPTIONS.with_changes(projector_gamma=2.2), seed=40)
    p = observe_pose("gamma", images, CODEC, BOARD)
    assert p.gamma is not None and abs(p.gamma - 2.2) < 0.2
    linear = observe_pose("linear", render_board(RIG, BOARD, CENTRAL[0], CODEC, OPTIONS, seed=41), CODEC, BOARD)
    assert linear.gamma is not None and abs(linear.gamma - 1.0) < 0.1


def test_a_plane_measured_with_the_calibrated_rig_is_flat(rendered) -> None:  # type: ignore[no-untyped-def]
    """A tilted plane (no board in view) measured with the calibrated rig is flat within 2x the
    flatness it has with the true rig (its noise)."""
    from metrology.core.codecs.decode import decode_codec

    calibrated = calibrate(rendered[0]).rig
    tilted = BoardPose.from_angles(12, -8, 0, (0, 0, 500))
    far = BoardPose(R=tilted.R, t=tilted.t - tilted.R @ np.array([5000.0, 5000.0, 0.0]))  # squares out of view
    images = render_board(RIG, BOARD, far, CODEC, OPTIONS, seed=50)
    decoded = decode_codec(images, CODEC)
    u, v = decoded.axes["u"].coordinate, decoded.axes["v"].coordinate
    noise = plane_flatness_mm(RIG, u, v)
    flatness = plane_flatness_mm(calibrated, u, v)
    assert 0 < noise < 0.2
    assert flatness < 2 * noise, (flatness, noise)
