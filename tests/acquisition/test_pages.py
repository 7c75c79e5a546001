"""Dashboard pages of acquisition: the acquire page (agent status, form), an acquisition's page (progress,
per-frame checks, thumbnails of the stored frames), and the link beside "simulate" on the rig's captures."""

from __future__ import annotations

import json

import cv2
import numpy as np
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from metrology.acquisition.models import Acquisition
from metrology.jobs.models import Job
from tests.app.stacks import plane_zip


def test_rig_captures_page_links_to_acquire(client_alice, rig):
    html = client_alice.get(f"/rigs/{rig.pk}/captures/").content.decode()
    assert f"/rigs/{rig.pk}/acquire/" in html and "Simulate a capture" in html


def test_acquire_page_shows_agent_status_and_queues(client_alice, alice_token, rig):
    page = client_alice.get(f"/rigs/{rig.pk}/acquire/")
    assert page.status_code == 200 and "not connected" in page.content.decode()
    api = Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")
    api.post(f"/api/rigs/{rig.pk}/agent/register/", json.dumps({"camera": "opencv:0"}), content_type="application/json")
    html = client_alice.get(f"/rigs/{rig.pk}/acquire/").content.decode()
    assert "connected" in html and "opencv:0" in html and "last seen" in html
    bad = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "stage", "codec": "gcps-v1"})
    assert bad.status_code == 400 and "z_in_mm is required" in bad.content.decode()
    assert Acquisition.objects.count() == 0
    done = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "reference", "exposure": "12", "codec": "gcps-v1"})
    acquisition = Acquisition.objects.get()
    assert done.status_code == 302 and done["Location"] == f"/acquisitions/{acquisition.pk}/"
    assert acquisition.exposure_ms == 12.0 and acquisition.job.status == Job.Status.QUEUED


def test_acquire_form_asks_for_a_multi_exposure_capture(client_alice, rig):
    page = client_alice.get(f"/rigs/{rig.pk}/acquire/").content.decode()
    assert 'name="exposures"' in page and 'name="max_exposures"' in page
    bad = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "exposures": "10,1,10"})
    assert bad.status_code == 400 and "exposures must be distinct exposure times" in bad.content.decode()
    bad = client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "exposures": "1,10", "max_exposures": "2"})
    assert bad.status_code == 400 and "max_exposures applies to exposures" in bad.content.decode()
    assert Acquisition.objects.count() == 0
    client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "exposures": "100, 1,10"})
    client_alice.post(f"/rigs/{rig.pk}/acquire/", {"role": "object", "exposures": "auto", "max_exposures": "2"})
    listed, auto = Acquisition.objects.order_by("id")
    assert listed.exposures == [1.0, 10.0, 100.0] and (auto.exposures, auto.max_exposures) == ("auto", 2)
    assert "exposures 1.0, 10.0, 100.0 ms" in client_alice.get(f"/acquisitions/{listed.pk}/").content.decode()
    html = client_alice.get(f"/acquisitions/{auto.pk}/").content.decode()
    assert "exposures bracketed automatically (at most 2)" in html


def test_acquisition_page_shows_checks_and_thumbnails(client_alice, alice_token, rig):
    api = Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")
    session = api.post(
        f"/api/rigs/{rig.pk}/agent/register/", json.dumps({"camera": "virtual"}), content_type="application/json"
    ).json()["session"]
    queued = api.post(
        f"/api/rigs/{rig.pk}/captures/acquire/", json.dumps({"role": "reference"}), content_type="application/json"
    ).json()
    api.post(f"/api/rigs/{rig.pk}/agent/take/", json.dumps({"session": session}), content_type="application/json")
    running = client_alice.get(f"/acquisitions/{queued['id']}/").content.decode()
    assert "No frame grabbed yet" in running and "acquisition/acquisition.js" in running
    frames = [
        {"name": "GC_3", "regrabs": 2, "refused_reasons": ["did not change from the previous frame", "saturated"],
         "saturated_fraction": 0.0, "dark_fraction": 0.3, "change_fraction": 0.49, "expected_change": 0.5},
    ]  # fmt: skip
    response = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {
            "session": session,
            "file": SimpleUploadedFile("s.zip", plane_zip(), "application/zip"),
            "frames": json.dumps(frames),
        },
    )
    assert response.status_code == 201
    html = client_alice.get(f"/acquisitions/{queued['id']}/").content.decode()
    assert "did not change from the previous frame; saturated" in html and "0.490 (0.500)" in html
    thumb_url = f"/acquisitions/{queued['id']}/frames/3.png"
    assert thumb_url in html
    thumb = client_alice.get(thumb_url)
    image = cv2.imdecode(np.frombuffer(thumb.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert thumb["Content-Type"] == "image/png" and image.shape == (120, 160)  # the small rig is 160 px wide
    assert client_alice.get(f"/acquisitions/{queued['id']}/frames/11.png").status_code == 404
