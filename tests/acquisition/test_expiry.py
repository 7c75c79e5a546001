"""Acquisitions that no agent takes expire with a reason (issue 23 item 6): after
``GCPS_ACQUISITION_TIMEOUT_SECONDS`` on a rig without a connected agent, the next read or the periodic
job sweep fails them; the API, the job and the pages show why."""

from __future__ import annotations

import html
import json
from datetime import timedelta

import pytest
from django.test import Client
from django.utils import timezone

from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from tests.conftest import logged_in

REASON = "no capture agent took this acquisition within 60 s (GCPS_ACQUISITION_TIMEOUT_SECONDS)"


@pytest.fixture
def api(alice_token, settings) -> Client:
    settings.GCPS_ACQUISITION_TIMEOUT_SECONDS = 60.0
    return Client(HTTP_AUTHORIZATION=f"Token {alice_token[1]}")


def _post(client: Client, url: str, data: dict):
    return client.post(url, json.dumps(data), content_type="application/json")


def _acquire(api: Client, rig, *, age_s: float) -> dict:
    queued = _post(api, f"/api/rigs/{rig.pk}/captures/acquire/", {"role": "object"})
    assert queued.status_code == 202, queued.content
    Job.objects.filter(pk=queued.json()["job"]).update(created_at=timezone.now() - timedelta(seconds=age_s))
    return queued.json()


def test_the_next_read_expires_an_acquisition_no_agent_took(api, alice, rig):
    old = _acquire(api, rig, age_s=61)
    recent = _acquire(api, rig, age_s=30)
    shown = api.get(f"/api/acquisitions/{old['id']}/").json()
    assert shown["status"] == "failed" and REASON in shown["error"] and repr(rig.name) in shown["error"]
    assert api.get(f"/api/acquisitions/{recent['id']}/").json()["status"] == "queued"
    job = api.get(f"/api/jobs/{old['job']}/").json()
    assert job["status"] == "failed" and REASON in job["error"] and job["finished_at"]
    client = logged_in(alice)
    for page in (f"/acquisitions/{old['id']}/", f"/rigs/{rig.pk}/acquire/"):
        response = client.get(page)
        assert response.status_code == 200 and "no capture agent took this acquisition" in html.unescape(
            response.content.decode()
        ), page


def test_the_job_sweep_expires_them_without_any_read(api, rig):
    old = _acquire(api, rig, age_s=120)
    counts = job_services.sweep_jobs()
    assert counts["acquisitions_expired"] == 1
    job = Job.objects.get(pk=old["job"])
    assert job.status == "failed" and REASON in job.error
    assert job_services.sweep_jobs()["acquisitions_expired"] == 0  # once


def test_a_connected_agent_keeps_its_rigs_queue(api, rig):
    session = _post(api, f"/api/rigs/{rig.pk}/agent/register/", {"camera": "virtual", "name": "bench"}).json()
    waiting = _acquire(api, rig, age_s=600)  # behind a long queue, say: the agent will take it
    assert api.get(f"/api/acquisitions/{waiting['id']}/").json()["status"] == "queued"
    assert job_services.sweep_jobs()["acquisitions_expired"] == 0
    taken = _post(api, f"/api/rigs/{rig.pk}/agent/take/", {"session": session["session"]}).json()
    assert taken["id"] == waiting["id"] and taken["status"] == "running"
