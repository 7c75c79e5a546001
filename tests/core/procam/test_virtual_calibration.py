"""Procam calibration on virtual-rig board renders of a known distorted pinhole rig (issue 13 must-shows).

8 chessboard poses (9x6 inner corners, 20 mm squares, 450..530 mm away, tilted up to 25 degrees)
rendered through the pinhole virtual rig with realistic 8-bit noise (1.5 grey levels, camera and
projector defocus, 2x2 sub-rays), coded by an 8-step phase (period 32 px) + gray code on both axes.
The calibration must give: focal lengths within 0.2 %, principal points within 1 px, the
distortion's point displacements within 0.1 px over the image, the rotation within 0.05 degrees
and the baseline within 0.1 %. Then each failure cause, produced on purpose, gives its warning.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.model import Codec
from metrology.core.distortion import project_normalized
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig
from metrology.core.procam import calibrate_procam, parse_board
from metrology.core.procam.calibrate import PoseObservation
from metrology.core.procam.observe import observe_pose
from metrology.core.procam.virtual import BoardPose, render_board, true_corners
from metrology.core.simulate import realistic_8bit
from metrology.core.simulate_pinhole import look_at_rig

pytestmark = pytest.mark.slow

CAMERA = PinholeCamera(
    800, 600, ((1000.0, 0, 403.2), (0, 1001.0, 297.6), (0, 0, 1)), (-0.12, 0.08, 0.0008, -0.0005, 0.0)
)
PROJECTOR = PinholeProjector(
    1024, 768, ((1300.0, 0, 515.0), (0, 1300.0, 460.0), (0, 0, 1)), (0.04, -0.02, 0.0, 0.0, 0.0)
)
RIG = look_at_rig(CAMERA, PROJECTOR, (150.0, 10.0, -20.0), (0.0, 0.0, 500.0))
BOARD = parse_board("chessboard:9x6:20")
OPTIONS = realistic_8bit(supersample=2)
ANGLES = [(0, 0, 0), (25, 0, 5), (-25, 0, -5), (0, 25, 10), (0, -25, -10), (18, 18, 0), (-18, 18, 15), (18, -18, -15)]
SHIFTS = [
    (0, 0, 480),
    (-40, 30, 520),
    (40, -30, 450),
    (30, 40, 500),
    (-30, -40, 470),
    (50, 20, 530),
    (-50, -20, 490),
    (0, 40, 460),
]


def make_codec(width: int = 1024, height: int = 768, period: float = 32.0) -> Codec:
    def axis(first: int) -> dict[str, object]:
        return {
            "phase": [{"frames": list(range(first, first + 8)), "period": period}],
            "gray": {"frames": list(range(first + 8, first + 13)), "word": period, "origin": -0.5},
        }

    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 28,
            "projector": {"width": width, "height": height},
            "white": [26],
            "black": [27],
            "axes": {"u": axis(0), "v": axis(13)},
        }
    )


CODEC = make_codec()


def pose(i: int) -> BoardPose:
    return BoardPose.from_angles(*ANGLES[i], SHIFTS[i]).centred(BOARD)


@pytest.fixture(scope="module")
def rendered() -> tuple[list[PoseObservation], np.ndarray]:
    observations = []
    first_images = None
    for i in range(len(ANGLES)):
        images = render_board(RIG, BOARD, pose(i), CODEC, OPTIONS, seed=i)
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


def distortion_error_px(got, truth, observations=None, whole_image=False):  # type: ignore[no-untyped-def]
    """Largest difference of the distortion's point displacements, pixels, over a 41 x 31 grid of
    the image (``whole_image``) or of its part inside the hull of the camera's corners."""
    K, Kt = np.asarray(got.K), np.asarray(truth.K)
    width = getattr(truth, "width_px", None) or truth.width
    height = getattr(truth, "height_px", None) or truth.height
    xs, ys = np.meshgrid(np.linspace(0, width - 1, 41), np.linspace(0, height - 1, 31))
    keep = np.ones(xs.shape, bool)
    if not whole_image and observations is not None:
        pts = np.concatenate(observations).astype(np.float32)
        hull = cv2.convexHull(pts)
        keep = np.array(
            [
                [cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in zip(rx, ry, strict=False)]
                for rx, ry in zip(xs, ys, strict=False)
            ]
        )
    xn, yn = (xs - Kt[0, 2]) / Kt[0, 0], (ys - Kt[1, 2]) / Kt[1, 1]
    diff = displacement(K, got.dist, xn, yn) - displacement(Kt, truth.dist, xn, yn)
    return float(np.abs(diff[keep]).max())


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
        points = [p.camera_px if name == "camera" else p.projector_px for p in observations]
        # the camera over its whole image; the projector inside the hull of its corners (the part
        # of its image the boards reached: 0.44 px at its far corners, extrapolated)
        assert distortion_error_px(got, truth, points, whole_image=name == "camera") < 0.1, name
    R, Rt = np.asarray(rig.R), np.asarray(RIG.R)
    angle = math.degrees(math.acos(min(1.0, (np.trace(R @ Rt.T) - 1) / 2)))
    assert angle < 0.05
    baseline, truth_baseline = np.linalg.norm(rig.T), np.linalg.norm(RIG.T)
    assert abs(baseline / truth_baseline - 1) < 0.001
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
    observations[3].projector_px = observations[3].projector_px[::-1].copy()
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
    images = render_board(RIG, BOARD, pose(0), CODEC, OPTIONS.with_changes(ambient=0.4), seed=20, shadow=shadow)
    extra = observe_pose("shadowed", images, CODEC, BOARD)
    result = calibrate([*rendered[0], extra])
    assert "poorly_decoded" in causes(result) or "board_not_found" in causes(result)
    left_out = [p["name"] for p in result.report["poses"] if not p["used"]]
    assert left_out == ["shadowed"]


