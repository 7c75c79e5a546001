"""An agent's stack is checked before it is stored (issue 23 item 6): frames of random noise, or frames
without fringes, are refused; the agent gets the reason (400), the acquisition's job fails with it,
and the API and the acquisition's page show it; nothing is stored."""

from __future__ import annotations

import html
import json

import numpy as np
import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from metrology.captures.models import Capture
from metrology.core.codecs import builtin_codec
from metrology.core.codecs.decode import fringe_refusal
from metrology.jobs.models import Job
from tests.app.stacks import SMALL_RIG, plane_zip, render_images, stack_zip
from tests.conftest import logged_in

SHAPE = (11, SMALL_RIG["height_px"], SMALL_RIG["width_px"])


def noise_zip(seed: int = 0) -> bytes:
    return stack_zip(np.random.default_rng(seed).integers(0, 256, SHAPE).astype(np.uint8))


def dark_zip() -> bytes:
    return stack_zip(np.random.default_rng(1).integers(0, 4, SHAPE).astype(np.uint8))


@pytest.fixture
def api(alice_token) -> Client:
    return Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")


def _post(client: Client, url: str, data: dict):
    return client.post(url, json.dumps(data), content_type="application/json")


def _taken_acquisition(api: Client, rig) -> tuple[str, dict]:
    session = _post(api, f"/api/rigs/{rig.pk}/agent/register/", {"camera": "virtual", "name": "bench"}).json()
    queued = _post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"}).json()
    taken = _post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session["session"]}).json()
    assert taken["id"] == queued["id"]
    return session["session"], queued


@pytest.mark.parametrize(
    ("stack", "reason"),
    [
        (noise_zip, "the frames do not show the codec's fringes"),
        (dark_zip, "the frames show no fringes of the codec"),
    ],
    ids=["random-noise", "dark"],
)
def test_a_stack_without_the_codecs_fringes_is_refused_with_a_reason_everyone_sees(api, alice, rig, stack, reason):
    session, queued = _taken_acquisition(api, rig)
    upload = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", stack(), "application/zip"), "frames": "[]"},
    )
    # the agent: a 400 naming the reason
    assert upload.status_code == 400, upload.content
    assert reason in upload.json()["error"] and "the uploaded stack was refused" in upload.json()["error"]
    assert Capture.objects.count() == 0
    # the job and the API
    job = Job.objects.get(pk=queued["job"])
    assert job.status == "failed" and reason in job.error
    shown = api.get(f"/api/acquisitions/{queued['id']}/").json()
    assert shown["status"] == "failed" and reason in shown["error"]
    # the acquisition's page
    page = logged_in(alice).get(f"/acquisitions/{queued['id']}/")
    assert page.status_code == 200 and reason in html.unescape(page.content.decode())
    # the agent's later report of the failure finds the acquisition already failed
    failed = _post(api, f"/api/acquisitions/{queued['id']}/fail/", {"session": session, "reason": "upload refused"})
    assert failed.status_code == 409


def test_a_stack_with_fringes_is_stored(api, rig):
    session, queued = _taken_acquisition(api, rig)
    upload = api.post(
        f"/api/acquisitions/{queued['id']}/upload/",
        {"session": session, "file": SimpleUploadedFile("s.zip", plane_zip(z_mm=5.0), "application/zip")},
    )
    assert upload.status_code == 201, upload.content
    assert Capture.objects.count() == 1


def test_the_core_check_tells_fringes_from_noise_and_flat_frames():
    from metrology.core.geometry.crossed_axes import Rig

    codec = builtin_codec("gcps-v1")
    rng = np.random.default_rng(3)
    assert fringe_refusal(render_images(Rig.from_dict(SMALL_RIG), 0.0), codec) is None
    assert fringe_refusal(render_images(Rig.from_dict(SMALL_RIG), 0.0, bit_depth=16), codec) is None
    noise16 = rng.integers(0, 65536, SHAPE).astype(np.uint16)
    assert "coordinates do not follow the code" in (fringe_refusal(noise16, codec) or "")
    flat = np.full(SHAPE, 200, np.uint8)
    assert "0.0 % of the sampled pixels decode" in (fringe_refusal(flat, codec) or "")
