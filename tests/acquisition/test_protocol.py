"""The acquisition API and agent protocol through Django's test client (real database, no mocks).

Process-level end-to-end tests (live server, headless Chromium, ``gcps agent``) are in
test_end_to_end.py; these pin the protocol's rules: one agent per rig, sessions, refusals,
timeouts, and nothing stored unless a whole valid stack is uploaded.
"""

from __future__ import annotations

import json
from datetime import timedelta

import cv2
import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client
from django.utils import timezone

from metrology.acquisition.models import Acquisition, Agent
from metrology.captures.models import Capture
from metrology.core.patterns import projector_patterns
from metrology.jobs.models import Job
from tests.app.stacks import plane_zip


@pytest.fixture
def api(alice_token) -> Client:
    return Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")


def post(client: Client, url: str, data: dict):
    return client.post(url, json.dumps(data), content_type="application/json")


def register(api: Client, rig, camera: str = "virtual") -> str:
    response = post(api, f"/api/rigs/{rig.pk}/agent/register/", {"camera": camera, "name": "bench-pc"})
    assert response.status_code == 201, response.content
    return response.json()["session"]


def test_second_agent_refused_while_first_connected(api, rig):
    session = register(api, rig)
    response = post(api, f"/api/rigs/{rig.pk}/agent/register/", {"camera": "opencv:0"})
    assert response.status_code == 409
    assert "already has a connected capture agent" in response.json()["error"]
    # after a clean disconnect a new agent may register
    assert post(api, f"/api/rigs/{rig.pk}/agent/disconnect/", {"session": session}).status_code == 200
    register(api, rig, "opencv:0")
    status = api.get(f"/api/rigs/{rig.pk}/agent/").json()
    assert status["connected"] is True and status["camera"] == "opencv:0"


def test_silent_agent_expires_and_its_acquisition_fails_with_reason(api, rig, settings):
    settings.GCPS_AGENT_TIMEOUT_SECONDS = 5.0
    session = register(api, rig)
    queued = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "reference"}).json()
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session})
    assert taken.status_code == 200 and taken.json()["id"] == queued["id"]
    Agent.objects.update(last_seen_at=timezone.now() - timedelta(seconds=6))
    detail = api.get(f"/api/acquisitions/{queued['id']}/").json()
    assert detail["status"] == "failed"
    assert "stopped responding" in detail["error"] and "no capture was stored" in detail["error"]
    assert Capture.objects.count() == 0
    # the expired session is refused, a new agent may register
    assert post(api, f"/api/rigs/{rig.pk}/agent/heartbeat/", {"session": session}).status_code == 409
    register(api, rig)


def test_acquire_validates_and_queues(api, rig):
    bad = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "stage"})
    assert bad.status_code == 400 and "z_in_mm" in bad.json()["error"]
    bad = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": "graycode-9"})
    assert bad.status_code == 400 and "codec" in bad.json()["error"]
    bad = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "exposure": -3})
    assert bad.status_code == 400 and "exposure" in bad.json()["error"]
    assert Acquisition.objects.count() == 0 and Job.objects.count() == 0
    ok = post(
        api,
        f"/api/rigs/{rig.pk}/captures/acquire/",
        {"role": "stage", "z_in_mm": 4.0, "repeat": 2, "exposure": 12.5, "codec": "gcps-v1:800x600"},
    )
    assert ok.status_code == 202, ok.content
    body = ok.json()
    assert body["status"] == "queued" and body["agent_connected"] is False
    assert body["codec"] == "gcps-v1:800x600" and body["projector"] == {"width": 800, "height": 600}
    assert body["frame_names"][0] == "GC_0" and len(body["frame_names"]) == 11
    assert Job.objects.get(pk=body["job"]).kind == "acquire_capture"


