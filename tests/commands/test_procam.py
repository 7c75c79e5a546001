"""gcps calibrate-procam: the command line contract (exit 2 naming the problem, nothing written),
the correspondence file, and the report's keys, on exact projections of a known pinhole rig."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, look_at_rig
from metrology.core.procam import parse_board
from metrology.core.procam.virtual import BoardPose, true_corners

CAMERA = PinholeCamera(800, 600, ((1000.0, 0, 403.2), (0, 1001.0, 297.6), (0, 0, 1)), (-0.12, 0.08, 0.0008, -0.0005))
PROJECTOR = PinholeProjector(1024, 768, ((1300.0, 0, 515.0), (0, 1300.0, 460.0), (0, 0, 1)), (0.04, -0.02, 0.0, 0.0))
RIG = look_at_rig(CAMERA, PROJECTOR, (150.0, 10.0, -20.0), (0.0, 0.0, 500.0))
BOARD = parse_board("chessboard:9x6:20")
ANGLES = [(0, 0, 0), (25, 0, 5), (-25, 0, -5), (0, 25, 10), (0, -25, -10), (18, 18, 0), (-18, 18, 15), (18, -18, -15)]
SHIFTS = [(0, 0, 480), (-40, 30, 520), (40, -30, 450), (30, 40, 500), (-30, -40, 470), (50, 20, 530), (-50, -20, 490)]


def correspondences(noise_px: float = 0.02, seed: int = 0) -> dict:  # type: ignore[type-arg]
    rng = np.random.default_rng(seed)
    poses = []
    for i, (a, s) in enumerate(zip(ANGLES, SHIFTS, strict=False)):
        cam, prj = true_corners(RIG, BOARD, BoardPose.from_angles(*a, s).centred(BOARD))
        cam = cam + noise_px * rng.standard_normal(cam.shape)
        prj = prj + noise_px * rng.standard_normal(prj.shape)
        poses.append({"name": f"p{i}", "camera_px": cam.tolist(), "projector_px": prj.tolist()})
    return {
        "format": "gcps-procam-correspondences/1",
        "camera_size": [800, 600],
        "projector_size": [1024, 768],
        "poses": poses,
    }


def run(tmp_path: Path, data: dict | None, *extra: str) -> int:  # type: ignore[type-arg]
    args = ["--quiet", "calibrate-procam", "--board", "chessboard:9x6:20"]
    if data is not None:
        (tmp_path / "c.json").write_text(json.dumps(data))
        args += ["--correspondences", str(tmp_path / "c.json")]
    return main([*args, "--out", str(tmp_path / "rig.json"), "--report", str(tmp_path / "report.json"), *extra])


def test_correspondences_calibrate_the_rig(tmp_path: Path) -> None:
    (tmp_path / "fig").mkdir()
    assert run(tmp_path, correspondences(), "--fix-k3", "--figures", str(tmp_path / "fig")) == 0
    svgs = sorted(p.name for p in (tmp_path / "fig").iterdir())
    assert svgs == [f"residuals_p{i}.svg" for i in range(7)]
    svg = (tmp_path / "fig" / "residuals_p0.svg").read_text()
    assert svg.startswith("<svg") and svg.count("<line") == 2 * BOARD.count
    rig = PinholeRig.from_json((tmp_path / "rig.json").read_text())
    report = json.loads((tmp_path / "report.json").read_text())
    assert abs(rig.camera.K[0][0] / 1000.0 - 1) < 0.002 and abs(rig.projector.K[0][0] / 1300.0 - 1) < 0.002
    R, Rt = np.asarray(rig.R), np.asarray(RIG.R)
    assert math.degrees(math.acos(min(1.0, (np.trace(R @ Rt.T) - 1) / 2))) < 0.05
    assert abs(np.linalg.norm(rig.T) / np.linalg.norm(RIG.T) - 1) < 0.001
    for key in ("camera_rms_px", "projector_rms_px", "stereo_rms_px"):
        assert 0.015 < report[key] < 0.04  # 0.02 px noise per coordinate: RMS ~ 0.028 over x and y
    pose = report["poses"][0]
    assert set(pose) >= {"name", "used", "reason", "rms_px", "corners"} and pose["used"] and pose["reason"] is None
    assert set(pose["corners"][0]) >= {"camera_px", "projector_px", "residual_camera_px", "residual_projector_px"}
    assert report["camera"]["std"]["fx"] > 0 and 0 < report["coverage"]["camera"] <= 1
    assert report["pose_diversity"]["max_angle_between_boards_deg"] > 30


def test_correspondence_with_a_reversed_projector_list_is_left_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = correspondences()
    data["poses"][2]["projector_px"] = data["poses"][2]["projector_px"][::-1]
    assert (
        main(
            [
                "calibrate-procam",
                "--board",
                "chessboard:9x6:20",
                "--correspondences",
                _write(tmp_path, data),
                "--out",
                str(tmp_path / "rig.json"),
                "--report",
                str(tmp_path / "report.json"),
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["poses_used"] == 6 and "corner_order_flipped" in summary["warnings"]


def _write(tmp_path: Path, data: dict) -> str:  # type: ignore[type-arg]
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data))
    return str(path)


@pytest.mark.parametrize(
    ("board", "data_change", "extra", "message"),
    [
        ("chessboard:9x6", None, [], "--board"),
        ("chessboard:9x6:-2", None, [], "--board"),
        ("hexagons:9x6:20", None, [], "--board"),
        ("chessboard:9x6:20", "count", [], "expected 54"),
        ("chessboard:9x6:20", "format", [], "format"),
        ("chessboard:9x6:20", "key", [], "unknown key"),
        ("chessboard:9x6:20", "one", [], "at least 2 usable poses"),
        ("chessboard:9x6:20", None, ["--poses", "nowhere"], "either --poses"),
        ("chessboard:9x6:20", None, ["--min-decoded", "2"], "--min-decoded"),
    ],
)
def test_bad_input_exits_2_naming_the_problem(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    board: str,
    data_change: str | None,
    extra: list[str],
    message: str,
) -> None:
    data = correspondences()
    if data_change == "count":
        data["poses"][1]["camera_px"] = data["poses"][1]["camera_px"][:-1]
    elif data_change == "format":
        data["format"] = "other"
    elif data_change == "key":
        data["poses"][0]["camerapx"] = []
    elif data_change == "one":
        data["poses"] = data["poses"][:1]
    args = ["calibrate-procam", "--board", board, "--correspondences", _write(tmp_path, data)]
    code = main([*args, "--out", str(tmp_path / "rig.json"), "--report", str(tmp_path / "report.json"), *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "rig.json").exists() and not (tmp_path / "report.json").exists()


def test_missing_capture_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(
        [
            "calibrate-procam",
            "--board",
            "chessboard:9x6:20",
            "--codec",
            "gcps-v1",
            "--poses",
            str(tmp_path / "none"),
            "--out",
            str(tmp_path / "rig.json"),
            "--report",
            str(tmp_path / "report.json"),
        ]
    )
    assert code == 2 and "--poses" in capsys.readouterr().err


def test_example_correspondence_file_calibrates(tmp_path: Path) -> None:
    """examples/procam-correspondences.json (7 poses of a 9x6 board, 20 mm squares, exact projections of
    this module's rig plus 0.02 px noise, rounded to 0.001 px) gives that rig back."""
    example = Path(__file__).resolve().parents[2] / "examples" / "procam-correspondences.json"
    args = ["--quiet", "calibrate-procam", "--board", "chessboard:9x6:20", "--correspondences", str(example)]
    assert main([*args, "--fix-k3", "--out", str(tmp_path / "rig.json"), "--report", str(tmp_path / "r.json")]) == 0
    rig = PinholeRig.from_json((tmp_path / "rig.json").read_text())
    assert (
        abs(rig.camera.K[0][0] / 1000.0 - 1) < 0.002 and abs(np.linalg.norm(rig.T) / np.linalg.norm(RIG.T) - 1) < 0.001
    )
