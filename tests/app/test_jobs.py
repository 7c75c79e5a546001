"""The job engine: claiming, idempotence, takeover of stale jobs, the sweep, failures and retries."""

from __future__ import annotations

from datetime import timedelta

import pytest
from celery.exceptions import SoftTimeLimitExceeded
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage
from django.db import OperationalError
from django.utils import timezone

from metrology.jobs import services
from metrology.jobs.models import Job
from tests.conftest import stored_files


@pytest.fixture
def job(user_and_token) -> Job:
    return services.create_job(owner=user_and_token[0], kind=Job.Kind.MEASUREMENT, parameters={"x": 1})


@pytest.fixture
def handler(monkeypatch):
    """Replace the measurement handler by a function the test sets."""
    calls = []

    def set_handler(function):
        def wrapped(job, run):
            calls.append(run.token)
            return function(job, run)

        monkeypatch.setattr(services, "_handler", lambda kind: wrapped)
        return calls

    return set_handler


def test_a_job_runs_once_and_a_done_job_is_not_recomputed(job, handler):
    calls = handler(lambda job, run: run.commit(lambda _job: None))
    assert services.execute_job(job.pk) == "done"
    job.refresh_from_db()
    assert (job.status, job.progress, job.attempts) == ("done", 100, 1)
    assert services.execute_job(job.pk) == "skipped"
    assert len(calls) == 1


def test_a_running_job_with_a_fresh_heartbeat_is_left_alone(job, handler):
    calls = handler(lambda job, run: None)
    assert services.claim_job(job.pk) is not None
    assert services.execute_job(job.pk) == "skipped"
    assert calls == []


def test_a_redelivered_message_of_a_just_killed_worker_is_retried_later(job, handler):
    handler(lambda job, run: None)
    assert services.claim_job(job.pk, task_id="task-1") is not None
    assert services.execute_job(job.pk, task_id="task-1") == services.BUSY
    assert services.execute_job(job.pk, task_id="task-2") == "skipped"


def test_a_stale_running_job_is_taken_over_and_the_old_attempt_cannot_publish(job, handler, settings):
    old = services.claim_job(job.pk)
    old.save_file(default_storage, "measurements/1/old/height.npy", ContentFile(b"half"))
    Job.objects.filter(pk=job.pk).update(
        heartbeat_at=timezone.now() - timedelta(seconds=settings.GCPS_JOB_STALE_SECONDS + 1)
    )
    new = services.claim_job(job.pk)
    assert new is not None and new.token != old.token
    with pytest.raises(services.SupersededError):
        old.commit(lambda _job: pytest.fail("superseded attempt must not write"))
    with pytest.raises(services.SupersededError):
        old.progress(50, "measure")
    old.discard_files()
    new.commit(lambda _job: None)
    job.refresh_from_db()
    assert job.status == "done" and job.attempts == 2


def test_a_job_past_its_attempts_is_failed_with_the_reason(job, settings):
    Job.objects.filter(pk=job.pk).update(
        status="running", attempts=settings.GCPS_JOB_MAX_ATTEMPTS, heartbeat_at=timezone.now() - timedelta(hours=1)
    )
    assert services.claim_job(job.pk) is None
    job.refresh_from_db()
    assert job.status == "failed" and f"gave up after {settings.GCPS_JOB_MAX_ATTEMPTS} attempts" in job.error


def test_the_sweep_requeues_stale_jobs_and_fails_exhausted_ones(user_and_token, settings, monkeypatch):
    sent = []
    monkeypatch.setattr(services, "enqueue_job", lambda job, **_: sent.append(job.pk))
    owner = user_and_token[0]
    old = timezone.now() - timedelta(seconds=settings.GCPS_JOB_STALE_SECONDS + 5)
    stale = services.create_job(owner=owner, kind="measurement", parameters={})
    exhausted = services.create_job(owner=owner, kind="measurement", parameters={})
    fresh = services.create_job(owner=owner, kind="measurement", parameters={})
    Job.objects.filter(pk=stale.pk).update(status="running", attempts=1, heartbeat_at=old)
    Job.objects.filter(pk=exhausted.pk).update(
        status="running", attempts=settings.GCPS_JOB_MAX_ATTEMPTS, heartbeat_at=old
    )
    Job.objects.filter(pk=fresh.pk).update(status="running", attempts=1, heartbeat_at=timezone.now())
    assert services.sweep_stale_jobs() == {"requeued": 1, "failed": 1}
    assert sent == [stale.pk]
    assert Job.objects.get(pk=stale.pk).status == "queued"
    failed = Job.objects.get(pk=exhausted.pk)
    assert failed.status == "failed" and "the worker stopped responding" in failed.error
    assert Job.objects.get(pk=fresh.pk).status == "running"


