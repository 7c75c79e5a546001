"""Issue 12 must-show: characterization of a stage series on a pinhole rig, end to end through the
API (uploads with role stage and z_in_mm, POST /api/characterizations/, the job in-process, the
stored report and its CSV). The stage moves the plane along the reference plane's normal (the
virtual rig's scenes face the camera: the normal is the camera's Z), so the true slopes are 1."""

from __future__ import annotations

import io

import numpy as np
import pytest
from django.test import Client

from metrology.characterizations.models import Characterization
from tests.app.uploads import characterize, post_capture
from tests.pinhole_stacks import CODEC, capture_zip

pytestmark = pytest.mark.django_db(transaction=True)

STAGE_MM = (0.0, 5.0, 10.0, 15.0)


def upload_stage(api, rig_id: int, z_in_mm: float):
    data, _ = capture_zip("plane", z_mm=z_in_mm)
    handle = io.BytesIO(data)
    handle.name = f"stage-{z_in_mm}.zip"
    return api.post(
        f"/api/rigs/{rig_id}/captures/",
        {"file": handle, "role": "stage", "z_in_mm": str(z_in_mm)},
        format="multipart",
    )


@pytest.mark.slow
def test_pinhole_characterization_through_the_api(api, pinhole_rig):
    rig_id = pinhole_rig["id"]
    plate, _ = capture_zip("plane", z_mm=0.0)
    ref = post_capture(api, rig_id, plate, "reference")
    assert ref.status_code == 201, ref.content
    series = []
    for z in STAGE_MM:
        stage = upload_stage(api, rig_id, z)
        assert stage.status_code == 201, stage.content
        assert stage.json()["z_in_mm"] == z
        series.append({"z_in_mm": z, "captures": [stage.json()["id"]]})
    body = characterize(api, rig_id, ref.json()["id"], series, {"n_points": 7, "rows": 3})
    assert body["rig_values"]["model"] == "pinhole"
    results = body["results"]
    assert results["model"] == "pinhole" and results["z_in_mm"] == list(STAGE_MM)
    slopes = np.array([p["slope"] for p in results["test_points"]])
    assert len(slopes) == 21 and np.abs(slopes - 1).max() < 1e-5, slopes
    assert results["overall"]["max_abs_slope_deviation"] < 1e-5
    assert abs(body["overall_mean_error_mm"]) < 1e-3 and body["overall_std_error_mm"] < 1e-3
    csv = api.get(f"/api/characterizations/{body['id']}/test_points.csv")
    assert csv.status_code == 200
    lines = b"".join(csv.streaming_content if csv.streaming else [csv.content]).decode().splitlines()
    assert len(lines) == 22 and lines[0].startswith("x_mm,y_mm,row_px,column_px,slope")
    # the dashboard's characterization page loads with the pinhole results
    browser = Client()
    browser.force_login(api.user)
    page = browser.get(f"/characterizations/{body['id']}/")
    assert page.status_code == 200
    assert "In-out characteristic per test point" in page.content.decode()


def test_pinhole_characterization_refuses_a_stage_capture_of_another_codec(api, pinhole_rig):
    rig_id = pinhole_rig["id"]
    plate, _ = capture_zip("plane", z_mm=0.0)
    ref = post_capture(api, rig_id, plate, "reference").json()["id"]
    first = upload_stage(api, rig_id, 0.0).json()["id"]
    other = {**CODEC, "axes": {"u": {**CODEC["axes"]["u"], "phase": [{**CODEC["axes"]["u"]["phase"][0]}]}}}
    other["axes"]["u"]["phase"][0]["period"] = 32.0
    other["axes"]["u"]["gray"] = {**CODEC["axes"]["u"]["gray"], "word": 32.0, "frames": list(range(8, 13))}
    other["white"], other["black"], other["frames"] = [13], [14], 15
    data, _ = capture_zip("plane", codec=other, z_mm=5.0)
    handle = io.BytesIO(data)
    handle.name = "stage.zip"
    second = api.post(
        f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": "stage", "z_in_mm": "5"}, format="multipart"
    )
    assert second.status_code == 201, second.content
    series = [{"z_in_mm": 0.0, "captures": [first]}, {"z_in_mm": 5.0, "captures": [second.json()["id"]]}]
    response = api.post("/api/characterizations/", {"rig": rig_id, "reference": ref, "series": series}, format="json")
    assert response.status_code == 400
    assert f"capture {second.json()['id']} has another codec" in response.json()["error"]
    assert Characterization.objects.count() == 0
