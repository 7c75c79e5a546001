"""The projector-camera calibration page shows what the poses cannot determine (issue 21, item 4):
beside each intrinsic's std its leave-one-pose-out spread (marked when they disagree) and its
correlation with the boards' distance; per device the focal length's correlation with the boards'
mean distance and whether they are separable; the ``focal_distance_coupled`` warning with what to
do. The reports are the core's (Django test client; a stored done calibration, as the job leaves
it): the six noisy poses of tests/core/procam/noisy_corners.py, boards facing the camera, and the
real kamino410 captures through ``gcps calibrate-procam``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from django.utils.html import escape

from metrology.calibrations.models import ProcamCalibration
from metrology.cli import main
from metrology.dashboard.templatetags.dashboard import num, sig
from metrology.jobs.models import Job
from metrology.pipeline.calibrate_procam import ProcamOptions, report_json_text
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG
from tests.core.procam.noisy_corners import FACING, board_poses, calibrate, noisy, observations
from tests.datasets import dataset_path, require_dataset

ROOT = Path(__file__).resolve().parents[2]
KAMINO = dataset_path("kamino410-procam-calibration", "sample_data")
KAMINO_CODEC = ROOT / "examples" / "kamino410-procam.codec.json"

pytestmark = pytest.mark.django_db


def stored(owner: Any, report: dict[str, Any], board: str = "chessboard:9x6:20") -> ProcamCalibration:
    """A done calibration holding ``report`` as the job stores it (non-finite numbers as null)."""
    rig = create_rig(owner=owner, data={**SMALL_RIG, "width_px": 800, "height_px": 600, "name": "bench"})
    job = Job.objects.create(owner=owner, kind=Job.Kind.PROCAM_CALIBRATION, status=Job.Status.DONE, progress=100)
    text = report_json_text(report)
    return ProcamCalibration.objects.create(
        owner=owner,
        rig=rig,
        options=ProcamOptions(board=board).to_dict(),
        report=json.loads(text),
        report_json=text,
        job=job,
    )


def page(client: Any, calibration: ProcamCalibration) -> str:
    response = client.get(f"/procam-calibrations/{calibration.pk}/")
    assert response.status_code == 200
    return str(response.content.decode())


def assert_shows_the_uncertainty(html: str, report: dict[str, Any]) -> None:
    """Every intrinsic's spread and distance correlation in its device's table, each device's focal
    correlation and mean distance in the section, and the disagreements named."""
    u = report["uncertainty"]
    assert "What the poses cannot determine" in html and "left-out spread" in html
    for device in ("camera", "projector"):
        entry = u[device]
        assert f"{entry['focal_parameter']}: {num(entry['focal_distance_correlation'], 4)}" in html
        assert f"{num(entry['mean_distance_mm'], 1)} ± {sig(entry['mean_distance_std_mm'])} mm" in html
        for name, item in entry["intrinsics"].items():
            assert f">{num(item['distance_correlation'], 4)}</td>" in html, (device, name)
            assert f"{sig(item['leave_one_out_std'])}" in html, (device, name)
            if item["agrees"] is False:
                assert f"(× {num(item['spread_ratio'], 1)}, disagrees)" in html
    if u["disagreements"]:
        assert escape(", ".join(u["disagreements"])) in html
    else:
        assert "they agree within a factor 4" in html


@pytest.fixture(scope="module")
def six_report() -> dict[str, Any]:
    """The report of noisy_corners.py's six poses (0.1 px noise, joint fit)."""
    report: dict[str, Any] = calibrate(observations(np.random.default_rng(2)), True).report
    return report


def test_page_shows_std_spread_and_correlation(client_alice: Any, alice: Any, six_report: dict[str, Any]) -> None:
    """Six poses tilted up to 25 degrees, 0.1 px noise: separable (correlations 0.99 < 0.999)."""
    report = six_report
    html = page(client_alice, stored(alice, report))
    assert_shows_the_uncertainty(html, report)
    assert "focal_distance_coupled" not in html and '<strong class="disagree">no</strong>' not in html
    assert html.count('<td class="separable">yes</td>') == 2


def test_page_of_a_report_without_uncertainty(client_alice: Any, alice: Any, six_report: dict[str, Any]) -> None:
    """Reports stored before keep their page, without the section or the columns."""
    report = {key: value for key, value in six_report.items() if key != "uncertainty"}
    html = page(client_alice, stored(alice, report))
    assert "What the poses cannot determine" not in html and "left-out spread" not in html
    assert f"{report['camera']['std']['fx']:.2g}" in html


@pytest.mark.slow
def test_page_warns_when_focal_length_and_distance_are_coupled(client_alice: Any, alice: Any) -> None:
    """Boards facing the camera at one distance: the warning with how to tilt the board, and
    "no" for both devices."""
    report = calibrate(noisy(board_poses(FACING), np.random.default_rng(0), 0.05), True).report
    assert report["uncertainty"]["coupled"] == ["camera", "projector"]
    html = page(client_alice, stored(alice, report))
    (warning,) = [w for w in report["warnings"] if w["cause"] == "focal_distance_coupled"]
    assert "focal_distance_coupled" in html and escape(warning["message"]) in html
    assert escape(warning["action"]) in html and "Tilt the board by 20 to 40 degrees about both of its axes" in html
    assert html.count('<strong class="disagree">no</strong> (beyond 0.999)') == 2
    assert_shows_the_uncertainty(html, report)


@pytest.fixture(scope="module")
def kamino_report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    require_dataset(KAMINO / "capture_0", "kamino410 procam dataset")
    out = tmp_path_factory.mktemp("kamino-page")
    poses = [str(KAMINO / f"capture_{i}") for i in range(5)]
    args = ["--quiet", "calibrate-procam", "--codec", str(KAMINO_CODEC), "--board", "chessboard:9x7:75"]
    assert main([*args, "--poses", *poses, "--out", str(out / "rig.json"), "--report", str(out / "report.json")]) == 0
    report: dict[str, Any] = json.loads((out / "report.json").read_text())
    return report


@pytest.mark.slow
def test_page_shows_the_kamino410_numbers(client_alice: Any, alice: Any, kamino_report: dict[str, Any]) -> None:
    """The real poses: separable (camera 0.990, projector 0.909), and the left-out spread of the
    camera's focal length 5 times its std, which the page says."""
    html = page(client_alice, stored(alice, kamino_report, "chessboard:9x7:75"))
    assert_shows_the_uncertainty(html, kamino_report)
    assert "camera.fx" in kamino_report["uncertainty"]["disagreements"]
    assert "they disagree by more than a factor 4 for camera.fx" in html
