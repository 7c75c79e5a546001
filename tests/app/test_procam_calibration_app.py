"""Projector-camera calibration through the REST API (jobs in-process, through the handler a worker calls).

Six board poses of a known distorted pinhole rig (tests/app/procam_stacks.py: camera fx 400,
projector fx 420, baseline 122.07 mm; one pose with the board partly out of view) are uploaded as
board captures of a 320x240 crossed-axes rig; the job must give the camera fx within 0.5 %, the
projector fx and the baseline within 1 %, use five poses and warn about the sixth. Applying makes
the rig a pinhole rig with the calibrated file and a history entry; bad requests answer 400 with a
sentence naming the field; a job whose poses are all unusable fails with each pose's reason; the
command line gives the same report and rig file for the same stacks (to 1e-5 px, see
PARITY_RTOL).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from metrology.calibrations.models import ProcamCalibration
from metrology.cli import main
from metrology.core.geometry.pinhole import PinholeRig
from metrology.rigs.models import Rig, RigParameters
from tests.app.procam_stacks import (
    BOARD_SPEC,
    OPTIONS,
    RIG_320,
    TRUE_RIG,
    UNUSABLE_POSE,
    codec_dict,
    pose_name,
    pose_stacks,
    pose_zip,
    pose_zips,
)

# Jobs are enqueued on commit: these tests need real commits.
pytestmark = pytest.mark.django_db(transaction=True)

CAMERA_FX_TOLERANCE = 0.005  # relative
PROJECTOR_FX_TOLERANCE = 0.01
BASELINE_TOLERANCE = 0.01


def upload(api, rig_id: int, data: bytes, name: str, role: str = "board"):
    handle = io.BytesIO(data)
    handle.name = name
    return api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role}, format="multipart")


@pytest.fixture
def rig320(api) -> dict:
    response = api.post("/api/rigs/", {**RIG_320, "name": "procam bench"}, format="json")
    assert response.status_code == 201, response.content
    return response.json()


@pytest.fixture
def poses(api, rig320) -> list[int]:
    ids = []
    for index, data in enumerate(pose_zips()):
        response = upload(api, rig320["id"], data, pose_name(index))
        assert response.status_code == 201, response.content
        assert response.json()["role"] == "board"
        ids.append(response.json()["id"])
    return ids


def request(api, rig_id: int, poses: list[int], **extra):
    body = {"rig": rig_id, "poses": poses, "board": BOARD_SPEC, "options": OPTIONS, **extra}
    return api.post("/api/procam-calibrations/", body, format="json")


def relative(a: float, b: float) -> float:
    return abs(a / b - 1)


@pytest.mark.slow
def test_calibration_job_report_apply_and_history(api, rig320, poses, monkeypatch):
    from metrology.jobs.services import JobRun

    phases: list[tuple[int, str]] = []
    original = JobRun.progress

    def recording(self, percent: int, phase: str = "") -> None:
        phases.append((percent, phase))
        original(self, percent, phase)

    monkeypatch.setattr(JobRun, "progress", recording)
    response = request(api, rig320["id"], poses)
    assert response.status_code == 202, response.content
    body = api.get(f"/api/procam-calibrations/{response.json()['id']}/").json()
    assert body["status"] == "done", body["error"]
    assert body["poses"] == poses and body["board"] == BOARD_SPEC and body["options"]["fix_k3"] is True
    # the progress a user sees: read and observe pose i of 6, then calibrate
    names = [phase for _, phase in phases]
    assert [f"observe pose {i} of 6" for i in range(1, 7)] == [n for n in names if n.startswith("observe")]
    assert "read pose 1 of 6" in names and "calibrate" in names
    assert [p for p, _ in phases] == sorted(p for p, _ in phases)  # never goes back

    report = body["report"]
    assert report["format"] == "gcps-procam-report/1" and report["poses_total"] == 6 and report["poses_used"] == 5
    bad = report["poses"][UNUSABLE_POSE]
    assert bad["name"] == pose_name(UNUSABLE_POSE) and not bad["used"] and bad["cause"] == "board_not_found"
    causes = [w["cause"] for w in report["warnings"]]  # the six poses leave image edges bare: coverage too
    assert (
        causes == body["warnings"] and causes[0] == "board_not_found" and set(causes) <= {"board_not_found", "coverage"}
    )
    true_K, true_P = np.asarray(TRUE_RIG.camera.K), np.asarray(TRUE_RIG.projector.K)
    assert relative(report["camera"]["K"][0][0], true_K[0, 0]) < CAMERA_FX_TOLERANCE
    assert relative(report["camera"]["K"][1][1], true_K[1, 1]) < CAMERA_FX_TOLERANCE
    assert relative(report["projector"]["K"][0][0], true_P[0, 0]) < PROJECTOR_FX_TOLERANCE
    assert relative(report["baseline_mm"], float(np.linalg.norm(TRUE_RIG.T))) < BASELINE_TOLERANCE
    assert body["stereo_rms_px"] == report["stereo_rms_px"] < 0.2  # 8-bit noise of 1.5 grey levels
    assert set(body["timings"]) >= {"calibrate_procam.read", "calibrate_procam.observe", "calibrate_procam.calibrate"}

    rig_file = PinholeRig.from_dict(body["rig_file"])
    assert rig_file.camera.width_px == 320 and rig_file.projector.width == 320
    assert relative(float(np.asarray(rig_file.camera.K)[0, 0]), true_K[0, 0]) < CAMERA_FX_TOLERANCE
    # the files as the command writes them
    served = api.get(f"/api/procam-calibrations/{body['id']}/report.json")
    assert served.status_code == 200 and served["Content-Type"] == "application/json"
    assert json.loads(served.content) == report and served.content.decode().endswith("}\n")
    rig_json = api.get(f"/api/procam-calibrations/{body['id']}/rig.json")
    assert rig_json.status_code == 200 and rig_json.content.decode() == rig_file.to_json()

    # apply: the rig becomes a pinhole rig with that file; history says which calibration set it
    assert body["rig_before"]["model"] == "crossed_axes" and body["rig_before"]["rig_file"]["L_mm"] == RIG_320["L_mm"]
    applied = api.post(f"/api/procam-calibrations/{body['id']}/apply/")
    assert applied.status_code == 200 and applied.json()["applied"] is True
    rig = api.get(f"/api/rigs/{rig320['id']}/").json()
    assert rig["model"] == "pinhole" and rig["pinhole"] == rig_file.to_dict()
    assert (rig["width_px"], rig["height_px"]) == (320, 240) and rig["L_mm"] is None
    # the rig's default codec (gcps-v1, another projector) becomes the poses' codec, so that
    # captures uploaded without a codec.json are of the calibrated projector
    from metrology.captures.models import Capture

    assert rig320["codec"] == "gcps-v1" and rig["codec"] == Capture.objects.get(pk=poses[0]).codec
    assert [h["source"] for h in rig["history"]] == ["created", "calibration"]
    assert rig["history"][0]["values"]["L_mm"] == RIG_320["L_mm"]  # what it replaced stays
    assert rig["history"][1]["procam_calibration"] == body["id"] and rig["history"][1]["values"] == rig["pinhole"]
    again = api.post(f"/api/procam-calibrations/{body['id']}/apply/")
    assert again.status_code == 200 and again.json()["applied_at"] == applied.json()["applied_at"]
    assert RigParameters.objects.filter(rig_id=rig320["id"]).count() == 2
    listed = api.get(f"/api/procam-calibrations/?rig={rig320['id']}").json()
    assert [c["id"] for c in listed] == [body["id"]] and "report" not in listed[0]


def test_apply_before_done_is_refused_and_apply_on_request_applies(api, rig320, poses, monkeypatch):
    import metrology.jobs.services as job_services

    queued: list[int] = []
    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: queued.append(job_id))
    response = request(api, rig320["id"], poses[:3], apply=True)
    assert response.status_code == 202 and response.json()["status"] == "queued"
    calibration_id = response.json()["id"]
    refused = api.post(f"/api/procam-calibrations/{calibration_id}/apply/")
    assert refused.status_code == 400
    assert refused.json()["error"] == f"procam calibration {calibration_id} cannot be applied: its job is queued"
    assert api.get(f"/api/procam-calibrations/{calibration_id}/report.json").status_code == 404
    assert api.get(f"/api/procam-calibrations/{calibration_id}/rig.json").status_code == 404
    assert Rig.objects.get(pk=rig320["id"]).model == "crossed_axes"
    assert job_services.execute_job(queued[0]) == "done"
    body = api.get(f"/api/procam-calibrations/{calibration_id}/").json()
    assert body["applied"] is True and body["report"]["poses_used"] == 3
    rig = Rig.objects.get(pk=rig320["id"])
    assert rig.model == "pinhole" and rig.rig_file() == PinholeRig.from_dict(body["rig_file"]).to_dict()


def test_bad_requests_answer_400_naming_the_field(api, other_api, rig320, poses):
    rig_id = rig320["id"]
    other_rig = other_api.post("/api/rigs/", {**RIG_320, "name": "bob's"}, format="json").json()
    bobs = upload(other_api, other_rig["id"], pose_zips()[0], "b.zip").json()["id"]
    u_only = upload(api, rig_id, pose_zip(pose_stacks()[0][[*range(13), 26, 27]], codec_dict("u")), "u.zip")
    assert u_only.status_code == 201, u_only.content
    obj = upload(api, rig_id, pose_zips()[1], "o.zip", role="object").json()["id"]
    wrong = upload(api, rig_id, pose_zip(np.zeros((28, 200, 300), np.uint8)), "small.zip")
    assert wrong.status_code == 400 and "the frames are 300x200 px but the rig is 320x240 px" in wrong.json()["error"]
    cases = [
        ({"poses": poses[:1]}, "poses: give at least 2 board captures (8 to 12 recommended), got 1"),
        ({"poses": [poses[0], bobs]}, f"poses[1]: capture {bobs} does not exist among yours"),
        ({"poses": [poses[0], poses[0]]}, f"poses[1]: capture {poses[0]} is given twice"),
        ({"poses": [poses[0], obj]}, f"poses[1]: capture {obj} has role 'object'; expected board"),
        (
            {"poses": [poses[0], u_only.json()["id"]]},
            f"poses[1]: capture {u_only.json()['id']}'s codec does not code the projector's v axis; "
            "a board pose needs both axes coded (docs/codecs.md)",
        ),
        ({"board": "chessboard:9x7"}, "board: 'chessboard:9x7': expected chessboard:COLSxROWS:SQUARE_MM"),
        ({"board": "chessboard:2x7:20"}, "board: a chessboard needs at least 3x3 inner corners, got 2x7"),
        ({"board": "chessboard:9x100000:20"}, "board: at most 100 points per row and 100 rows, got 9x100000"),
        ({"options": {"colour": 1}}, "options: unknown option(s) colour; accepted: window, min_decoded"),
        ({"options": {"window": 0}}, "options: window must be 1..200 pixels, got 0"),
        ({"options": {"min_decoded": "half"}}, "options: min_decoded must be a number within 0..1, got 'half'"),
        ({"rig": other_rig["id"]}, f"rig: rig {other_rig['id']} does not exist among yours"),
    ]
    for change, message in cases:
        body = {"rig": rig_id, "poses": poses, "board": BOARD_SPEC, "options": OPTIONS, **change}
        response = api.post("/api/procam-calibrations/", body, format="json")
        assert response.status_code == 400, (change, response.content)
        assert message in response.json()["error"], (change, response.json())
    # a stored pose whose size is no longer the rig's camera size (the rig's camera changed)
    stored = Rig.objects.get(pk=rig_id)
    Rig.objects.filter(pk=rig_id).update(parameters={**stored.parameters, "width_px": 640, "height_px": 480})
    response = request(api, rig_id, poses)
    assert response.status_code == 400
    assert f"poses[0]: capture {poses[0]} is 320x240 px but the rig's camera is 640x480 px" in response.json()["error"]
    assert not ProcamCalibration.objects.exists()
    for body in ({"rig": rig_id, "poses": "1,2", "board": BOARD_SPEC}, {"rig": rig_id, "poses": [1, 2]}):
        response = api.post("/api/procam-calibrations/", body, format="json")
        assert response.status_code == 400 and response.json()["error"], response.content
    assert api.get("/api/procam-calibrations/?rig=abc").status_code == 400
    assert api.get(f"/api/procam-calibrations/?rig={other_rig['id']}").status_code == 400


def test_poses_without_a_board_fail_the_job_with_each_reason(api, rig320):
    rng = np.random.default_rng(3)
    ids = []
    for name in ("blank-a.zip", "blank-b.zip"):
        images = rng.integers(90, 110, size=(28, 240, 320), dtype=np.uint8)
        ids.append(upload(api, rig320["id"], pose_zip(images), name).json()["id"])
    response = request(api, rig320["id"], ids)
    assert response.status_code == 202, response.content
    body = api.get(f"/api/procam-calibrations/{response.json()['id']}/").json()
    assert body["status"] == "failed" and body["report"] == {} and body["rig_file"] is None
    assert body["error"] == (
        "need at least 2 usable poses, have 0 (blank-a.zip: board not found in the board image; "
        "blank-b.zip: board not found in the board image)"
    )
    refused = api.post(f"/api/procam-calibrations/{body['id']}/apply/")
    assert refused.status_code == 400 and "its job is failed" in refused.json()["error"]


@pytest.mark.slow
def test_job_and_command_line_give_the_same_report_and_rig_file(api, rig320, poses, tmp_path: Path):
    response = request(api, rig320["id"], poses)
    calibration = ProcamCalibration.objects.get(pk=response.json()["id"])
    assert calibration.job.status == "done", calibration.job.error
    paths = []
    for index, data in enumerate(pose_zips()):
        path = tmp_path / pose_name(index)
        path.write_bytes(data)
        paths.append(str(path))
    out, report_path = tmp_path / "rig.json", tmp_path / "report.json"
    args = ["calibrate-procam", "--board", BOARD_SPEC, "--fix-k3", "--poses", *paths]
    assert main(["--quiet", *args, "--out", str(out), "--report", str(report_path)]) == 0
    cli_report = json.loads(report_path.read_text())
    job_report = json.loads(api.get(f"/api/procam-calibrations/{calibration.pk}/report.json").content)
    assert (
        set(cli_report.pop("timings_s"))
        == set(job_report.pop("timings_s"))
        == {"read", "observe", "calibrate", "total"}
    )
    assert_same(cli_report, job_report)
    job_rig = json.loads(api.get(f"/api/procam-calibrations/{calibration.pk}/rig.json").content)
    assert list(job_rig) == list(json.loads(out.read_text()))  # the same keys, in the same order
    assert_same(json.loads(out.read_text()), job_rig)
    assert_same(json.loads(out.read_text()), calibration.rig_file)


PARITY_RTOL, PARITY_ATOL = 1e-5, 1e-5
"""Tolerances of the command/job comparison (relative; absolute, in the report's units: px, mm).
Two runs on the same stacks find the same corners bit for bit, but OpenCV's calibration sums in
parallel threads, so its results vary between runs by up to about 1e-6 px (measured: 9.4e-7 px on
the camera's cx over five runs; bit-identical with ``cv2.setNumThreads(1)``)."""


def assert_same(expected, actual, where: str = "") -> None:
    """``actual`` equals ``expected``: same keys, lists, strings, booleans; numbers within PARITY_RTOL."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict) and set(actual) == set(expected), where
        for key, value in expected.items():
            assert_same(value, actual[key], f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), where
        for index, (a, b) in enumerate(zip(expected, actual, strict=True)):
            assert_same(a, b, f"{where}[{index}]")
    elif isinstance(expected, float) and not isinstance(actual, bool):
        assert actual == pytest.approx(expected, rel=PARITY_RTOL, abs=PARITY_ATOL), where
    else:
        assert actual == expected, where
