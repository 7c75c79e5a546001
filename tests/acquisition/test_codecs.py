"""Acquisitions of any codec through the protocol (Django's test client, real database, no mocks).

The agent's own pieces do the agent's part: the acquisition the server hands out is resolved by
:func:`resolve_codec`, grabbed frame by frame by :func:`run_sequence` from the virtual camera (which
renders the codec's frames at the true projector coordinates of the virtual rig), zipped by
:func:`stack_zip` and uploaded. The stored capture must carry its codec and decode, with the codec
decoder, to the true projector coordinates.
"""

from __future__ import annotations

import io
import json
import zipfile

import cv2
import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from metrology.acquisition.agent.cameras import AcquisitionTarget, make_camera
from metrology.acquisition.agent.client import stack_zip
from metrology.acquisition.agent.patterns import resolve_codec
from metrology.acquisition.agent.sequencer import InstantProjector, SequenceOptions, run_sequence
from metrology.acquisition.models import Acquisition
from metrology.captures.models import Capture
from metrology.captures.stacks import load_codec_stack
from metrology.core.codecs import codec_from_dict, codec_patterns
from metrology.core.codecs.decode import decode_codec
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.core.scenes import make_scene
from metrology.core.simulate import crossed_rig_truth, render_stack
from metrology.jobs.models import Job
from tests.acquisition.helpers import PROJ_H, PROJ_W, phase_gray_codec
from tests.app.stacks import SMALL_RIG, plane_zip

SIM_OPTIONS = {"bit_depth": 8, "noise_grey": 1.0}


@pytest.fixture
def api(alice_token) -> Client:
    return Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")


def post(client: Client, url: str, data: dict):
    return client.post(url, json.dumps(data), content_type="application/json")


def register(api: Client, rig) -> str:
    response = post(api, f"/api/rigs/{rig.pk}/agent/register/", {"camera": "virtual", "name": "bench-pc"})
    assert response.status_code == 201, response.content
    return response.json()["session"]


def agent_grabs(taken: dict) -> tuple[np.ndarray, bytes]:
    """What ``gcps agent`` does with a taken acquisition, minus HTTP: the frames and the zip it uploads."""
    codec = resolve_codec(taken["codec"])
    camera = make_camera("virtual", scene={"name": "sphere"}, options=SIM_OPTIONS)
    camera.prepare(
        AcquisitionTarget(role=taken["role"], codec=codec, rig_geometry=taken["rig_geometry"]),
    )
    result = run_sequence(
        InstantProjector(), camera, codec, exposure_ms=10.0, options=SequenceOptions(settle_s=0.0, max_grabs=3)
    )
    return result.images, stack_zip(result.images, codec)


def true_uv() -> tuple[np.ndarray, np.ndarray]:
    rig = CoreRig.from_dict(SMALL_RIG)
    return crossed_rig_truth(render_stack(rig, make_scene("sphere", rig=rig)), rig, PROJ_W, PROJ_H)


@pytest.mark.parametrize("axes", [("u",), ("u", "v")], ids=["u-only", "both-axes"])
def test_acquisition_of_a_phase_gray_codec_is_stored_with_its_codec_and_decodes_to_the_truth(api, rig, axes):
    document = phase_gray_codec(axes)
    canonical = codec_from_dict(document).to_dict()
    session = register(api, rig)
    queued = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": document})
    assert queued.status_code == 202, queued.content
    body = queued.json()
    assert body["codec"] == canonical and len(body["frame_names"]) == document["frames"]
    assert body["projector"] == {"width": PROJ_W, "height": PROJ_H}
    assert Job.objects.get(pk=body["job"]).parameters["codec"] == canonical

    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    assert taken["id"] == body["id"] and taken["codec"] == canonical
    images, archive = agent_grabs(taken)
    assert images.shape == (document["frames"], SMALL_RIG["height_px"], SMALL_RIG["width_px"])

    # a stack of another codec is refused, nothing stored, the acquisition still running
    wrong = api.post(
        f"/api/acquisitions/{body['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", plane_zip(), "application/zip")},
    )
    assert wrong.status_code == 400 and Capture.objects.count() == 0, wrong.content
    assert Job.objects.get(pk=body["job"]).status == "running"

    upload = api.post(
        f"/api/acquisitions/{body['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", archive, "application/zip"), "camera": "virtual"},
    )
    assert upload.status_code == 201, upload.content
    capture = Capture.objects.get()
    assert capture.codec == canonical and capture.source == "rig"
    assert Acquisition.objects.get().capture_id == capture.pk
    with capture.file.open("rb") as handle, zipfile.ZipFile(io.BytesIO(handle.read())) as stored_zip:
        assert json.loads(stored_zip.read("codec.json")) == canonical

    stack = load_codec_stack(capture)
    np.testing.assert_array_equal(stack.images, images)
    uv = decode_codec(stack.images, stack.codec).uv()
    truth = true_uv()
    for index, axis in enumerate(("u", "v")):
        decoded = uv[..., index]
        if axis not in axes:
            continue
        both = np.isfinite(decoded) & np.isfinite(truth[index])
        assert both.mean() > 0.5, (axis, both.mean())
        # 4-step phase, period 32 px, modulation ~100 grey levels, noise 1 grey level:
        # sigma = P / (2 pi) * sqrt(2 / N) * sigma_noise / B ~ 0.04 px; median |error| well under 0.1 px
        error = np.abs(decoded[both] - truth[index][both])
        assert np.median(error) < 0.1, (axis, float(np.median(error)))
        assert np.mean(error < 1.0) > 0.99, (axis, float(np.mean(error < 1.0)))  # no period slips