def test_take_progress_upload_stores_capture_with_provenance(api, rig):
    session = register(api, rig, "virtual:plane")
    assert post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).status_code == 204
    queued = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "reference", "exposure": 8}).json()
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    assert taken["id"] == queued["id"] and taken["rig_geometry"]["width_px"] == rig.width_px
    frames = [{"name": "GC_0", "ok": True, "regrabs": 1}]
    progress = post(
        api,
        f"/api/acquisitions/{queued['id']}/progress/",
        {"session": session, "percent": 40, "phase": "grab GC_3", "frames": frames},
    )
    assert progress.status_code == 200
    assert Job.objects.get(pk=queued["job"]).progress == 40
    # a truncated stack is refused and nothing is stored
    bad = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", b"PK\x03\x04broken", "application/zip")},
    )
    assert bad.status_code == 400 and Capture.objects.count() == 0
    upload = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {
            "session": session,
            "file": SimpleUploadedFile("s.zip", plane_zip(), "application/zip"),
            "camera": "virtual:plane",
            "exposure_ms": "8",
            "frames": json.dumps(frames),
        },
    )
    assert upload.status_code == 201, upload.content
    capture = Capture.objects.get()
    assert capture.source == "rig" and capture.role == "reference"
    assert capture.parameters["camera"] == "virtual:plane" and capture.parameters["exposure_ms"] == 8.0
    assert capture.parameters["agent"] == Agent.objects.get().pk and capture.parameters["regrabs"] == 1
    job = Job.objects.get(pk=queued["job"])
    assert job.status == "done" and job.progress == 100
    assert Acquisition.objects.get().frames == frames
    # a second upload for the finished acquisition is refused
    again = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", plane_zip(), "application/zip")},
    )
    assert again.status_code == 409 and Capture.objects.count() == 1


def test_agent_failure_and_disconnect_fail_the_job(api, rig):
    session = register(api, rig)
    first = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    second = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session})
    failed = post(api, f"/api/acquisitions/{first['id']}/fail/", {"session": session, "reason": "camera unplugged"})
    assert failed.status_code == 200 and failed.json()["status"] == "failed"
    assert Job.objects.get(pk=first["job"]).error == "camera unplugged"
    post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session})
    post(api, f"/api/rigs/{rig.pk}/agent/disconnect/", {"session": session, "reason": "agent stopped (SIGTERM)"})
    job = Job.objects.get(pk=second["job"])
    assert job.status == "failed" and job.error.startswith("agent stopped (SIGTERM)")
    assert Capture.objects.count() == 0


def test_projector_state_show_and_confirm(api, client_alice, rig):
    session = register(api, rig)
    acquisition = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    bad = post(api, f"/api/rigs/{rig.pk}/projector/", {"session": session, "kind": "frame", "frame": 11})
    assert bad.status_code == 400
    seq = post(
        api,
        f"/api/rigs/{rig.pk}/projector/",
        {"session": session, "kind": "frame", "frame": 3, "acquisition": acquisition["id"]},
    ).json()["seq"]
    state = client_alice.get(f"/api/rigs/{rig.pk}/projector/?page=1&after=0&wait=1").json()
    assert (state["seq"], state["kind"], state["frame"], state["shown_seq"]) == (seq, "frame", 3, 0)
    shown = client_alice.post(
        f"/api/rigs/{rig.pk}/projector/shown/",
        json.dumps({"seq": seq, "kind": "frame", "frame": 3, "screen": {"device_pixel_ratio": 2}}),
        content_type="application/json",
    )
    assert shown.status_code == 200
    state = api.get(f"/api/rigs/{rig.pk}/projector/?shown={seq}&wait=1").json()
    assert state["shown_seq"] == seq and state["shown_frame"] == 3


@pytest.mark.parametrize(
    "body",
    [
        {"seq": 1, "kind": "frame", "frame": -12775725494152984459739136},  # found by schemathesis: a 500 before
        {"seq": 2**40, "kind": "frame", "frame": 3},
        {"seq": 1, "kind": "frame", "frame": 2**31},
    ],
)
def test_projector_confirmation_out_of_range_is_refused_not_a_server_error(client_alice, rig, body):
    answer = client_alice.post(
        f"/api/rigs/{rig.pk}/projector/shown/", json.dumps(body), content_type="application/json"
    )
    assert answer.status_code == 400
    assert "error" in answer.json()


