"""The projector-camera calibration pages (Django test client): the form uploads the pose zips into one
new capture session and starts the job; the detail page shows the report's numbers, the warnings,
the per-pose table and figures (served as SVG under a script-free policy); Apply converts the rig and
its page and history show the calibration; a refused form stores nothing."""

from __future__ import annotations

import re
from xml.etree import ElementTree

import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.utils.html import escape

from metrology.calibrations.models import ProcamCalibration
from metrology.captures.models import Capture, CaptureSession
from metrology.rigs.models import Rig
from metrology.rigs.services import create_rig
from tests.app.procam_stacks import BOARD_SPEC, RIG_320, TRUE_RIG, UNUSABLE_POSE, pose_name, pose_zip, pose_zips
from tests.conftest import stored_files


def pose_files() -> list[SimpleUploadedFile]:
    return [SimpleUploadedFile(pose_name(i), data, "application/zip") for i, data in enumerate(pose_zips())]


@pytest.fixture
def rig320(alice):
    return create_rig(owner=alice, data={**RIG_320, "name": "procam bench"})


@pytest.mark.slow
def test_new_calibration_page_upload_detail_apply(client_alice, alice, rig320, run_jobs):
    page = client_alice.get(f"/procam-calibrations/new/?rig={rig320.pk}")
    html = page.content.decode()
    assert page.status_code == 200
    assert "inner corners of a chessboard (where four squares meet), points per row first" in html
    assert "chessboard:9x7:25" in html and "multiple" in html and "converts it to a pinhole rig" in html
    form = {"rig": rig320.pk, "board": BOARD_SPEC, "pose_files": pose_files(), "min_decoded": "0.25", "fix_k3": "on"}
    with run_jobs():
        response = client_alice.post("/procam-calibrations/new/", form)
    assert response.status_code == 302, response.content.decode()[:3000]
    calibration = ProcamCalibration.objects.get()
    assert response["Location"] == f"/procam-calibrations/{calibration.pk}/"
    captures = list(Capture.objects.filter(rig=rig320).order_by("id"))
    assert [c.role for c in captures] == ["board"] * 6 and len({c.session_id for c in captures}) == 1
    assert [c.original_name for c in captures] == [pose_name(i) for i in range(6)]

    html = client_alice.get(response["Location"]).content.decode()
    calibration.refresh_from_db()
    assert calibration.job.status == "done", calibration.job.error
    report = calibration.report
    fx = report["camera"]["K"][0][0]
    assert abs(fx / np.asarray(TRUE_RIG.camera.K)[0, 0] - 1) < 0.005
    assert f"{fx:.2f} px" in html and f"{report['stereo_rms_px']:.3f} px" in html
    assert f"{report['baseline_mm']:.2f} mm" in html and f"{report['camera']['std']['fx']:.2g}" in html
    assert "board_not_found" in html and escape(report["warnings"][0]["action"]) in html
    assert "5 of 6" in html and "board not found in the board image" in html
    assert f"{report['leave_one_out']['median_px']:.3f} px" in html and "refined jointly" in html
    for pose in report["poses"]:
        if pose["used"]:  # each used pose's left-out prediction, in its row
            assert f"{pose['leave_one_out_projector_rms_px']:.3f}</td>" in html
    used = [i for i in range(6) if i != UNUSABLE_POSE]
    for index in used:
        assert f'/procam-calibrations/{calibration.pk}/residuals/{index}.svg"' in html
    assert f"/residuals/{UNUSABLE_POSE}.svg" not in html
    assert (
        "This changes the rig's model</strong> from <em>Crossed optical axes (the paper&#x27;s model)</em> "
        "to <em>Calibrated pinhole camera and projector</em>" in html
    )

    # the figures: well-formed SVG, no script allowed in them
    svg = client_alice.get(f"/procam-calibrations/{calibration.pk}/residuals/{used[0]}.svg")
    assert svg.status_code == 200 and svg["Content-Type"].startswith("image/svg+xml")
    assert svg["Content-Security-Policy"].startswith("default-src 'none'")
    ElementTree.fromstring(svg.content)
    assert client_alice.get(f"/procam-calibrations/{calibration.pk}/residuals/{UNUSABLE_POSE}.svg").status_code == 404
    for device in ("camera", "projector"):
        coverage = client_alice.get(f"/procam-calibrations/{calibration.pk}/coverage/{device}.svg")
        root = ElementTree.fromstring(coverage.content)
        shaded = [r for r in root.iter("{http://www.w3.org/2000/svg}rect") if r.get("fill") == "#cfe3f7"]
        assert len(shaded) == round(report["coverage"][device] * 64)  # the report's covered cells, drawn
    assert client_alice.get(f"/procam-calibrations/{calibration.pk}/coverage/other.svg").status_code == 404

    # apply: to the rig page, which shows the pinhole calibration and its history
    applied = client_alice.post(f"/procam-calibrations/{calibration.pk}/apply/")
    assert applied.status_code == 302 and applied["Location"] == f"/rigs/{rig320.pk}/"
    rig = Rig.objects.get(pk=rig320.pk)
    assert rig.model == "pinhole" and rig.rig_file() == calibration.rig_file
    html = client_alice.get(applied["Location"]).content.decode()
    assert "pinhole camera and projector" in html
    K = rig.parameters["camera"]["K"]  # six significant digits, not the stored float's seventeen
    assert f"K [[{K[0][0]:.6g}, 0, {K[0][2]:.6g}], [0, {K[1][1]:.6g}, {K[1][2]:.6g}], [0, 0, 1]]" in html
    assert f"projector-camera calibration {calibration.pk}</a>" in html
    assert (
        f"pinhole: camera fx {fx:.2f} px" in html
        and "Crossed optical axes (the paper&#x27;s model): L 1022 mm, d 352 mm, alpha 0.332 rad" in html
    )  # new entry and the one it replaced
    listing = client_alice.get("/procam-calibrations/").content.decode()
    assert f"Procam calibration {calibration.pk}" in listing and "board_not_found" in listing
    assert 'aria-current="page">Procam calibrations' in listing


