"""Inspections through the application (tasks in-process): nominal models uploaded and validated, an
inspection job on a measurement of the virtual rig with a planted pit, the report and the deviation
map through the API, the feature table, the exports (the measurement's points as E57, the
inspection's deviations as PLY), the pages, and a rig's inspection plan applied to its next
measurement with a trend per feature.

The scene is SMALL_RIG's block (25 mm high on the reference plane, rows 30-89, columns 40-119) with
a square pit 0.1 mm deep in its top (rows 55-64, columns 75-84); the nominal model is the block
without the pit: the top face at Z = 25 mm over the block's pixels, the ground plane at Z = 0 and
four walls (an open mesh: the ground is one face under the block). Measured and nominal agree to
the 16-bit rendering's quantisation away from the block's edges, so the pit's deviation is -0.1 mm
(inside the material) within 10 um and the rest of the top within a few micrometres.
"""

from __future__ import annotations

import hashlib
import io
import sys

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io.step import LINEAR_TOLERANCE_MM, ocp_installed
from metrology.inspections.models import Inspection
from tests.app.inspection_parts import (
    PIT_DEPTH_MM,
    SMALL_RIG,
    TOP_FEATURE,
    block_nominal,
    block_step,
    pitted_block_heights,
    stl_bytes,
)
from tests.app.stacks import render_images, stack_zip
from tests.app.uploads import upload

pytestmark = pytest.mark.django_db(transaction=True)


@pytest.fixture
def pitted_measurement(api, rig) -> int:
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, pitted_block_heights(), bit_depth=16)), "object")
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    return body["id"]


@pytest.fixture
def nominal(api) -> dict:
    vertices, faces = block_nominal()
    data = io.BytesIO(stl_bytes(vertices, faces))
    data.name = "block.stl"
    response = api.post("/api/nominals/", {"file": data, "name": "block"}, format="multipart")
    assert response.status_code == 201, response.content
    return response.json()


def test_nominal_upload_is_validated_and_described(api, nominal):
    assert nominal["triangle_count"] == 12 and nominal["units"] == "mm" and nominal["file_format"] == "stl"
    assert len(nominal["sha256"]) == 64 and nominal["size_bytes"] == 84 + 50 * 12
    assert any("open" in warning for warning in nominal["summary"]["warnings"])  # the ground is one face
    listed = api.get("/api/nominals/").json()
    assert [n["id"] for n in listed] == [nominal["id"]]
    download = api.get(f"/api/nominals/{nominal['id']}/file/")
    assert download.status_code == 200

    for name, content, expected in (
        ("part.igs", b"IGES", "must be .stl, .ply, .obj, .step or .stp"),
        ("bad.step", b"ISO-10303-21;\nnot really\n", "bad.step"),  # unreadable, or no cadquery-ocp: a 400 either way
        ("empty.stl", b"", "empty"),
        ("garbage.ply", b"not a ply file at all", "garbage.ply"),
    ):
        data = io.BytesIO(content)
        data.name = name
        response = api.post("/api/nominals/", {"file": data}, format="multipart")
        assert response.status_code == 400, (name, response.content)
        assert expected in response.json()["error"], response.json()
    assert len(api.get("/api/nominals/").json()) == 1  # nothing stored from the refused uploads


