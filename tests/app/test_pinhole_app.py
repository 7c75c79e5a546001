"""Pinhole rigs through the REST API: rig import, uploads of any codec, measurement jobs (depth without
a reference, heights with one, points and sigma stored), downloads, and what stays crossed-axes only."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.rigs.models import Rig
from tests.app.uploads import post_capture
from tests.pinhole_stacks import CODEC, RIG, capture_zip

pytestmark = pytest.mark.django_db(transaction=True)


def fetch(api, url: str) -> np.ndarray:
    return np.load(io.BytesIO(b"".join(api.get(url).streaming_content)))


def test_pinhole_rig_is_imported_and_checked(api, pinhole_rig):
    assert pinhole_rig["model"] == "pinhole" and pinhole_rig["width_px"] == 160 and pinhole_rig["height_px"] == 120
    assert pinhole_rig["pinhole"] == RIG.to_dict() and pinhole_rig["L_mm"] is None
    assert Rig.objects.get(pk=pinhole_rig["id"]).to_core() == RIG
    bad = RIG.to_dict()
    bad["R"] = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]
    refused = api.post("/api/rigs/", bad, format="json")
    assert refused.status_code == 400 and "R" in refused.json()["error"]
    unknown = api.post("/api/rigs/", {**RIG.to_dict(), "colour": 1}, format="json")
    assert unknown.status_code == 400 and "colour" in unknown.json()["error"]
    assert Rig.objects.count() == 1


@pytest.mark.slow
def test_pinhole_measurements_depth_heights_points_sigma(api, pinhole_rig):
    rig_id = pinhole_rig["id"]
    sphere, truth = capture_zip("sphere")
    plate, _ = capture_zip("plane", z_mm=0.0)
    obj = post_capture(api, rig_id, sphere, "object")
    assert obj.status_code == 201, obj.content
    ref = post_capture(api, rig_id, plate, "reference")
    assert ref.status_code == 201, ref.content
    # depth: no reference
    response = api.post("/api/measurements/", {"rig": rig_id, "object": obj.json()["id"]}, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    assert body["statistics"]["z"] == "depth (camera Z)" and body["rig_values"]["model"] == "pinhole"
    assert {"height.npy", "points.npy", "mesh.ply", "height.tiff"} <= set(body["files"])
    points = fetch(api, body["files"]["points.npy"])
    z = fetch(api, body["files"]["height.npy"])
    ok = np.isfinite(z)
    assert ok.mean() > 0.5 and np.array_equal(z[ok], points[..., 2][ok])
    # noise-free 16-bit: within 1 um of the truth (but rare decoder slips)
    assert np.mean(np.linalg.norm(points[ok] - truth[ok], axis=-1) < 1e-3) > 0.999
    mesh = b"".join(api.get(body["files"]["mesh.ply"]).streaming_content)
    assert mesh.startswith(b"ply") and b"element vertex" in mesh
    # heights above the reference plate, with sigma
    request = {"rig": rig_id, "reference": ref.json()["id"], "object": obj.json()["id"], "options": {"sigma": True}}
    response = api.post("/api/measurements/", request, format="json")
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    assert body["statistics"]["z"] == "height above the reference plane"
    h = fetch(api, body["files"]["height.npy"])
    assert np.mean(np.abs(h[ok] - (600.0 - truth[..., 2][ok])) < 1e-3) > 0.999
    sigma = fetch(api, body["files"]["sigma.npy"])
    assert np.array_equal(np.isfinite(sigma), np.isfinite(h)) and body["statistics"]["sigma_mm_median"] >= 0
    bad = api.post("/api/measurements/", {**request, "options": {"triangulate": "w"}}, format="json")
    assert bad.status_code == 400 and "triangulate must be one of" in bad.json()["error"]


@pytest.mark.slow
def test_pinhole_uploads_must_match_the_rigs_projector_and_crossed_only_jobs_are_refused(api, pinhole_rig):
    rig_id = pinhole_rig["id"]
    other = {**CODEC, "projector": {"width": 1024, "height": 768}}
    data, _ = capture_zip("sphere", codec=other)
    refused = post_capture(api, rig_id, data, "object")
    assert refused.status_code == 400
    assert "the codec's projector is 1024x768 but the rig's projector is 640x400" in refused.json()["error"]
    # the paper's calibration adjusts L and alpha: refused on a pinhole rig, naming it
    plate, _ = capture_zip("plane", z_mm=0.0)
    reference = post_capture(api, rig_id, plate, "reference").json()["id"]
    master = post_capture(api, rig_id, capture_zip("sphere")[0], "master").json()["id"]
    calibration = api.post(
        "/api/calibrations/",
        {"rig": rig_id, "reference": reference, "master": master, "master_height_mm": 40.0},
        format="json",
    )
    assert calibration.status_code == 400, calibration.content
    message = calibration.json()["error"]
    assert message.startswith(f"rig {rig_id} is a pinhole rig: "), message
    assert "the paper's calibration adjusts L and alpha (calibrate it from board poses)" in message
    # the virtual rig renders every model: simulating a capture of a pinhole rig (in the rig's default
    # codec, for its projector) is accepted
    assert api.put(f"/api/rigs/{rig_id}/codec/", {"codec": CODEC}, format="json").status_code == 200
    simulate = api.post(
        f"/api/rigs/{rig_id}/captures/simulate/", {"role": "reference", "scene": {"name": "reference"}}, format="json"
    )
    assert simulate.status_code == 202, simulate.content
    job = Job.objects.get(pk=simulate.json()["job"])
    assert job.status == "done", job.error
    assert Measurement.objects.count() == 0
