"""The embedded default's jobs (no broker): the request that starts a job answers at once, the job
runs in the process's background thread after the commit, and its page shows its progress and then
its result (``GCPS_EMBEDDED_JOBS=background``, the default; the other tests run jobs inline)."""

from __future__ import annotations

import time

import pytest

from metrology.jobs.models import Job
from metrology.jobs.services import EmbeddedWorker
from metrology.measurements.models import Measurement


@pytest.fixture
def background_jobs(transactional_db, settings):
    """Jobs run in the embedded worker thread, slowly enough (a pause between phases) to be seen running."""
    settings.GCPS_EMBEDDED_JOBS = "background"
    settings.GCPS_JOB_PHASE_PAUSE_SECONDS = 0.4
    yield EmbeddedWorker.get()
    assert EmbeddedWorker.get().wait_idle(120), "the embedded worker did not finish its jobs"


def test_a_measurement_runs_after_the_request_and_its_page_shows_progress(client_alice, rig, captures, background_jobs):
    reference, obj = captures
    start = time.monotonic()
    response = client_alice.post("/measurements/new/", {"rig": rig.pk, "reference": reference.pk, "object": obj.pk})
    answered_s = time.monotonic() - start
    assert response.status_code == 302
    measurement = Measurement.objects.get(rig=rig)
    job = Job.objects.get(pk=measurement.job_id)
    assert job.status in (Job.Status.QUEUED, Job.Status.RUNNING), (job.status, answered_s)
    page = client_alice.get(response["Location"]).content.decode()
    assert f'data-url="/api/jobs/{job.pk}/"' in page and "data-finished" not in page
    assert background_jobs.wait_idle(120)
    job.refresh_from_db()
    assert job.status == Job.Status.DONE, job.error
    assert job.heartbeat_at is not None and job.heartbeat_at >= job.started_at
    page = client_alice.get(response["Location"]).content.decode()
    assert 'id="fig-height_map"' in page and 'class="card js-job"' not in page
    assert client_alice.get(f"/jobs/{job.pk}/").status_code == 200


def test_a_job_left_running_by_a_stopped_process_is_run_again(
    alice, rig, captures, settings, monkeypatch, transactional_db
):
    """A fresh embedded worker sweeps first: a job whose heartbeat went stale (its process stopped
    mid-job) runs again, instead of staying "running" for ever."""
    from datetime import timedelta

    from django.utils import timezone

    import metrology.jobs.services as job_services
    from metrology.measurements.services import request_measurement

    reference, obj = captures
    with monkeypatch.context() as patched:
        patched.setattr(job_services, "_send", lambda job_id, **_: None)  # the process stops before it runs
        measurement = request_measurement(owner=alice, rig=rig, reference_id=reference.pk, object_id=obj.pk)
    stale = timezone.now() - timedelta(seconds=settings.GCPS_JOB_STALE_SECONDS + 5)
    Job.objects.filter(pk=measurement.job_id).update(
        status=Job.Status.RUNNING, attempts=1, started_at=stale, heartbeat_at=stale, progress=40
    )
    settings.GCPS_EMBEDDED_JOBS = "background"
    monkeypatch.setattr(EmbeddedWorker, "_instance", None)  # a fresh process's worker
    worker = EmbeddedWorker.get()
    deadline = time.monotonic() + 120
    while not Job.objects.get(pk=measurement.job_id).finished and time.monotonic() < deadline:
        time.sleep(0.2)
    assert worker.wait_idle(120)
    job = Job.objects.get(pk=measurement.job_id)
    assert job.status == Job.Status.DONE and job.attempts == 2, (job.status, job.attempts, job.error)
