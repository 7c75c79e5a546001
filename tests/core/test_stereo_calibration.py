"""Two-camera calibration (metrology/core/stereo_calibration.py) on exact corners of the virtual
stereo pair of tests/stereo_boards.py: the pair comes back to numerical precision; a pose whose
camera-1 corners come in reversed order is left out and named in a warning."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from metrology.core.stereo_calibration import StereoBoardPose, StereoCalibrationError, calibrate_stereo
from tests import stereo_boards as sb

SIZE = (sb.WIDTH, sb.HEIGHT)


def _exact_poses() -> list[StereoBoardPose]:
    """Every pose's board points projected through the true cameras (cv2.projectPoints), pixels."""
    obj = sb.BOARD.object_points()
    poses = []
    for i, pose in enumerate(sb.board_poses()):
        X0 = obj @ pose.R.T + pose.t
        X1 = X0 @ sb.R1.T + sb.T1
        a = cv2.projectPoints(X0, np.zeros(3), np.zeros(3), sb.K0, sb.D0)[0].reshape(-1, 2)
        b = cv2.projectPoints(X1, np.zeros(3), np.zeros(3), sb.K1, sb.D1)[0].reshape(-1, 2)
        poses.append(StereoBoardPose(f"p{i}", np.asarray(a, np.float64), np.asarray(b, np.float64)))
    return poses


def test_exact_corners_give_the_pair_back() -> None:
    """Noise-free corners, rounded only by OpenCV's float32 points (about 1e-5 px at 300 px):
    measured RMS 5.5e-6 px, K within 4e-5 px, k1..p2 within 2e-5, k3 (least determined) within
    1.0e-4, R within 1e-6 degrees, T within 1.1e-5 mm. Tolerances about ten times that."""
    result = calibrate_stereo(_exact_poses(), sb.BOARD, SIZE, SIZE, sb.PROJECTOR_SIZE)
    data = result.rig.to_dict()
    for camera, (K, dist) in zip(data["cameras"], ((sb.K0, sb.D0), (sb.K1, sb.D1)), strict=True):
        np.testing.assert_allclose(camera["K"], K, atol=5e-4)
        np.testing.assert_allclose(camera["dist"][:4], dist[:4], atol=2e-4)
        assert abs(camera["dist"][4] - dist[4]) < 1e-3
    R = np.array(data["cameras"][1]["R"])
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(R @ sb.R1.T)[0])) < 1e-5
    np.testing.assert_allclose(data["cameras"][1]["T"], sb.T1, atol=2e-4)
    report = result.report
    for key in ("camera0_rms_px", "camera1_rms_px", "stereo_rms_px", "leave_one_out"):
        value = report[key]["median_px"] if key == "leave_one_out" else report[key]
        assert value < 5e-5, (key, value)


def test_a_reversed_pose_is_left_out_and_named() -> None:
    poses = _exact_poses()
    reversed_pose = StereoBoardPose("p3", poses[3].camera0_px, poses[3].camera1_px[::-1].copy())
    poses[3] = reversed_pose
    result = calibrate_stereo(poses, sb.BOARD, SIZE, SIZE, sb.PROJECTOR_SIZE)
    report = result.report
    assert report["poses_used"] == len(poses) - 1
    entry = next(p for p in report["poses"] if p["name"] == "p3")
    assert entry["used"] is False and entry["cause"] == "corner_order_flipped"
    warning = next(w for w in report["warnings"] if w["cause"] == "corner_order_flipped")
    assert warning["poses"] == ["p3"] and "projector" not in warning["message"] + warning["action"]
    assert report["stereo_rms_px"] < 5e-5


def test_too_few_poses_and_wrong_shapes_are_refused() -> None:
    poses = _exact_poses()
    with pytest.raises(StereoCalibrationError, match="at least 2 board poses"):
        calibrate_stereo(poses[:1], sb.BOARD, SIZE, SIZE, sb.PROJECTOR_SIZE)
    short = StereoBoardPose("p1", poses[1].camera0_px, poses[1].camera1_px[:10])
    with pytest.raises(StereoCalibrationError, match=r"pose p1: cam1 has points of shape \(10, 2\)"):
        calibrate_stereo([poses[0], short], sb.BOARD, SIZE, SIZE, sb.PROJECTOR_SIZE)
