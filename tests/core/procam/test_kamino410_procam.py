"""Real captures: kamino410 procam-calibration (5 poses of a 9x7 inner-corner chessboard, gray code
with inverses on both axes, 1024x768 projector; MIT licensed, kept outside the repository).

Its own program, rerun, gives camera fx 3452.4, projector fx 1980.6, stereo RMS 0.575 px and
T = (88.0, -641.6, -80.4) board units (square "75"). Its projector figures come from its program's
convention (image sizes given as (rows, cols), OpenCV 4.x's 30-iteration stop); our correspondences
reproduce them under that convention, and converge to projector fx 1888, which predicts
left-out poses 6x better than the dataset's (see docs/procam-calibration.md). Skipped (with
the reason) when the dataset folder is absent, except under ``CI=true`` where its absence fails.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import main
from tests.datasets import dataset_path, require_dataset

ROOT = Path(__file__).resolve().parents[3]
DATASET = dataset_path("kamino410-procam-calibration", "sample_data")
CODEC = ROOT / "examples" / "kamino410-procam.codec.json"
T_REFERENCE = np.array([88.0, -641.6, -80.4])

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict]:  # type: ignore[type-arg]
    require_dataset(DATASET / "capture_0", "kamino410 procam dataset")
    out = tmp_path_factory.mktemp("kamino")
    poses = [str(DATASET / f"capture_{i}") for i in range(5)]
    args = ["--quiet", "calibrate-procam", "--codec", str(CODEC), "--board", "chessboard:9x7:75", "--poses", *poses]
    assert main([*args, "--out", str(out / "rig.json"), "--report", str(out / "report.json")]) == 0
    return json.loads((out / "rig.json").read_text()), json.loads((out / "report.json").read_text())


def test_camera_and_stereo_match_the_datasets_program(calibrated) -> None:  # type: ignore[no-untyped-def]
    rig, report = calibrated
    assert rig["model"] == "pinhole" and report["poses_used"] == 5
    assert abs(rig["camera"]["K"][0][0] / 3452.0 - 1) < 0.01
    assert report["stereo_rms_px"] <= 0.7
    assert len(report["poses"]) == 5 and all(len(p["corners"]) == 63 for p in report["poses"])


def _dataset_convention(report: dict) -> dict[str, object]:  # type: ignore[type-arg]
    """Re-fit the report's correspondences the way the dataset's program (``calibrate.py``) does.

    Its program calls ``cv2.calibrateCamera(objps, corners, shape, None, None)`` with
    ``shape = (rows, cols)`` for both devices where OpenCV reads ``(width, height)``, so each
    Levenberg-Marquardt run starts from a principal point at the swapped image centre (the
    projector's at (383.5, 511.5) instead of (511.5, 383.5)); under OpenCV 4.x the run stops at its
    default 30 iterations (``TERM_CRITERIA_COUNT + EPS``, 30, DBL_EPSILON). ``cv2.stereoCalibrate``
    then keeps both intrinsics (its default flag ``CALIB_FIX_INTRINSIC``). Returns the projector
    K (3, 3), RMS values (pixels) and T (3,) in board units.
    """
    obj = np.zeros((63, 3), np.float32)
    obj[:, :2] = 75.0 * np.mgrid[0:9, 0:7].T.reshape(-1, 2)
    objects, camera, projector = [], [], []
    for pose in report["poses"]:  # every corner the dataset's program would use: all with both points
        used = [i for i, c in enumerate(pose["corners"]) if c["projector_px"] is not None]
        objects.append(obj[used])
        camera.append(np.float32([pose["corners"][i]["camera_px"] for i in used]))
        projector.append(np.float32([pose["corners"][i]["projector_px"] for i in used]))
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, float(np.finfo(float).eps))
    cam_rows_cols = (report["camera_size"][1], report["camera_size"][0])
    proj_rows_cols = (report["projector_size"][1], report["projector_size"][0])
    _, Kc, dc, _, _ = cv2.calibrateCamera(objects, camera, cam_rows_cols, None, None, criteria=criteria)  # type: ignore[call-overload]
    proj_rms, Kp, dp, _, _ = cv2.calibrateCamera(objects, projector, proj_rows_cols, None, None, criteria=criteria)  # type: ignore[call-overload]
    stereo = cv2.stereoCalibrate(objects, camera, projector, Kc, dc, Kp, dp, None)  # type: ignore[call-overload]
    T = stereo[6].ravel()
    return {"camera_K": Kc, "projector_K": Kp, "projector_rms": proj_rms, "stereo_rms": stereo[0], "T": T}


def _t_close(T: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """(relative length difference, angle in degrees) between two translations."""
    length = abs(np.linalg.norm(T) / np.linalg.norm(reference) - 1)
    cos = float(T @ reference / (np.linalg.norm(T) * np.linalg.norm(reference)))
    return float(length), math.degrees(math.acos(min(1.0, cos)))


def test_our_correspondences_reproduce_the_datasets_projector_under_its_convention(calibrated) -> None:  # type: ignore[no-untyped-def]
    """The dataset's projector fx 1980.6 is its program's convention, not its data: our corners,
    fitted with swapped image sizes and 30 iterations, give it within the issue's tolerances."""
    _, report = calibrated
    fit = _dataset_convention(report)
    assert abs(fit["camera_K"][0, 0] / 3452.0 - 1) < 0.01  # type: ignore[index]
    assert abs(fit["projector_K"][0, 0] / 1981.0 - 1) < 0.03  # type: ignore[index]
    assert fit["stereo_rms"] <= 0.7  # type: ignore[operator]
    length, angle = _t_close(np.asarray(fit["T"]), T_REFERENCE)
    assert length < 0.02 and angle < 1.0


def test_our_converged_projector_calibration(calibrated) -> None:  # type: ignore[no-untyped-def]
    """The product's result is the converged joint minimum with 8 outlier corners left out:
    projector fx 1887.7 (1891.8 with all corners, 1888.3 with all corners and the intrinsics held
    at the per-device fits, 1895.6 for the dataset program's own corners run to convergence),
    T = (95.7, -622.6, -240.9), and a better fit than the dataset's convention (projector RMS 0.13
    against 0.28, stereo 0.17 against 0.56)."""
    rig, report = calibrated
    assert report["intrinsics_refined_jointly"] is True
    outliers = {p["name"]: sum(1 for c in p["corners"] if c.get("outlier")) for p in report["poses"]}
    assert outliers == {"capture_0": 0, "capture_1": 7, "capture_2": 1, "capture_3": 0, "capture_4": 0}
    assert abs(rig["projector"]["K"][0][0] / 1887.7 - 1) < 0.005
    assert abs(rig["projector"]["K"][0][0] / 1895.6 - 1) < 0.01
    length, angle = _t_close(np.asarray(rig["T"]), np.array([95.7, -622.6, -240.9]))
    assert length < 0.005 and angle < 0.25
    fit = _dataset_convention(report)
    assert report["projector_rms_px"] <= 0.2 and report["projector_rms_px"] < 0.6 * float(fit["projector_rms"])  # type: ignore[arg-type]
    assert report["stereo_rms_px"] < 0.4 * float(fit["stereo_rms"])  # type: ignore[arg-type]


def _dataset_convention_leave_one_out(report: dict) -> list[float]:  # type: ignore[type-arg]
    """Each pose's projector corners predicted by the dataset program's calibration of the other
    four (its convention, as in :func:`_dataset_convention`), RMS pixels."""
    obj = np.zeros((63, 3), np.float32)
    obj[:, :2] = 75.0 * np.mgrid[0:9, 0:7].T.reshape(-1, 2)
    poses = report["poses"]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, float(np.finfo(float).eps))
    cam_rows_cols = (report["camera_size"][1], report["camera_size"][0])
    proj_rows_cols = (report["projector_size"][1], report["projector_size"][0])
    out = []
    for k in range(len(poses)):
        objects, camera, projector = [], [], []
        for pose in poses[:k] + poses[k + 1 :]:
            objects.append(obj)
            camera.append(np.float32([c["camera_px"] for c in pose["corners"]]))
            projector.append(np.float32([c["projector_px"] for c in pose["corners"]]))
        _, Kc, dc, _, _ = cv2.calibrateCamera(objects, camera, cam_rows_cols, None, None, criteria=criteria)  # type: ignore[call-overload]
        _, Kp, dp, _, _ = cv2.calibrateCamera(objects, projector, proj_rows_cols, None, None, criteria=criteria)  # type: ignore[call-overload]
        stereo = cv2.stereoCalibrate(objects, camera, projector, Kc, dc, Kp, dp, None)  # type: ignore[call-overload]
        R, T = stereo[5], stereo[6]
        cam_k = np.float32([c["camera_px"] for c in poses[k]["corners"]])
        prj_k = np.float64([c["projector_px"] for c in poses[k]["corners"]])
        _, rvec, tvec = cv2.solvePnP(obj, cam_k, Kc, dc)
        rp = cv2.Rodrigues(R @ cv2.Rodrigues(rvec)[0])[0]
        predicted, _ = cv2.projectPoints(obj, rp, R @ tvec + T, Kp, dp)
        out.append(float(np.sqrt(np.mean(np.sum((predicted.reshape(-1, 2) - prj_k) ** 2, axis=1)))))
    return out