def test_projector_state_wait_parameters_out_of_range_are_refused(client_alice, rig):
    answer = client_alice.get(f"/api/rigs/{rig.pk}/projector/?after={10**30}&wait=0")
    assert answer.status_code == 400
    assert "after" in answer.json()["error"]


def test_projector_page_and_frames(client_alice, api, rig):
    page = client_alice.get(f"/rigs/{rig.pk}/projector/")
    assert page.status_code == 200
    html = page.content.decode()
    assert "acquisition/projector.js" in html and "<canvas" in html
    assert " on" + "click" not in html.lower() and "<script>" not in html  # no inline script (CSP)
    acquisition = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object", "codec": "gcps-v1:640x480"})
    acq = acquisition.json()["id"]
    png = client_alice.get(f"/rigs/{rig.pk}/projector/acquisitions/{acq}/frames/8.png")
    assert png.status_code == 200 and png["Content-Type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(image, projector_patterns(640, 480)[8])
    assert client_alice.get(f"/rigs/{rig.pk}/projector/acquisitions/{acq}/frames/11.png").status_code == 404
    assert Client().get(f"/rigs/{rig.pk}/projector/").status_code == 302  # login required


def test_stale_acquisition_requeued_by_the_sweep_fails_with_a_reason(api, rig, monkeypatch):
    """If the jobs' stale sweep sees a running acquisition first, the worker fails it with words."""
    from metrology.jobs import services as job_services

    session = register(api, rig)
    queued = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session})
    Job.objects.filter(pk=queued["job"]).update(heartbeat_at=timezone.now() - timedelta(hours=1))
    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: None)  # the test runs the requeued job itself
    assert job_services.sweep_stale_jobs()["requeued"] == 1
    assert job_services.execute_job(queued["job"]) == "failed"
    job = Job.objects.get(pk=queued["job"])
    assert job.status == "failed" and "capture agent running this acquisition stopped responding" in job.error
    assert Capture.objects.count() == 0


@pytest.mark.slow  # three exposures rendered on the virtual camera: about 6 s
def test_a_bracketed_acquisition_uploads_a_multi_exposure_capture(api, rig):
    """The agent's automatic bracket on the virtual camera (a 1000:1 part on the paper's rig,
    gcps-v1), written as the agent uploads it, is stored with its exposures."""
    from metrology.acquisition.agent.cameras import AcquisitionTarget, VirtualCamera
    from metrology.acquisition.agent.client import exposures_zip
    from metrology.acquisition.agent.patterns import resolve_codec
    from metrology.acquisition.agent.sequencer import InstantProjector, SequenceOptions, run_bracketed_sequence
    from metrology.captures.stacks import load_capture_images
    from metrology.core.codecs.stack import ExposureStack

    session = register(api, rig)
    queued = post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    camera = VirtualCamera({"name": "plane", "hdr": True}, {"bit_depth": 8, "noise_grey": 1.0})
    codec = resolve_codec(taken["codec"])
    camera.prepare(AcquisitionTarget(role="object", codec=codec, rig_geometry=taken["rig_geometry"]))
    acquired = run_bracketed_sequence(
        InstantProjector(), camera, codec, exposures_ms=None, options=SequenceOptions(settle_s=0.0)
    )
    exposures = list(acquired.exposures_ms)
    assert len(exposures) >= 2 and exposures == sorted(exposures)
    data = exposures_zip([s.images for s in acquired.stacks], exposures, codec)
    upload = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", data, "application/zip"), "exposure_ms": "1"},
    )
    assert upload.status_code == 201, upload.content
    capture = Capture.objects.get()
    assert [e["exposure_us"] for e in capture.exposures] == pytest.approx([e * 1000 for e in exposures])
    stored = load_capture_images(capture)
    assert isinstance(stored, ExposureStack)
    for images, frames in zip(stored.images, acquired.stacks, strict=True):
        assert np.array_equal(images, frames.images)  # bit for bit as grabbed


