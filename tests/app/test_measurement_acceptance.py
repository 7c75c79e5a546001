"""VDI/VDE 2634-2 acceptance of stored measurements through the API
(``GET /api/measurements/{id}/acceptance/``), both rig models, jobs run in-process: the same numbers
as the pipeline's ``gcps acceptance`` on the same stacks, the analytic truth within stated
tolerances, 400 on bad parameters, 409 before the job is done, 404 for another user."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict, render_codec
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, cast_truth
from metrology.core.synthetic import sphere_heights
from metrology.pipeline.acceptance import AcceptanceOptions, acceptance
from tests.app.stacks import SMALL_RIG, png, render_images, stack_zip, zip_bytes
from tests.app.uploads import upload
from tests.pinhole_stacks import CODEC, PROJ_H, PROJ_W, RIG

pytestmark = pytest.mark.django_db(transaction=True)

SPHERE_RADIUS_MM = 50.0


def pinhole_frames(scene: str, **params: float) -> np.ndarray:
    """Noise-free 16-bit frames of ``CODEC`` of a scene placed 600 mm in front of the pinhole test rig."""
    prepared = RIG.prepare(RIG.shape, (PROJ_W, PROJ_H))
    truth = cast_truth(prepared, make_scene(scene, **params), ScenePlacement.facing_camera(600.0))
    return np.stack(render_codec(codec_from_dict(CODEC), truth.u, None))


def pinhole_zip(frames: np.ndarray) -> bytes:
    members = {f"frame_{i:02d}.png": png(image) for i, image in enumerate(frames)}
    members["codec.json"] = json.dumps(CODEC).encode()
    return zip_bytes(members)


def measure(api, body: dict) -> int:
    response = api.post("/api/measurements/", body, format="json")
    assert response.status_code == 202, response.content
    measurement = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert measurement["status"] == "done", measurement
    return measurement["id"]


def accept(api, measurement_id: int, **query: object) -> dict:
    response = api.get(f"/api/measurements/{measurement_id}/acceptance/", query)
    assert response.status_code == 200, response.content
    return response.json()


@pytest.fixture
def pinhole(api) -> dict:
    """A pinhole rig with a plate (reference), a tilted plane and a sphere resting on the plate, measured."""
    rig = api.post("/api/rigs/", {**RIG.to_dict(), "name": "pinhole bench"}, format="json")
    assert rig.status_code == 201, rig.content
    rig_id = rig.json()["id"]
    frames = {"plate": pinhole_frames("plane", z_mm=0.0), "sphere": pinhole_frames("sphere")}
    ids = {
        name: upload(api, rig_id, pinhole_zip(f), "object" if name == "sphere" else "reference")
        for name, f in frames.items()
    }
    return {
        "frames": frames,
        "plate_depth": measure(api, {"rig": rig_id, "object": ids["plate"]}),
        "sphere_depth": measure(api, {"rig": rig_id, "object": ids["sphere"]}),
        "sphere_height": measure(api, {"rig": rig_id, "reference": ids["plate"], "object": ids["sphere"]}),
    }


def test_pinhole_flatness_and_probing_equal_the_pipeline_and_the_truth(api, pinhole):
    # flatness of the plate (depth measurement, no reference needed): the pipeline's numbers exactly
    body = accept(api, pinhole["plate_depth"], test="flatness")
    expected = acceptance(
        RIG, None, pinhole["frames"]["plate"], AcceptanceOptions("flatness"), codec=codec_from_dict(CODEC)
    )
    for key in ("flatness_mm", "flatness_rejected_mm", "rms_mm", "n_points", "n_rejected"):
        assert body[key] == pytest.approx(expected.report[key], rel=1e-9, abs=1e-12), key
    assert body["test"] == "flatness" and body["standard"] == "VDI/VDE 2634 part 2"
    assert (
        body["model"] == "pinhole"
        and body["frame"] == "camera"
        and body["triangulate"] == expected.report["triangulate"]
    )
    assert body["measurement"] == pinhole["plate_depth"] and set(body["timings_s"]) == {"load", "fit"}
    # noise-free 16-bit renders: the plate is flat to 2 um after the 0.3 % rejection (decoder slips
    # at most a handful of pixels), its normal the optical axis
    assert body["n_points"] > 0.5 * 160 * 120
    assert body["flatness_rejected_mm"] < 2e-3
    assert abs(abs(body["normal"][2]) - 1.0) < 1e-9
    # probing: the sphere above the plate (heights) against the pipeline and the true diameter
    diameter = 2 * SPHERE_RADIUS_MM
    body = accept(api, pinhole["sphere_height"], test="probing", diameter=diameter)
    expected = acceptance(
        RIG,
        pinhole["frames"]["plate"],
        pinhole["frames"]["sphere"],
        AcceptanceOptions("probing", diameter_mm=diameter),
        codec=codec_from_dict(CODEC),
    )
    for key in ("form_error_mm", "size_error_mm", "form_error_rejected_mm", "size_error_rejected_mm", "n_points"):
        assert body[key] == pytest.approx(expected.report[key], rel=1e-9, abs=1e-12), key
    assert abs(body["size_error_rejected_mm"]) < 2e-3 and body["form_error_rejected_mm"] < 5e-3
    assert body["diameter_rejected_mm"] == pytest.approx(diameter, abs=2e-3)
    # a min_height above the equator (the sphere rests on the plate) keeps only its upper cap (the
    # mixed-pixel filter drops the grazing band next to the plate: the measured cap starts near 60 mm)
    higher = accept(api, pinhole["sphere_height"], test="probing", diameter=diameter, min_height=80)
    assert 0 < higher["n_points"] < body["n_points"] and higher["options"]["min_height_mm"] == 80.0


def test_pinhole_probing_of_a_depth_measurement_is_refused(api, pinhole):
    response = api.get(f"/api/measurements/{pinhole['sphere_depth']}/acceptance/", {"test": "probing", "diameter": 100})
    assert response.status_code == 400
    assert "without a reference capture" in response.json()["error"]


@pytest.fixture
def crossed(api, rig) -> dict:
    """A crossed-axes measurement of a plane 12 mm above the reference (exact 16-bit stacks)."""
    core = CoreRig.from_dict(SMALL_RIG)
    stacks = {"reference": render_images(core, 0.0, bit_depth=16), "object": render_images(core, 12.0, bit_depth=16)}
    ids = {role: upload(api, rig["id"], stack_zip(images), role) for role, images in stacks.items()}
    return {"stacks": stacks, "core": core, "id": measure(api, {"rig": rig["id"], **ids})}


def test_crossed_axes_flatness_equals_the_pipeline(api, crossed):
    body = accept(api, crossed["id"], test="flatness")
    expected = acceptance(
        crossed["core"], crossed["stacks"]["reference"], crossed["stacks"]["object"], AcceptanceOptions("flatness")
    )
    for key in ("flatness_mm", "flatness_rejected_mm", "rms_mm", "n_points", "n_rejected"):
        assert body[key] == pytest.approx(expected.report[key], rel=1e-9, abs=1e-12), key
    assert body["options"] == expected.options.to_dict()
    assert (body["model"], body["frame"], body["triangulate"]) == (
        expected.report["model"],
        expected.report["frame"],
        expected.report["triangulate"],
    )
    assert body["model"] == "crossed_axes" and body["frame"] == "paper"
    # exact stacks: 16-bit quantisation only (the height test of test_measurement_job allows 10 um)
    assert body["n_points"] > 0.8 * 160 * 120 and body["flatness_rejected_mm"] < 0.01
    # the spheres of probing/spacing cannot be segmented on a plane: 400 naming the test
    response = api.get(f"/api/measurements/{crossed['id']}/acceptance/", {"test": "spacing", "spacing": 50})
    assert response.status_code == 400 and response.json()["error"].startswith("spacing:")


@pytest.mark.parametrize(
    "query, words",
    [
        ({}, "test is required"),
        ({"test": "roundness"}, "test must be one of flatness, probing, spacing, got 'roundness'"),
        ({"test": "probing"}, "diameter is required"),
        ({"test": "spacing"}, "spacing is required"),
        ({"test": "probing", "diameter": "big"}, "diameter must be a number of millimetres, got 'big'"),
        ({"test": "probing", "diameter": "-3"}, "diameter must be a positive number"),
        ({"test": "spacing", "spacing": "nan"}, "spacing must be a positive number"),
        ({"test": "flatness", "min_height": "0"}, "min_height must be a positive number"),
        ({"test": "flatness", "tolerance": "1"}, "unknown query parameter 'tolerance'"),
    ],
)
def test_bad_parameters_answer_400_naming_them(api, crossed, query, words):
    response = api.get(f"/api/measurements/{crossed['id']}/acceptance/", query)
    assert response.status_code == 400
    assert words in response.json()["error"]


def test_not_done_is_409_and_others_measurements_404(api, other_api, rig, monkeypatch):
    import metrology.jobs.services as job_services

    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: None)  # the job stays queued
    core = CoreRig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, 5.0, bit_depth=16)), "object")
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    measurement_id = response.json()["id"]
    queued = api.get(f"/api/measurements/{measurement_id}/acceptance/", {"test": "flatness"})
    assert queued.status_code == 409 and "its job is queued" in queued.json()["error"]
    assert other_api.get(f"/api/measurements/{measurement_id}/acceptance/", {"test": "flatness"}).status_code == 404


def test_acceptance_is_in_the_openapi_schema(api):
    schema = api.get("/api/schema/", {"format": "json"}).json()
    operation = schema["paths"]["/api/measurements/{measurement_id}/acceptance/"]["get"]
    assert operation["operationId"] == "measurements_acceptance"
    names = {p["name"]: p for p in operation["parameters"] if p["in"] == "query"}
    assert set(names) == {"test", "diameter", "spacing", "min_height"} and names["test"]["required"]
    assert {"200", "400", "404", "409"} <= set(operation["responses"])


def test_crossed_axes_spacing_and_probing_of_two_spheres(api, rig):
    """Two spheres of radius 40 mm, centres 200 mm apart, resting on R (exact 16-bit stacks)."""
    core = CoreRig.from_dict(SMALL_RIG)
    za = sphere_heights(core, (250.0, 0.0, 40.0), 40.0)
    zb = sphere_heights(core, (450.0, 0.0, 40.0), 40.0)
    stacks = {
        "reference": render_images(core, 0.0, bit_depth=16),
        "object": render_images(core, np.where(za > 0, za, zb), bit_depth=16),
    }
    ids = {role: upload(api, rig["id"], stack_zip(images), role) for role, images in stacks.items()}
    measurement_id = measure(api, {"rig": rig["id"], **ids})
    body = accept(api, measurement_id, test="spacing", spacing=200, min_height=5)
    options = AcceptanceOptions("spacing", spacing_mm=200.0, min_height_mm=5.0)
    expected = acceptance(core, stacks["reference"], stacks["object"], options)
    for key in ("spacing_error_mm", "spacing_error_rejected_mm"):
        assert body[key] == pytest.approx(expected.report[key], rel=1e-9, abs=1e-12), key
    # exact 16-bit stacks (~3 mm pixels): the centres 200 mm apart within 10 um (measured: 0.2 um)
    assert abs(body["spacing_error_rejected_mm"]) < 0.01
    probing = accept(api, measurement_id, test="probing", diameter=80, min_height=5)
    expected = acceptance(
        core, stacks["reference"], stacks["object"], AcceptanceOptions("probing", diameter_mm=80.0, min_height_mm=5.0)
    )
    assert probing["size_error_rejected_mm"] == pytest.approx(expected.report["size_error_rejected_mm"], abs=1e-12)
    assert abs(probing["size_error_rejected_mm"]) < 0.01  # measured: 0.3 um