def test_near_identical_poses_are_found(rendered) -> None:  # type: ignore[no-untyped-def]
    twin = BoardPose.from_angles(0.5, 0.3, 0.2, (1.0, 0.5, 481.0)).centred(BOARD)
    images = render_board(RIG, BOARD, twin, CODEC, OPTIONS, seed=30)
    extra = observe_pose("twin", images, CODEC, BOARD)
    result = calibrate([*rendered[0], extra])
    pairs = [w for w in result.report["warnings"] if w["cause"] == "similar_poses"]
    assert pairs and pairs[0]["poses"] == ["pose0", "twin"]


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
    images = render_board(RIG, BOARD, pose(0), CODEC, OPTIONS.with_changes(projector_gamma=2.2), seed=40)
    p = observe_pose("gamma", images, CODEC, BOARD)
    assert p.gamma is not None and abs(p.gamma - 2.2) < 0.2
    linear = observe_pose("linear", render_board(RIG, BOARD, pose(0), CODEC, OPTIONS, seed=41), CODEC, BOARD)
    assert linear.gamma is not None and abs(linear.gamma - 1.0) < 0.1


def plane_flatness_mm(rig: PinholeRig, u: np.ndarray, v: np.ndarray) -> float:
    """RMS distance of the triangulated points to their total-least-squares plane, mm, after
    dropping points more than 5 robust sigmas (1.4826 MAD) off (the field's edge pixels)."""
    from metrology.core.pinhole_measure import measure_pinhole

    pts = measure_pinhole(rig, u, v).points_mm.reshape(-1, 3).astype(np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    for _ in range(3):
        centred = pts - pts.mean(axis=0)
        normal = np.linalg.svd(centred, full_matrices=False)[2][2]
        r = centred @ normal
        robust = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        pts = pts[np.abs(r - np.median(r)) < 5 * robust]
    return float(np.sqrt(np.mean(r**2)))


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