def test_acquire_takes_the_exposures_of_a_multi_exposure_capture_and_refuses_bad_ones(api, rig):
    """``exposures``: "auto" (with ``max_exposures``) or times in ms, stored shortest first; every
    refusal a 400 naming the field, nothing stored (docs/exposures.md). The schema's part is in
    tests/app/test_openapi.py."""
    from metrology.rigs.services import create_rig
    from tests.app.stereo_stacks import WIDE_RIG

    url = f"/api/rigs/{rig.pk}/captures/acquire/"
    refusals = [
        ({"exposures": [1, -10]}, "exposures must be finite exposure times in (0, 60000] ms"),
        ({"exposures": [0]}, "exposures must be finite"),
        ({"exposures": "1,1e400"}, "exposures must be finite"),
        ({"exposures": [10**400]}, "exposures must be 'auto' or exposure times in ms"),
        ({"exposures": [10, 1, 10]}, "exposures must be distinct"),
        ({"exposures": list(range(1, 10))}, "exposures may list at most 8 exposure times, got 9"),
        ({"exposures": []}, "exposures must list at least one"),
        ({"exposures": "bright"}, "exposures must be 'auto' or exposure times in ms"),
        ({"exposures": {"auto": True}}, "exposures must be 'auto' or a list"),
        ({"exposures": [True]}, "exposures must be exposure times in ms"),
        ({"exposures": [1, 10], "max_exposures": 2}, 'max_exposures applies to exposures "auto" only'),
        ({"exposures": "auto", "max_exposures": 9}, "max_exposures"),
        ({"exposures": [1, 10], "exposure": 5}, "give exposure (one exposure) or exposures"),
    ]
    for extra, message in refusals:
        response = post(api, url, {"role": "object", **extra})
        assert response.status_code == 400, (extra, response.content)
        assert message in response.json()["error"], (extra, response.json())
    assert Acquisition.objects.count() == 0 and Job.objects.count() == 0
    stereo = create_rig(owner=rig.owner, data={**WIDE_RIG.to_dict(), "name": "stereo"})
    response = post(api, f"/api/rigs/{stereo.pk}/captures/acquire/", {"role": "object", "exposures": [1, 10]})
    assert response.status_code == 202 and response.json()["exposures"] == [1.0, 10.0]  # bracketed as a pair

    listed = post(api, url, {"role": "object", "exposures": [100, 1.5, 10]}).json()
    assert listed["exposures"] == [1.5, 10.0, 100.0] and listed["max_exposures"] is None
    auto = post(api, url, {"role": "object", "exposures": "AUTO", "max_exposures": 2}).json()
    assert auto["exposures"] == "auto" and auto["max_exposures"] == 2
    single = post(api, url, {"role": "object", "exposure": 4}).json()
    assert single["exposures"] is None and single["exposure_ms"] == 4.0
    assert Job.objects.get(pk=listed["job"]).parameters["exposures"] == [1.5, 10.0, 100.0]
    # the agent takes them with the acquisition, oldest first
    session = register(api, rig)
    taken = post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session}).json()
    assert taken["id"] == listed["id"] and taken["exposures"] == [1.5, 10.0, 100.0]


def test_the_agent_honours_the_requests_exposures_over_its_own_default():
    """:func:`requested_exposures`: the request's ``exposures`` (and ``max_exposures``), or its single
    ``exposure``, over the agent's ``--exposures``/``--max-exposures``, which serve the requests
    that choose neither."""
    from metrology.acquisition.agent.bracketing import BracketOptions
    from metrology.acquisition.agent.client import AgentOptions, requested_exposures
    from metrology.acquisition.agent.sequencer import SequenceOptions

    options = AgentOptions(SequenceOptions(), exposures=(4.0, 40.0), bracket=BracketOptions(max_exposures=5))
    assert requested_exposures({"exposures": [2.0, 20.0]}, options) == ((2.0, 20.0), options.bracket)
    choice, bracket = requested_exposures({"exposures": "auto", "max_exposures": 2}, options)
    assert choice == "auto" and bracket.max_exposures == 2
    assert requested_exposures({"exposure_ms": 8.0, "exposures": None}, options) == (None, options.bracket)
    assert requested_exposures({"exposure_ms": None, "exposures": None}, options) == ((4.0, 40.0), options.bracket)
