"""Calibration and characterization jobs in the embedded mode, with results as JSON and CSV."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from metrology.calibrations.models import Calibration
from metrology.characterizations.models import Characterization
from metrology.core.geometry.crossed_axes import Rig
from metrology.jobs.models import Job
from tests.app.stacks import SMALL_RIG
from tests.app.uploads import upload_heights

pytestmark = pytest.mark.django_db(transaction=True)
CORE_RIG = Rig.from_dict(SMALL_RIG)


def master_heights(height_mm: float = 40.0) -> np.ndarray:
    z = np.zeros(CORE_RIG.shape)
    z[25:95, 30:130] = height_mm
    return z


def test_calibration_from_the_papers_rough_start_is_applied_to_the_rig(api, rig):
    reference = upload_heights(api, rig["id"], 0.0, "reference")["id"]
    master = upload_heights(api, rig["id"], master_heights(), "master")["id"]
    response = api.post(
        "/api/calibrations/",
        {
            "rig": rig["id"],
            "reference": reference,
            "master": master,
            "master_height_mm": 40.0,
            "method": "lsq",
            "initial": {"L_mm": 1080.0, "alpha_rad": 0.4871},
            "apply": True,
        },
        format="json",
    )
    assert response.status_code == 202, response.content
    body = api.get(f"/api/calibrations/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    assert body["result"]["L_mm"] == pytest.approx(1022.0, abs=0.5)
    assert body["result"]["alpha_rad"] == pytest.approx(0.332, abs=1e-3)
    assert len(body["iterations"]) >= 1 and body["applied"]
    rig_now = api.get(f"/api/rigs/{rig['id']}/").json()
    assert rig_now["L_mm"] == pytest.approx(body["result"]["L_mm"])
    assert [entry["source"] for entry in rig_now["history"]] == ["created", "calibration"]
    assert rig_now["history"][-1]["calibration"] == body["id"]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"method": "guess"}, "method"),
        ({"master_height_mm": -1}, "master_height_mm must be a positive number"),
        ({"initial": {"L_mm": -3}}, "L_mm must be a positive finite number"),
        ({"initial": {"fw_mm": 3}}, "initial: unknown key(s) fw_mm"),
        ({"options": {"bogus": 1}}, "method 'lsq' has no option bogus"),
        ({"options": {"max_iterations": 0}}, "options.max_iterations must be an integer"),
        ({"master": "REF"}, "must differ"),
    ],
)
def test_bad_calibration_requests_answer_400(api, rig, change, words):
    reference = upload_heights(api, rig["id"], 0.0, "reference")["id"]
    master = upload_heights(api, rig["id"], master_heights(), "master")["id"]
    body = {"rig": rig["id"], "reference": reference, "master": master, "master_height_mm": 40.0, **change}
    if body["master"] == "REF":
        body["master"] = reference
    response = api.post("/api/calibrations/", body, format="json")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]
    assert Calibration.objects.count() == 0 and Job.objects.count() == 0


def test_characterization_of_a_stage_series_with_csv_tables(api, rig):
    reference = upload_heights(api, rig["id"], 0.0, "reference")["id"]
    session = api.post(f"/api/rigs/{rig['id']}/sessions/", {"name": "stage"}, format="json").json()["id"]
    for z in (0.0, 4.0, 8.0):
        for repeat in range(2):
            upload_heights(api, rig["id"], z, "stage", z_in_mm=z, repeat=repeat, session=session)
    response = api.post(
        "/api/characterizations/",
        {"rig": rig["id"], "reference": reference, "session": session, "options": {"n_points": 5}},
        format="json",
    )
    assert response.status_code == 202, response.content
    characterization_id = response.json()["id"]
    body = api.get(f"/api/characterizations/{characterization_id}/").json()
    assert body["status"] == "done", body
    assert body["results"]["z_in_mm"] == [0.0, 4.0, 8.0]
    assert len(body["results"]["test_points"]) == 5
    assert abs(body["overall_mean_error_mm"]) < 0.01
    positions = api.get(f"/api/characterizations/{characterization_id}/positions.csv")
    assert positions.status_code == 200 and positions["Content-Type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(positions.content.decode())))
    assert [float(row["z_in_mm"]) for row in rows] == [0.0, 4.0, 8.0]
    points = api.get(f"/api/characterizations/{characterization_id}/test_points.csv").content.decode()
    rows = list(csv.DictReader(io.StringIO(points)))
    assert len(rows) == 5 and abs(float(rows[0]["slope"]) - 1) < 1e-3


def test_bad_characterization_requests_answer_400(api, rig):
    reference = upload_heights(api, rig["id"], 0.0, "reference")["id"]
    stage = upload_heights(api, rig["id"], 4.0, "stage", z_in_mm=4.0)["id"]
    cases = [
        ({}, "give either series"),
        ({"series": [{"z_in_mm": 4.0, "captures": [stage]}]}, "two or more distinct z_in_mm"),
        ({"series": [{"z_in_mm": 4.0, "captures": [reference]}, {"z_in_mm": 8, "captures": [stage]}]}, "role"),
        ({"series": [{"z_in_mm": 4.0, "captures": [stage]}, {"z_in_mm": 8, "captures": [stage]}]}, "listed twice"),
        ({"series": [{"z_in_mm": 4.0, "captures": []}, {"z_in_mm": 8, "captures": [stage]}]}, "lists no capture"),
        ({"session": 999}, "session 999 does not exist"),
        ({"series": [], "options": {"patch_px": 4}}, "patch_px must be an odd"),
    ]
    for change, words in cases:
        response = api.post(
            "/api/characterizations/", {"rig": rig["id"], "reference": reference, **change}, format="json"
        )
        assert response.status_code == 400, (change, response.content)
        assert words in response.json()["error"], (change, response.json())
    assert Characterization.objects.count() == 0 and Job.objects.count() == 0


def test_simulated_capture_in_process(api, rig):
    response = api.post(
        f"/api/rigs/{rig['id']}/captures/simulate/",
        {
            "role": "object",
            "scene": {"name": "sphere", "radius_mm": 60.0},
            "options": {"bit_depth": 8, "noise_grey": 1.5},
        },
        format="json",
    )
    assert response.status_code == 202, response.content
    body = api.get(f"/api/captures/{response.json()['id']}/").json()
    assert body["status"] == "stored" and body["source"] == "virtual" and body["bit_depth"] == 8
    job = api.get(f"/api/jobs/{body['job']}/").json()
    assert job["status"] == "done" and job["parameters"]["scene"]["name"] == "sphere"


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({"scene": {"name": "teapot"}}, "unknown scene 'teapot'"),
        ({"scene": {"name": "sphere", "colour": 3}}, "has no parameter 'colour'"),
        ({"scene": {}}, "scene.name is required"),
        ({"scene": {"name": "plane"}, "options": {"bit_depth": 12}}, "bit_depth"),
        ({"scene": {"name": "plane"}, "options": {"flux": 1}}, "flux"),
        ({"scene": {"name": "plane"}, "role": "stage"}, "z_in_mm is required"),
    ],
)
def test_bad_simulation_requests_answer_400(api, rig, body, words):
    response = api.post(f"/api/rigs/{rig['id']}/captures/simulate/", {"role": "object", **body}, format="json")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]
    assert Job.objects.count() == 0
