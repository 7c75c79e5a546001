"""`gcps calibrate-stereo` (issue 24, a contract): board poses rendered through a virtual stereo pair of
known K, dist, R, T (tests/stereo_boards.py) give back the pair within stated tolerances, with a report
in the style of calibrate-procam; bad inputs exit 2 with one line naming the pose and the camera."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import read_codec
from metrology.core.codecs.stack import write_codec_stack
from metrology.core.geometry import model_from_dict
from metrology.core.geometry.stereo import StereoRig
from metrology.pipeline.calibrate_stereo import StereoCalibrationOptions
from tests import stereo_boards as sb

BOARD = sb.BOARD.spec()


def _run(captures: list[Path], out: Path, report: Path, *extra: str) -> int:
    args = ["--quiet", "calibrate-stereo", "--board", BOARD, "--poses", *map(str, captures)]
    return main([*args, "--out", str(out), "--report", str(report), *extra])


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return list(sb.write_captures(tmp_path_factory.mktemp("stereo_boards")).folders)


@pytest.fixture(scope="module")
def calibrated(captures: list[Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, dict]:
    root = tmp_path_factory.mktemp("calibrated")
    out, report = root / "rig.json", root / "report.json"
    size = ["--projector-size", *map(str, sb.PROJECTOR_SIZE)]
    assert _run(captures, out, report, *size, "--fix-k3") == 0
    return out.read_bytes(), json.loads(report.read_text())


def _map_error_px(K: np.ndarray, dist: np.ndarray, K_true: np.ndarray, dist_true: np.ndarray) -> float:
    """Largest distance (px) over a 17 x 13 grid of the whole image between where the true camera and
    the calibrated one put the same ray (intrinsics and distortion together)."""
    xs, ys = np.meshgrid(np.linspace(0, sb.WIDTH - 1, 17), np.linspace(0, sb.HEIGHT - 1, 13))
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), K_true, dist_true).reshape(-1, 2)
    points = np.concatenate([rays, np.ones((rays.shape[0], 1))], axis=1)
    again = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)
    return float(np.abs(again - pixels).max())


def test_the_pair_is_recovered(calibrated: tuple[bytes, dict]) -> None:
    """Eight poses, 320x256 8-bit images with 1 grey level of noise, k3 held at 0 (the truth's).
    Measured: K within 0.36 px, the pixel maps within 0.52 px over the whole image (corners of the
    image extrapolated), R within 0.05 degrees, T within 0.27 mm of a 110 mm baseline. Tolerances
    about twice to three times that."""
    text, _ = calibrated
    rig = model_from_dict(json.loads(text))
    assert isinstance(rig, StereoRig)
    data = rig.to_dict()
    for camera, (K_true, dist_true) in zip(data["cameras"], ((sb.K0, sb.D0), (sb.K1, sb.D1)), strict=True):
        K, dist = np.array(camera["K"]), np.array(camera["dist"])
        assert (camera["width_px"], camera["height_px"]) == (sb.WIDTH, sb.HEIGHT)
        assert np.abs(K - K_true).max() < 1.0, K - K_true
        assert _map_error_px(K, dist, K_true, dist_true) < 1.2
    R, T = np.array(data["cameras"][1]["R"]), np.array(data["cameras"][1]["T"])
    angle_deg = np.degrees(np.linalg.norm(cv2.Rodrigues(R @ sb.R1.T)[0]))
    assert angle_deg < 0.15
    assert np.linalg.norm(T - sb.T1) < 0.8, T - sb.T1
    assert data["projector"] == {"width": 1280, "height": 800}


def test_the_report_explains_the_fit(calibrated: tuple[bytes, dict]) -> None:
    """Per-camera and stereo RMS at the corner noise (0.04 px measured), per-pose RMS equal to the RMS
    of that pose's per-corner residuals, leave-one-pose-out for every pose, coverage of both images,
    pose diversity, and warnings each with an action."""
    _, report = calibrated
    assert report["format"] == "gcps-stereo-calibration-report/1"
    assert report["board"] == BOARD and report["poses_used"] == report["poses_total"] == len(sb.POSE_ANGLES)
    for key in ("camera0_rms_px", "camera1_rms_px", "stereo_rms_px"):
        assert 0.005 < report[key] < 0.1, (key, report[key])
    assert report["camera0_size"] == report["camera1_size"] == [sb.WIDTH, sb.HEIGHT]
    assert abs(report["baseline_mm"] - np.linalg.norm(sb.T1)) < 0.8
    loo = report["leave_one_out"]["camera1_rms_px"]
    assert set(loo) == {f"pose_{i:02d}" for i in range(len(sb.POSE_ANGLES))}
    assert all(0.0 < v < 0.2 for v in loo.values()), loo
    for pose in report["poses"]:
        corners = pose["corners"]
        assert len(corners) == sb.BOARD.count and all(c["used"] for c in corners)
        for camera in ("camera0", "camera1"):
            residuals = np.array([c[f"residual_{camera}_px"] for c in corners])
            rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
            assert rms == pytest.approx(pose[f"{camera}_rms_px"], rel=1e-3), (pose["name"], camera)
        assert pose["leave_one_out_camera1_rms_px"] == loo[pose["name"]]
        assert 0.0 <= pose["tilt_deg"] < 45.0 and 450.0 < pose["distance_mm"] < 700.0
    coverage = report["coverage"]
    assert 0.0 < coverage["camera0"] <= 1.0 and 0.0 < coverage["camera1"] <= 1.0
    assert set(coverage["edge_gaps"]) == {"camera0", "camera1"}
    assert report["pose_diversity"]["max_angle_between_boards_deg"] > 30.0
    assert report["uncertainty"]["camera0"] and report["uncertainty"]["camera1"]
    for warning in report["warnings"]:
        assert warning["message"] and warning["action"] and "projector" not in warning["message"]
    expected = {"board": BOARD, "projector_size": [1280.0, 800.0], "fix_k3": True, "joint": True, "projector": False}
    assert report["options"] == expected


@pytest.mark.slow
def test_codec_stacks_give_the_same_rig_and_the_codecs_projector_size(
    captures: list[Path], calibrated: tuple[bytes, dict], tmp_path: Path
) -> None:
    """Each camera a codec stack whose board frames are the board image (the first pose a zip): the
    same corners, so the same rig (to 1e-7 relative: OpenCV's calibration sums in parallel threads,
    and two runs on the same corners differ by about 1e-10 px), the projector's size the codec's."""
    codec = read_codec("gcps-v1:1280x800")
    stacked = []
    for source in captures:
        pose = tmp_path / source.name
        for camera in ("cam0", "cam1"):
            image = cv2.imread(str(source / camera / "board.png"), cv2.IMREAD_UNCHANGED)
            assert image is not None
            write_codec_stack(codec, np.repeat(image[None], codec.n_frames, axis=0), pose / camera)
            (pose / camera / "codec.json").unlink()  # a capture's codec.json lies at its top
        stacked.append(pose)
    # the first pose as a zip of both cameras' stacks
    stacked[0] = Path(shutil.make_archive(str(tmp_path / "pose_00"), "zip", root_dir=stacked[0]))
    out, report = tmp_path / "rig.json", tmp_path / "report.json"
    assert _run(stacked, out, report, "--codec", "gcps-v1:1280x800", "--fix-k3") == 0
    stacked_rig, single_rig = json.loads(out.read_text()), json.loads(calibrated[0])
    assert stacked_rig["projector"] == single_rig["projector"] == {"width": 1280, "height": 800}
    for stacked_camera, single_camera in zip(stacked_rig["cameras"], single_rig["cameras"], strict=True):
        assert list(stacked_camera) == list(single_camera)
        for key, value in single_camera.items():
            np.testing.assert_allclose(stacked_camera[key], value, rtol=1e-7, atol=1e-9, err_msg=key)


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_bad_inputs_exit_2_with_one_line(
    captures: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, report = tmp_path / "rig.json", tmp_path / "report.json"
    size = ["--projector-size", "1280", "800"]
    # a pose without cam1/
    broken = tmp_path / "no_cam1"
    shutil.copytree(captures[0], broken)
    shutil.rmtree(broken / "cam1")
    assert _run([*captures[1:3], broken], out, report, *size) == 2
    assert "no_cam1: no cam1/ folder" in _one_line_error(capsys)
    # too few poses
    assert _run(captures[:1], out, report, *size) == 2
    assert "need at least 2 board poses" in _one_line_error(capsys)
    # the board not found in one camera of a named pose
    blank = tmp_path / "blank"
    shutil.copytree(captures[0], blank)
    cv2.imwrite(str(blank / "cam1" / "board.png"), np.full((sb.HEIGHT, sb.WIDTH), 128, np.uint8))
    assert _run([*captures[1:3], blank], out, report, *size) == 2
    assert "pose blank: board chessboard:9x7:22 not found in cam1's image" in _one_line_error(capsys)
    # no projector size and no codec to take it from
    assert _run(captures[:2], out, report) == 2
    assert "--projector-size W H is required" in _one_line_error(capsys)
    assert not out.exists() and not report.exists()


def test_options_round_trip_and_refuse_bad_values() -> None:
    options = StereoCalibrationOptions(board=BOARD, projector_size=(1920, 1080), fix_k3=True)
    assert StereoCalibrationOptions.from_dict(json.loads(json.dumps(options.to_dict()))) == options
    with pytest.raises(ValueError, match="projector_size"):
        StereoCalibrationOptions(board=BOARD, projector_size=(0, 1080))
    with pytest.raises(ValueError, match="--board"):
        StereoCalibrationOptions(board="chess:9x7", projector_size=(1920, 1080))
    with pytest.raises(ValueError, match="unknown stereo calibration option"):
        StereoCalibrationOptions.from_dict({"board": BOARD, "projector_size": [1, 1], "window": 3})


@pytest.mark.slow
def test_projector_calibrated_from_camera_0s_codec_stacks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Six poses as codec stacks (both axes, 28 frames, codec.json at each capture's top) lit by a
    distorted 640x400 projector between the cameras: ``--projector`` also calibrates it against
    camera 0. Measured: projector K within 0.64 px, R within 0.006 degrees, T within 0.17 mm; the
    cameras' K within 0.5 px, R within 0.08 degrees, T within 0.11 mm. Tolerances about three times
    that. Single images cannot calibrate the projector (exit 2 naming the pose)."""
    from metrology.core.codecs.stack import write_codec_stack

    codec = sb.make_stack_codec()
    folders = []
    white: dict[str, np.ndarray] = {}
    for i, pose in enumerate(sb.board_poses()[:6]):
        folder = tmp_path / f"pose_{i:02d}"
        for camera, stack in zip(("cam0", "cam1"), sb.render_stack_pair(pose, codec, i), strict=True):
            white.setdefault(camera, stack[codec.white[0]])
            write_codec_stack(codec, stack, folder / camera)
            (folder / camera / "codec.json").unlink()
        (folder / "codec.json").write_text(codec.to_json())
        folders.append(folder)
    out, report_path = tmp_path / "rig.json", tmp_path / "report.json"
    assert _run(folders, out, report_path, "--projector", "--fix-k3") == 0
    data = json.loads(out.read_text())
    assert isinstance(model_from_dict(data), StereoRig)
    projector = data["projector"]
    R_p, T_p = sb.projector_pose()
    assert (projector["width"], projector["height"]) == (640, 400)
    assert np.abs(np.array(projector["K"]) - np.array(sb.PROJECTOR.K)).max() < 2.0
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(np.array(projector["R"]) @ R_p.T)[0])) < 0.02
    assert np.linalg.norm(np.array(projector["T"]) - T_p) < 0.5
    for camera, K_true in zip(data["cameras"], (sb.K0, sb.K1), strict=True):
        assert np.abs(np.array(camera["K"]) - K_true).max() < 1.5
    R = np.array(data["cameras"][1]["R"])
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(R @ sb.R1.T)[0])) < 0.25
    assert np.linalg.norm(np.array(data["cameras"][1]["T"]) - sb.T1) < 0.4
    report = json.loads(report_path.read_text())
    assert report["projector_calibration"]["format"] == "gcps-procam-report/1"
    assert report["projector_calibration"]["poses_used"] == 6
    # the first pose's white frames as single images: no stacks, no projector calibration
    single = tmp_path / "single"
    for camera in ("cam0", "cam1"):
        (single / camera).mkdir(parents=True)
        cv2.imwrite(str(single / camera / "board.png"), white[camera])
    capsys.readouterr()
    assert _run([single, *folders[1:3]], out, report_path, "--projector") == 2
    assert "pose single: --projector needs a codec stack in cam0/" in _one_line_error(capsys)