@pytest.mark.parametrize(
    ("error", "reason"),
    [
        (ValueError("reference stack has no valid pixel"), "reference stack has no valid pixel"),
        (SoftTimeLimitExceeded(), "stopped at the time limit of"),
        (KeyError("boom"), "internal error during the 'measure' phase: the job stopped on an unexpected KeyError"),
        (MemoryError(), "the worker ran out of memory during the 'measure' phase"),
        # a library's message that names its source files is not shown: it is logged instead
        (
            ValueError('File "/usr/lib/python3/dist-packages/scipy/optimize/_lsq.py", line 3, in f'),
            "internal error during the 'measure' phase: the job stopped on an unexpected ValueError",
        ),
    ],
)
def test_errors_fail_the_job_with_a_reason_and_leave_no_file(job, handler, media_root, error, reason):
    def compute(job, run):
        run.progress(10, "measure")
        run.save_file(default_storage, f"measurements/{job.pk}/{run.token.hex}/height.npy", ContentFile(b"partial"))
        raise error

    handler(compute)
    assert services.execute_job(job.pk) == "failed"
    job.refresh_from_db()
    assert job.status == "failed" and reason in job.error, job.error
    assert "boom" not in job.error and "Traceback" not in job.error and ".py" not in job.error
    assert stored_files(media_root) == []


def test_transient_errors_release_the_job_for_a_retry(job, handler):
    handler(lambda job, run: (_ for _ in ()).throw(OperationalError("server closed the connection")))
    with pytest.raises(OperationalError):
        services.execute_job(job.pk, transient=(OperationalError,))
    job.refresh_from_db()
    assert job.status == "queued" and job.run_token is None
    assert job.attempts == 0  # a transient failure does not use up one of the attempts
    handler(lambda job, run: run.commit(lambda _job: None))
    assert services.execute_job(job.pk) == "done"
    job.refresh_from_db()
    assert job.attempts == 1


def test_task_options():
    from metrology.jobs.tasks import TRANSIENT_ERRORS, run_job

    assert run_job.acks_late and run_job.reject_on_worker_lost
    assert set(run_job.autoretry_for) == set(TRANSIENT_ERRORS)
    assert OperationalError in TRANSIENT_ERRORS and ValueError not in TRANSIENT_ERRORS
    from workers import app

    assert app.conf.task_soft_time_limit and app.conf.task_time_limit > app.conf.task_soft_time_limit
    assert "sweep-stale-jobs" in app.conf.beat_schedule


def test_tasks_keep_their_registered_names_and_are_autodiscovered():
    """Messages already queued and beat entries name the tasks by these strings."""
    from workers import app

    app.loader.import_default_modules()  # what a worker does at start: autodiscovery over the installed apps
    names = {"workers.tasks.run_job", "workers.tasks.sweep_stale_jobs"}
    names.add("metrology.reports.tasks.scheduled_characterization_report")
    assert names <= set(app.tasks), sorted(name for name in app.tasks if not name.startswith("celery."))
    assert app.tasks["workers.tasks.run_job"].__module__ == "metrology.jobs.tasks"


def test_every_job_kind_has_a_registered_handler():
    from metrology.jobs.handlers import handler_for, register_handler, registered_kinds
    from metrology.measurements.services import run_measurement

    assert registered_kinds() == set(Job.Kind)
    assert handler_for("measurement") is run_measurement
    with pytest.raises(LookupError, match="'nonsense'"):
        handler_for("nonsense")
    with pytest.raises(ValueError, match="already has the handler"):
        register_handler(Job.Kind.MEASUREMENT, lambda job, run: None)


def test_the_sweep_resends_jobs_queued_too_long_and_a_job_sent_twice_runs_once(
    user_and_token, settings, handler, django_capture_on_commit_callbacks
):
    """A lost message (broker restarted without persistence) leaves the job queued: it is sent again."""
    calls = handler(lambda job, run: run.commit(lambda _job: None))
    owner = user_and_token[0]
    long_ago = timezone.now() - timedelta(seconds=settings.GCPS_JOB_RESEND_SECONDS + 5)
    lost = services.create_job(owner=owner, kind="measurement", parameters={})
    also_lost = services.create_job(owner=owner, kind="measurement", parameters={})
    for_an_agent = services.create_job(owner=owner, kind="acquire_capture", parameters={})  # never enqueued
    recent = services.create_job(owner=owner, kind="measurement", parameters={})
    running = services.create_job(owner=owner, kind="measurement", parameters={})
    Job.objects.filter(pk__in=[lost.pk, also_lost.pk]).update(enqueued_at=long_ago)
    Job.objects.filter(pk=for_an_agent.pk).update(created_at=long_ago)
    Job.objects.filter(pk=recent.pk).update(enqueued_at=timezone.now())
    Job.objects.filter(pk=running.pk).update(status="running", enqueued_at=long_ago, heartbeat_at=timezone.now())
    # embedded mode: "sending" runs the job in-process, so a resent job is done afterwards
    with django_capture_on_commit_callbacks(execute=True):
        assert services.resend_unclaimed_jobs() == {"resent": 2, "waiting": 0}
    assert Job.objects.get(pk=lost.pk).status == Job.Status.DONE
    assert Job.objects.get(pk=also_lost.pk).status == Job.Status.DONE
    assert Job.objects.get(pk=for_an_agent.pk).status == Job.Status.QUEUED
    assert Job.objects.get(pk=recent.pk).status == Job.Status.QUEUED
    assert Job.objects.get(pk=running.pk).status == Job.Status.RUNNING
    assert len(calls) == 2
    # the original message of the lost job turns up after all: the job is not run again
    assert services.execute_job(lost.pk) == "skipped"
    assert services.sweep_jobs() == {
        "requeued": 0,
        "failed": 0,
        "resent": 0,
        "waiting": 0,
        "agents_expired": 0,
        "acquisitions_expired": 0,
    }
    assert len(calls) == 2 and Job.objects.get(pk=lost.pk).attempts == 1
