"""Measurements in the embedded mode (tasks run in-process): request, result files, statistics, bad input."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import Rig
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload
from tests.conftest import stored_files

# Jobs are enqueued on commit: these tests need real commits.
pytestmark = pytest.mark.django_db(transaction=True)


@pytest.fixture
def no_workers(monkeypatch):
    """Jobs stay queued: nothing picks them up."""
    import metrology.jobs.services as job_services

    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: None)


def test_measurement_runs_and_serves_heights_and_meshes(api, rig, captures, media_root):
    reference, obj = captures
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    assert response.status_code == 202, response.content
    measurement_id = response.json()["id"]
    body = api.get(f"/api/measurements/{measurement_id}/").json()
    assert body["status"] == "done", body
    assert body["progress"] == 100 and body["error"] == ""
    assert body["statistics"]["valid_fraction"] > 0.5
    assert body["software_version"].startswith("gcps-lab")
    assert "measure" in body["timings"] and "store" in body["timings"]
    assert set(body["files"]) == {
        "height.npy",
        "height.tiff",
        "gray_only_height.npy",
        "points.npy",
        "mesh.ply",
        "mesh.stl",
        "mesh.obj",
        "points.e57",
    }

    download = api.get(f"/api/measurements/{measurement_id}/height.npy")
    assert download.status_code == 200
    z = np.load(io.BytesIO(b"".join(download.streaming_content)))
    assert z.shape == (120, 160) and z.dtype == np.float32
    truth = block_heights()
    # away from the block's edges the exact model gives the height to well under a micrometre
    inner = np.zeros_like(truth, dtype=bool)
    inner[35:85, 45:115] = True
    inner[:20, :] = True
    ok = inner & np.isfinite(z)
    assert ok.sum() > 0.8 * inner.sum()
    assert np.abs(z[ok] - truth[ok]).max() < 0.01  # 16-bit quantisation

    # only the referenced files are stored: two stacks and the two height maps (the points follow from
    # the heights on the paper's rig; meshes, TIFF and points on request)
    assert len(stored_files(media_root)) == 4
    for name, magic in (("mesh.ply", b"ply"), ("mesh.obj", b"# GCPS"), ("mesh.stl", b"GCPS"), ("height.tiff", b"II")):
        response = api.get(f"/api/measurements/{measurement_id}/{name}")
        assert response.status_code == 200
        assert b"".join(response.streaming_content).startswith(magic)
    # the derived files went to the cache folder only
    assert len([p for p in stored_files(media_root) if p.parent.name == "derived"]) == 4
    assert len(stored_files(media_root)) == 8


def test_results_are_not_served_before_done(api, rig, captures, no_workers):
    reference, obj = captures
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    measurement_id = response.json()["id"]
    assert response.json()["status"] == "queued"
    missing = api.get(f"/api/measurements/{measurement_id}/height.npy")
    assert missing.status_code == 404
    assert "its job is queued" in missing.json()["error"]


def test_a_core_error_fails_the_job_with_the_reason(api, rig, captures, monkeypatch):
    import metrology.core.measure as measure

    def broken(*_args, **_kwargs):
        raise ValueError("object stack has no valid pixel")

    monkeypatch.setattr(measure, "measure", broken)
    reference, obj = captures
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "failed"
    assert body["error"] == "object stack has no valid pixel"
    assert body["files"] == {}


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({"reference": "OBJ", "object": "OBJ"}, "must differ"),
        ({"reference": "OBJ", "object": "REF"}, "has role 'object'; expected reference"),
        ({"reference": 999, "object": "OBJ"}, "capture 999 does not exist among yours"),
        ({"reference": "REF"}, "object: This field is required."),
        ({"reference": "REF", "object": "OTHER_RIG"}, "belongs to rig"),
        ({"rig": 999, "reference": "REF", "object": "OBJ"}, "rig 999 does not exist among yours"),
        ({"reference": "REF", "object": "x"}, "object: A valid integer is required."),
    ],
)
def test_bad_measurement_requests_answer_400_and_store_nothing(api, rig, captures, media_root, body, words):
    reference, obj = captures
    other_rig = api.post("/api/rigs/", SMALL_RIG, format="json").json()
    other_capture = upload(api, other_rig["id"], stack_zip(render_images(Rig.from_dict(SMALL_RIG), 0.0)), "object")
    names = {"REF": reference, "OBJ": obj, "OTHER_RIG": other_capture}
    request = {"rig": rig["id"], **{key: names.get(value, value) for key, value in body.items()}}
    files_before = stored_files(media_root)
    response = api.post("/api/measurements/", request, format="json")
    assert response.status_code == 400, response.content
    assert words in response.json()["error"]
    assert Measurement.objects.count() == 0 and Job.objects.count() == 0
    assert stored_files(media_root) == files_before


def test_capture_still_being_simulated_is_refused(api, rig, captures, no_workers):
    reference, _obj = captures
    pending = api.post(
        f"/api/rigs/{rig['id']}/captures/simulate/",
        {"role": "object", "scene": {"name": "plane", "z_mm": 10.0}},
        format="json",
    ).json()
    response = api.post(
        "/api/measurements/", {"rig": rig["id"], "reference": reference, "object": pending["id"]}, format="json"
    )
    assert response.status_code == 400
    assert f"capture {pending['id']} is not stored yet (its job {pending['job']} is queued)" in response.json()["error"]