def test_refused_form_stores_nothing(client_alice, alice, rig320, media_root):
    bad = SimpleUploadedFile("bad.zip", pose_zip(np.zeros((28, 100, 100), np.uint8)), "application/zip")
    files = [*pose_files()[:2], bad]
    response = client_alice.post(
        "/procam-calibrations/new/", {"rig": rig320.pk, "board": BOARD_SPEC, "pose_files": files, "min_decoded": "0.25"}
    )
    html = response.content.decode()
    assert response.status_code == 400
    assert "pose file bad.zip: capture stack refused: the frames are 100x100 px but the rig is 320x240 px" in html
    assert not Capture.objects.exists() and not CaptureSession.objects.exists()
    assert not ProcamCalibration.objects.exists() and stored_files(media_root) == []
    response = client_alice.post(
        "/procam-calibrations/new/",
        {"rig": rig320.pk, "board": "chessboard:9x7", "pose_files": pose_files()[:2], "min_decoded": "0.25"},
    )
    assert response.status_code == 400 and "board: &#x27;chessboard:9x7&#x27;: expected" in response.content.decode()
    assert stored_files(media_root) == []
    one = client_alice.post(
        "/procam-calibrations/new/",
        {"rig": rig320.pk, "board": BOARD_SPEC, "pose_files": pose_files()[:1], "min_decoded": "0.25"},
    )
    assert one.status_code == 400 and "Give at least two poses" in one.content.decode()


def test_other_users_calibration_is_not_found(client_alice, client_bob, alice, rig320, run_jobs):
    from metrology.calibrations.procam_services import request_procam_calibration
    from metrology.captures.services import upload_capture

    ids = [upload_capture(owner=alice, rig=rig320, upload=f, role="board").pk for f in pose_files()[:3]]
    with run_jobs():
        calibration = request_procam_calibration(owner=alice, rig=rig320, pose_ids=ids, board=BOARD_SPEC)
    for url in ("", "residuals/0.svg", "coverage/camera.svg"):
        assert client_bob.get(f"/procam-calibrations/{calibration.pk}/{url}").status_code == 404
    assert client_bob.post(f"/procam-calibrations/{calibration.pk}/apply/").status_code == 404
    assert re.search(r"Procam calibration \d+", client_bob.get("/procam-calibrations/").content.decode()) is None


def test_form_passes_decoder_thresholds(client_alice, rig320):
    """The page offers the API's decoder thresholds; given, they reach the job's options; empty, the
    decoder's defaults stay (None)."""
    page = client_alice.get(f"/procam-calibrations/new/?rig={rig320.pk}").content.decode()
    assert 'name="min_modulation"' in page and 'name="min_inverse_contrast"' in page
    form = {"rig": rig320.pk, "board": BOARD_SPEC, "pose_files": pose_files()[:2], "min_decoded": "0.25"}
    given = client_alice.post(
        "/procam-calibrations/new/", {**form, "min_modulation": "6.5", "min_inverse_contrast": "3"}
    )
    assert given.status_code == 302, given.content.decode()[:2000]
    options = ProcamCalibration.objects.get().options
    assert options["min_modulation"] == 6.5 and options["min_inverse_contrast"] == 3.0
    refused = client_alice.post(
        "/procam-calibrations/new/", {**form, "pose_files": pose_files()[:2], "min_modulation": "-1"}
    )
    assert refused.status_code == 400 and ProcamCalibration.objects.count() == 1
    default = client_alice.post("/procam-calibrations/new/", {**form, "pose_files": pose_files()[:2]})
    assert default.status_code == 302
    latest = ProcamCalibration.objects.order_by("-id").first()
    assert (
        latest is not None
        and latest.options["min_modulation"] is None
        and latest.options["min_inverse_contrast"] is None
    )