@pytest.mark.skipif(not ocp_installed(), reason="STEP needs the optional cadquery-ocp (pip install 'gcps-lab[step]')")
def test_step_nominal_is_tessellated_stored_and_inspected(api, pitted_measurement, tmp_path):
    """The block as a STEP file of six planar faces: stored with the STEP file's hash and size, the
    tessellation's tolerance and triangle count, then read by the inspection job as a mesh is: the
    pit found as against the STL nominal (-0.1 mm within 10 um, the rest of the top within 5 um)."""
    step = block_step(tmp_path / "block.step").read_bytes()
    data = io.BytesIO(step)
    data.name = "block.step"
    response = api.post("/api/nominals/", {"file": data}, format="multipart")
    assert response.status_code == 201, response.content
    nominal = response.json()
    assert nominal["file_format"] == "step" and nominal["name"] == "block" and nominal["units"] == "mm"
    assert nominal["sha256"] == hashlib.sha256(step).hexdigest() and nominal["size_bytes"] == len(step)
    assert nominal["triangle_count"] == 12, nominal  # two per planar face, as block_nominal's
    tessellation = nominal["tessellation"]
    assert tessellation["linear_tolerance_mm"] == LINEAR_TOLERANCE_MM and tessellation["faces"] == 6, tessellation
    assert nominal["summary"]["tessellation"] == tessellation
    download = api.get(f"/api/nominals/{nominal['id']}/file/")
    assert download.status_code == 200 and b"".join(download.streaming_content) == step  # the STEP file itself
    from django.core.files.storage import default_storage

    from metrology.inspections.models import NominalModel

    stored = NominalModel.objects.get(pk=nominal["id"])
    assert stored.mesh[1] == "ply" and stored.mesh_file.name.endswith("block.tessellated.ply")
    spare = io.BytesIO(step)
    spare.name = "spare.stp"
    spare_id = api.post("/api/nominals/", {"file": spare}, format="multipart").json()["id"]
    files = [NominalModel.objects.get(pk=spare_id).file.name, NominalModel.objects.get(pk=spare_id).mesh_file.name]
    assert all(default_storage.exists(name) for name in files)
    assert api.delete(f"/api/nominals/{spare_id}/").status_code == 204
    assert not any(default_storage.exists(name) for name in files)  # the STEP file and its tessellation

    options = {"init": "identity", "tolerance_mm": 0.05, "systematic_mm": 0.0}
    request = {"measurement": pitted_measurement, "nominal": nominal["id"], "options": options}
    response = api.post("/api/inspections/", request, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/inspections/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    provenance = body["report"]["provenance"]["nominal"]
    assert provenance["sha256"] == nominal["sha256"] and provenance["format"] == "step"
    assert provenance["tessellation"] == tessellation
    dev = np.load(io.BytesIO(b"".join(api.get(body["files"]["deviations.npy"]).streaming_content)))
    assert abs(float(np.median(dev[57:63, 77:83])) + PIT_DEPTH_MM) < 0.010, np.median(dev[57:63, 77:83])
    top = np.zeros(dev.shape, bool)
    top[35:85, 45:115] = True
    top[52:68, 72:88] = False
    assert np.isfinite(dev[top]).mean() > 0.95 and np.nanpercentile(np.abs(dev[top]), 99) < 0.005

    from django.test import Client

    client = Client()
    client.force_login(api.user)
    page = client.get("/nominals/").content.decode()
    assert f"<td data-tessellation>{LINEAR_TOLERANCE_MM} mm, 0.1 rad</td>" in page and ">STEP<" in page
    report = client.get(f"/inspections/{body['id']}/report/").content.decode()
    assert f"(STEP, 12 triangles tessellated at {LINEAR_TOLERANCE_MM} mm, 0.1 rad, mm)" in report


def test_step_upload_without_the_extra_is_refused(api, monkeypatch):
    """A server without cadquery-ocp answers a STEP upload with a 400 naming the extra (the import of
    OpenCASCADE fails as where it is not installed); the service's availability check can be given."""
    from django.core.files.uploadedfile import SimpleUploadedFile

    from metrology.errors import BadInput
    from metrology.inspections.services import upload_nominal

    content = b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n"
    with monkeypatch.context() as patched:
        for module in [name for name in sys.modules if name == "OCP" or name.startswith("OCP.")] + ["OCP"]:
            patched.setitem(sys.modules, module, None)  # import OCP raises ImportError
        for name in ("part.step", "PART.STP"):
            data = io.BytesIO(content)
            data.name = name
            response = api.post("/api/nominals/", {"file": data}, format="multipart")
            assert response.status_code == 400, response.content
            error = response.json()["error"]
            assert name in error and "pip install 'gcps-lab[step]' (cadquery-ocp)" in error, error
    with pytest.raises(BadInput, match=r"cannot read STEP files.*gcps-lab\[step\]"):
        upload_nominal(
            owner=api.user, upload=SimpleUploadedFile("part.step", content), step_reader_available=lambda: False
        )
    assert api.get("/api/nominals/").json() == []  # nothing stored


def test_inspection_finds_the_pit_and_decides_conformance(api, pitted_measurement, nominal, tmp_path, monkeypatch):
    options = {"init": "identity", "tolerance_mm": 0.05, "k": 2, "systematic_mm": 0.0, "features": [TOP_FEATURE]}
    response = api.post(
        "/api/inspections/",
        {"measurement": pitted_measurement, "nominal": nominal["id"], "options": options},
        format="json",
    )
    assert response.status_code == 202, response.content
    body = api.get(f"/api/inspections/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    report = body["report"]
    assert report["format"] == "gcps-inspection/1"
    transform = np.array(report["transform"])
    assert transform.shape == (4, 4) and np.allclose(transform[3], [0, 0, 0, 1])
    # already aligned: the best fit moves the block by well under a micrometre
    assert np.abs(transform[:3, 3]).max() < 1e-3 and np.abs(transform[:3, :3] - np.eye(3)).max() < 1e-5
    assert report["provenance"]["nominal"]["sha256"] == nominal["sha256"]
    assert report["tolerance_mm"] == 0.05 and report["k"] == 2

    download = api.get(body["files"]["deviations.npy"])
    assert download.status_code == 200
    dev = np.load(io.BytesIO(b"".join(download.streaming_content)))
    assert dev.shape == (SMALL_RIG["height_px"], SMALL_RIG["width_px"]) and dev.dtype == np.float32
    pit = dev[57:63, 77:83]  # the pit's interior
    assert abs(float(np.median(pit)) + PIT_DEPTH_MM) < 0.010, np.median(pit)
    top = np.zeros(dev.shape, bool)
    top[35:85, 45:115] = True
    top[52:68, 72:88] = False  # the pit and its edges
    assert np.isfinite(dev[top]).mean() > 0.95
    assert np.nanpercentile(np.abs(dev[top]), 99) < 0.005  # 16-bit quantisation of the render
    counts = report["conformance"]
    assert sum(counts.values()) == report["deviation"]["points"] == int(np.isfinite(dev).sum())
    assert counts["nonconforming"] >= pit.size, report  # every pit point is out of tolerance
    assert counts["conforming"] > 0.9 * counts["nonconforming"] + top.sum() * 0.9

    # the top's plane: the pit is its flatness (minimum zone), its offset from the nominal ~0
    (feature,) = report["features"]
    assert feature["name"] == "top" and feature["error"] is None and feature["points"] > 0.9 * top.sum()
    assert feature["form"]["name"] == "flatness" and abs(feature["form_mm"] - PIT_DEPTH_MM) < 0.010, feature["form"]
    assert abs(feature["difference"]["offset_mm"]) < 0.005 and feature["difference"]["tilt_deg"] < 0.01
    assert feature["nominal"]["form_mm"] < 1e-6  # the nominal's top is two coplanar triangles

    # exports: the inspection's deviations as PLY (nominal frame), the measurement's points as E57
    from metrology.core.io.e57 import read_e57
    from metrology.core.io.points import read_ply
    from metrology.inspections.models import Inspection as InspectionRow
    from metrology.measurements.derived import measurement_points

    row = InspectionRow.objects.select_related("measurement").get(pk=body["id"])
    points = measurement_points(row.measurement).astype(np.float64)
    ply = api.get(body["files"]["deviations.ply"])
    assert ply.status_code == 200
    cloud = read_ply(b"".join(ply.streaming_content))
    has = np.isfinite(dev)
    np.testing.assert_array_equal(cloud.vertex["deviation_mm"], dev[has])  # float32 both
    np.testing.assert_allclose(cloud.points, points[has] @ transform[:3, :3].T + transform[:3, 3], atol=1e-9)
    assert ("sigma_mm" in cloud.vertex) == bool(row.measurement.sigma_npy)

    e57_url = f"/api/measurements/{pitted_measurement}/points.e57"
    with monkeypatch.context() as patched:  # a server without the optional pye57: a clear 409
        patched.setitem(__import__("sys").modules, "pye57", None)
        refused = api.get(e57_url)
    assert refused.status_code == 409 and "pye57 is not installed" in refused.json()["error"], refused.content
    e57 = api.get(e57_url)
    assert e57.status_code == 200, e57
    (tmp_path / "points.e57").write_bytes(b"".join(e57.streaming_content))
    (scan,) = read_e57(tmp_path / "points.e57")
    valid = np.isfinite(points).all(axis=-1)
    assert scan.points_mm.shape == (int(valid.sum()), 3) and scan.intensity is None
    assert scan.row is not None and scan.column is not None and valid[scan.row, scan.column].all()
    # float32 metres about the centroid, the centroid in the pose: the model frame's points to 0.1 um
    np.testing.assert_allclose(scan.points_mm, points[scan.row, scan.column], atol=1e-4)
    np.testing.assert_allclose(scan.rotation, np.eye(3), atol=1e-12)

    # the pages: the inspection with its figures, the printable report, the lists
    from django.test import Client

    client = Client()
    client.force_login(Inspection.objects.get(pk=body["id"]).owner)
    page = client.get(f"/inspections/{body['id']}/")
    assert page.status_code == 200
    html = page.content.decode()
    assert 'id="fig-deviation_map"' in html and 'id="fig-deviation_histogram"' in html
    assert f"data-nonconforming>{counts['nonconforming']}<" in html
    assert 'data-feature="top"' in html and 'data-difference="top offset"' in html
    assert f'href="/api/inspections/{body["id"]}/deviations.ply"' in html
    assert client.get(f"/inspections/{body['id']}/report/").status_code == 200
    assert client.get("/inspections/").status_code == 200 and client.get("/nominals/").status_code == 200
    assert b"Inspect against a nominal model" in client.get(f"/measurements/{pitted_measurement}/").content


def test_plan_inspects_each_new_measurement(api, rig, nominal):
    plan = api.put(
        f"/api/rigs/{rig['id']}/inspection-plan/",
        {"nominal": nominal["id"], "options": {"init": "identity", "tolerance_mm": 0.05, "features": [TOP_FEATURE]}},
        format="json",
    )
    assert plan.status_code == 200, plan.content
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, pitted_block_heights(), bit_depth=16)), "object")
    request = {"rig": rig["id"], "reference": reference, "object": obj}
    measurement = api.post("/api/measurements/", request, format="json")
    inspections = [i for i in api.get("/api/inspections/").json() if i["measurement"] == measurement.json()["id"]]
    assert len(inspections) == 1 and inspections[0]["plan"] == plan.json()["id"], inspections
    assert inspections[0]["status"] == "done", inspections[0]
    # without systematic_mm in the plan, the rig's (none: no characterization) is recorded
    assert inspections[0]["report"]["provenance"]["systematic"] == {"mm": 0.0, "from": "none"}

    from django.test import Client

    client = Client()
    client.force_login(Inspection.objects.get(pk=inspections[0]["id"]).owner)
    page = client.get(f"/rigs/{rig['id']}/inspection-plan/")
    assert page.status_code == 200 and b'id="fig-plan_trend"' in page.content
    assert b'id="fig-feature_trend_0"' in page.content and b"Feature top" in page.content
    assert inspections[0]["report"]["features"][0]["name"] == "top"
    assert b"&quot;near_faces&quot;: [2, 3]" in page.content  # the plan's features in the form, as JSON


def test_inspection_requests_are_checked(api, other_api, pitted_measurement, nominal):
    bad = api.post(
        "/api/inspections/",
        {"measurement": pitted_measurement, "nominal": nominal["id"], "options": {"init": "sideways"}},
        format="json",
    )
    assert bad.status_code == 400 and "init" in bad.json()["error"]
    foreign = other_api.post(
        "/api/inspections/", {"measurement": pitted_measurement, "nominal": nominal["id"]}, format="json"
    )
    assert foreign.status_code == 400 and "does not exist among yours" in foreign.json()["error"]
    assert api.delete(f"/api/nominals/{nominal['id']}/").status_code == 204  # unused: deleted