def test_acquisition_without_codec_takes_the_rigs_default_codec(api, rig):
    document = phase_gray_codec(("u",), steps=3)
    rig.codec = document
    rig.save(update_fields=["codec"])
    body = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "reference"}).json()
    assert body["codec"] == codec_from_dict(document).to_dict() and len(body["frame_names"]) == 15
    # the rig's default back to gcps-v1: an acquisition without codec is gcps-v1 again
    rig.codec = "gcps-v1"
    rig.save(update_fields=["codec"])
    body = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "reference"}).json()
    assert body["codec"] == "gcps-v1:1024x768" and body["frame_names"][0] == "GC_0"


def test_gcps_v1_acquisition_is_stored_with_codec_gcps_v1(api, rig):
    session = register(api, rig)
    body = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "reference"}).json()
    post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session})
    upload = api.post(
        f"/api/acquisitions/{body['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", plane_zip(), "application/zip")},
    )
    assert upload.status_code == 201, upload.content
    assert Capture.objects.get().codec == "gcps-v1"


def test_codecs_the_rig_cannot_use_or_a_mismatched_codec_json_are_refused(api, rig):
    v_only = phase_gray_codec(("v",))
    bad = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": v_only})
    assert bad.status_code == 400 and "u axis" in bad.json()["error"]
    bad = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": {"codec": "gcps-codec/1"}})
    assert bad.status_code == 400 and "codec" in bad.json()["error"]
    assert Acquisition.objects.count() == 0 and Job.objects.count() == 0
    # an upload whose codec.json is another codec than the one projected is refused
    session = register(api, rig)
    four = phase_gray_codec(("u",), steps=4)
    body = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": four}).json()
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    images, _ = agent_grabs(taken)
    three = resolve_codec(phase_gray_codec(("u",), steps=3))
    other = stack_zip(images[: three.n_frames], three)
    refused = api.post(
        f"/api/acquisitions/{body['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", other, "application/zip")},
    )
    assert refused.status_code == 400 and "not the codec that was projected" in refused.json()["error"]
    assert Capture.objects.count() == 0


def test_projector_serves_the_codecs_patterns(client_alice, api, rig):
    document = phase_gray_codec(("u", "v"))
    body = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": document}).json()
    expected = codec_patterns(codec_from_dict(document))
    for frame in (0, 5, 14, 20, document["frames"] - 2):
        response = client_alice.get(f"/rigs/{rig.pk}/projector/acquisitions/{body['id']}/frames/{frame}.png")
        assert response.status_code == 200, (frame, response.status_code)
        image = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(image, expected[frame])
    page = client_alice.get(f"/acquisitions/{body['id']}/")
    assert page.status_code == 200 and b"gcps-codec/1: 30 frames, axes u, v, projector 1024x768" in page.content


def test_dashboard_form_takes_a_codec_object_and_thumbnails_its_stored_frames(client_alice, api, rig):
    document = phase_gray_codec(("u",), steps=3)
    bad = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "codec": "{not json"})
    assert bad.status_code == 400 and "not a JSON object" in bad.content.decode()
    done = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "codec": json.dumps(document)})
    acquisition = Acquisition.objects.get()
    assert done.status_code == 302 and done["Location"] == f"/acquisitions/{acquisition.pk}/"
    assert acquisition.codec == codec_from_dict(document).to_dict()
    session = register(api, rig)
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    images, archive = agent_grabs(taken)
    upload = api.post(
        f"/api/acquisitions/{acquisition.pk}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", archive, "application/zip")},
    )
    assert upload.status_code == 201, upload.content
    # the thumbnail of a stored frame of this codec (read with the codec reader)
    response = client_alice.get(f"/acquisitions/{acquisition.pk}/frames/3.png")
    assert response.status_code == 200, response.status_code
    thumbnail = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert images.shape[2] == 160  # the small rig is 160 px wide: the thumbnail is the frame itself
    np.testing.assert_array_equal(thumbnail, images[3])