def test_our_calibration_predicts_left_out_poses_better_than_the_datasets(calibrated) -> None:  # type: ignore[no-untyped-def]
    """Which projector is right, fx 1888 or the dataset's 1981? Calibrate on four poses and predict
    the fifth's projector corners from its camera corners: the product's calibration (joint,
    converged, outliers left out) misses the corners it keeps by 0.22 px median (0.15-0.29 px),
    the dataset's convention misses all corners by 1.39 px median (1.10-3.74 px). The report's
    own leave-one-out figures are the product's."""
    _, report = calibrated
    ours = report["leave_one_out"]["projector_rms_px"]
    assert len(ours) == 5 and max(ours.values()) < 0.35 and report["leave_one_out"]["median_px"] < 0.25
    theirs = _dataset_convention_leave_one_out(report)
    assert np.median(theirs) > 1.0 and np.median(theirs) > 3 * report["leave_one_out"]["median_px"], theirs
    assert "inconsistent_pose" not in {w["cause"] for w in report["warnings"]}


def test_report_says_what_the_five_poses_cannot_determine(calibrated) -> None:  # type: ignore[no-untyped-def]
    """The joint fit's full covariance (both devices' 9 intrinsics, the stereo pose and 5 board
    poses: 54 parameters) gives the report's std; focal length and distance are separable (the camera's fy
    correlates 0.990 with the boards' mean distance, the projector's fx 0.909, both below
    0.999: no warning); but the five poses' left-out spread exceeds the std by a factor 4 to 5
    for the camera's fx and fy (15.8 px against 3.0 px), which the report says."""
    _, report = calibrated
    u = report["uncertainty"]
    assert u["fit"] == "joint" and u["leave_one_out_fits"] == 5
    assert len(u["covariance"]["parameters"]) == 2 * 9 + 6 + 5 * 6
    for device in ("camera", "projector"):
        for name, entry in u[device]["intrinsics"].items():
            assert entry["std"] == pytest.approx(entry["std_reported"], rel=1e-9), (device, name)
    assert u["camera"]["focal_distance_correlation"] == pytest.approx(0.990, abs=0.005)
    assert u["projector"]["focal_distance_correlation"] == pytest.approx(0.909, abs=0.02)
    assert u["coupled"] == [] and "focal_distance_coupled" not in {w["cause"] for w in report["warnings"]}
    fx = u["camera"]["intrinsics"]["fx"]
    assert fx["std"] == pytest.approx(3.05, rel=0.05) and fx["leave_one_out_std"] == pytest.approx(15.8, rel=0.1)
    assert fx["agrees"] is False and {"camera.fx", "camera.fy"} <= set(u["disagreements"])
    assert u["camera"]["mean_distance_mm"] == pytest.approx(
        float(np.mean([p["distance_mm"] for p in report["poses"]])), rel=1e-9
    )
