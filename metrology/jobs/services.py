"""Jobs: create, enqueue, run (claim -> compute -> commit), sweep the ones whose worker died.

A job is run by :func:`execute_job`, which a Celery task calls with the job's id. The run
*claims* the job (status running, a fresh ``run_token``) in a short transaction, computes outside
any transaction while a heartbeat thread keeps ``heartbeat_at`` fresh, and publishes its result
with :meth:`JobRun.commit`, which re-checks in one transaction that the attempt still owns the job
before it writes rows and marks the job done. So:

- a done or failed job is never recomputed (a duplicate message is acknowledged and ignored);
- a job whose worker died (SIGKILL, OOM, lost machine) has a stale heartbeat: the redelivered
  message (``acks_late`` + ``reject_on_worker_lost`` + the broker's visibility timeout) or the
  periodic :func:`sweep_stale_jobs` takes it over, and after ``GCPS_JOB_MAX_ATTEMPTS`` attempts
  it is marked failed with the reason;
- result files are written under an attempt-specific prefix and referenced by the rows only in
  the final transaction, so a half-written result is never visible.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import re
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import timedelta

from django.conf import settings
from django.core.files import File
from django.core.files.storage import Storage
from django.db import close_old_connections, connection, transaction
from django.db.models import F, Q
from django.db.models.functions import Greatest
from django.utils import timezone

from metrology.jobs import delivery
from metrology.jobs.handlers import JobHandler, handler_for, registered_sweeps
from metrology.jobs.models import Job
from metrology.unavailable import ServiceUnavailableError
from metrology.version import software_version

logger = logging.getLogger(__name__)


class SupersededError(Exception):
    """This attempt no longer owns the job (another attempt took it over, or it was failed)."""


class JobFailedError(Exception):
    """A job cannot complete for a reason a person can act on; the message becomes ``Job.error``."""


def create_job(*, owner, kind: str, parameters: dict) -> Job:
    """A queued job row; call :func:`enqueue_job` inside the same transaction."""
    return Job.objects.create(
        owner=owner, kind=kind, parameters=parameters, software_version=software_version(), status=Job.Status.QUEUED
    )


class BrokerUnavailableError(ServiceUnavailableError):
    """The broker cannot be reached, so a job cannot be sent to the workers now."""


RECOVERED_PRIORITY = 0
"""Priority of the messages of recovered jobs (a dead worker's job taken over, a lost message sent
again): on Redis, 0 is consumed first, before every job sent at ``CELERY_TASK_DEFAULT_PRIORITY``
(settings.py), so a recovered job is not put at the back of a backlog."""


def enqueue_job(job: Job, *, recovered: bool = False) -> None:
    """Send the job to the workers once the surrounding transaction commits.

    ``recovered`` (the sweep's resends and takeovers) sends it at :data:`RECOVERED_PRIORITY`: to
    the head of the queue.

    With a broker (not the embedded default), the broker is checked first, inside the transaction:
    when it is unreachable this raises :class:`BrokerUnavailableError`, the transaction that created
    the job (and the row that owns it) rolls back, and the request answers 503. Should the broker
    go away between that check and the send after commit, the job stays queued and the periodic
    sweep sends it again (:func:`sweep_jobs`).
    """
    if not settings.CELERY_TASK_ALWAYS_EAGER:
        check_broker()
    job_id = job.pk
    # marks the job as one the workers run (an acquisition, run by a rig's agent, never is)
    job.enqueued_at = timezone.now()
    Job.objects.filter(pk=job_id).update(enqueued_at=job.enqueued_at)
    transaction.on_commit(lambda: _send(job_id, recovered=recovered))


def check_broker() -> None:
    """Raise :class:`BrokerUnavailableError` unless the Celery broker answers (one try, about 2 s at most)."""
    from celery import current_app
    from kombu.exceptions import OperationalError as BrokerOperationalError

    try:
        with current_app.connection_for_write() as connection:
            connection.ensure_connection(max_retries=1, interval_start=0, interval_step=0.2, timeout=2)
    except (BrokerOperationalError, ConnectionError, OSError) as exc:
        logger.warning("broker unreachable: %s", exc)
        raise BrokerUnavailableError(
            "The job queue (broker) is unreachable, so the job was not created; try again in a minute.",
            retry_after_s=30,
        ) from None


def _send(job_id: int, *, recovered: bool = False) -> None:
    """Publish the job's message; on a broker failure, log it and leave the job queued for the sweep.

    On the embedded default (no broker) the job runs in this process: in the background thread of
    :class:`EmbeddedWorker` when ``GCPS_EMBEDDED_JOBS`` is ``background`` (the default: the request
    answers at once and the page shows the job's progress), else at once in the calling thread
    (``inline``: what the tests use, so that a job is done when its request returns).
    """
    from kombu.exceptions import OperationalError as BrokerOperationalError

    from metrology.jobs.tasks import run_job

    if settings.CELERY_TASK_ALWAYS_EAGER and settings.GCPS_EMBEDDED_JOBS == "background":
        EmbeddedWorker.get().submit(job_id)
        return
    options = {"priority": RECOVERED_PRIORITY} if recovered else {}
    delivery.mark_sent(job_id)  # before the send: the worker that receives it removes the marker
    try:
        result = run_job.apply_async(args=[job_id], **options)
    except (BrokerOperationalError, ConnectionError, OSError):
        if settings.CELERY_TASK_ALWAYS_EAGER:
            raise
        delivery.mark_unsent(job_id)  # no message waits: the sweep sends it again
        logger.warning("job %s could not be sent; it stays queued and the sweep sends it again", job_id, exc_info=True)
        return
    if not settings.CELERY_TASK_ALWAYS_EAGER:
        Job.objects.filter(pk=job_id, celery_task_id="").update(celery_task_id=result.id or "")


class EmbeddedWorker(threading.Thread):
    """The embedded default's job worker: one daemon thread of the web (or command) process that runs
    the jobs sent to it one after the other, outside the requests that created them.

    One thread, so that SQLite sees at most one job writing besides the requests (its writers wait
    for each other: ``timeout`` and ``transaction_mode`` of the database settings). Each job runs
    with a heartbeat (:func:`execute_job`), and the thread, when it starts, sweeps once
    (:func:`sweep_jobs`): a job left running by a process that stopped (a server restarted
    mid-job) is run again, or failed after ``GCPS_JOB_MAX_ATTEMPTS``, instead of staying "running".
    """

    _instance: EmbeddedWorker | None = None
    _lock = threading.Lock()

    def __init__(self) -> None:
        super().__init__(name="gcps-embedded-jobs", daemon=True)
        self.jobs: queue.Queue[int] = queue.Queue()
        self.idle = threading.Event()
        self.idle.set()

    @classmethod
    def get(cls) -> EmbeddedWorker:
        """The process's worker, started on first use."""
        with cls._lock:
            if cls._instance is None or not cls._instance.is_alive():
                cls._instance = cls()
                cls._instance.start()
            return cls._instance

    def submit(self, job_id: int) -> None:
        """Run the job ``job_id`` when the jobs sent before it are done."""
        self.idle.clear()
        self.jobs.put(job_id)

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Wait until every job sent so far has run; False if ``timeout`` (s) passed first."""
        return self.idle.wait(timeout)

    def run(self) -> None:
        try:
            sweep_jobs()
        except Exception:  # a sweep that fails must not stop the worker
            logger.warning("the embedded worker's first sweep failed", exc_info=True)
        finally:
            connection.close()
        while True:
            job_id = self.jobs.get()
            try:
                execute_job(job_id, heartbeat=True)
            except Exception:  # execute_job fails the job itself; this is a fault of the database
                logger.exception("embedded worker: job %s stopped", job_id)
            finally:
                connection.close()  # a fresh connection for the next job (SQLite: no lock held meanwhile)
                if self.jobs.empty():
                    self.idle.set()


# ----------------------------------------------------------------------------- running


@dataclass
class JobRun:
    """One attempt at a job: reports progress and phase timings, and commits the result."""

    job_id: int
    token: uuid.UUID
    timings: dict[str, float] = field(default_factory=dict)
    written: list[tuple[Storage, str]] = field(default_factory=list)  # (storage, name) to delete if superseded

    def progress(self, percent: int, phase: str = "") -> None:
        """Record progress (0-100) and what the job is doing; raises :class:`SupersededError` if taken over."""
        updated = Job.objects.filter(pk=self.job_id, run_token=self.token, status=Job.Status.RUNNING).update(
            progress=max(0, min(100, int(percent))), phase=phase[:64], heartbeat_at=timezone.now()
        )
        if not updated:
            raise SupersededError(f"job {self.job_id} was taken over by another attempt")
        if settings.GCPS_JOB_PHASE_PAUSE_SECONDS:
            time.sleep(settings.GCPS_JOB_PHASE_PAUSE_SECONDS)

    @contextlib.contextmanager
    def phase(self, name: str, percent: int) -> Iterator[None]:
        """Time a phase (``timings[name]``, seconds) after reporting ``percent`` and ``name``."""
        self.progress(percent, name)
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings[name] = round(self.timings.get(name, 0.0) + time.perf_counter() - start, 4)

    def save_file(self, storage: Storage, name: str, content: File) -> str:
        """Save ``content`` (a django File) under ``name``; remembered for cleanup. Returns the stored name."""
        stored = storage.save(name, content)
        self.written.append((storage, stored))
        return stored

    def commit(self, write: Callable[[Job], None]) -> None:
        """In one transaction: check ownership, call ``write(job)`` to store rows, mark the job done."""
        with transaction.atomic():
            job = Job.objects.select_for_update().get(pk=self.job_id)
            if job.run_token != self.token or job.status != Job.Status.RUNNING:
                raise SupersededError(f"job {self.job_id} was taken over by another attempt")
            write(job)
            job.status = Job.Status.DONE
            job.progress = 100
            job.phase = "done"
            job.error = ""
            job.timings = self.timings
            job.finished_at = timezone.now()
            job.heartbeat_at = job.finished_at
            job.save()
        self.written.clear()

    def discard_files(self) -> None:
        for storage, name in self.written:
            with contextlib.suppress(OSError):
                storage.delete(name)
        self.written.clear()


def _is_stale(job: Job, now) -> bool:
    beat = job.heartbeat_at or job.started_at
    return beat is None or now - beat > timedelta(seconds=settings.GCPS_JOB_STALE_SECONDS)


BUSY = "busy"


def claim_job(job_id: int, task_id: str = "") -> JobRun | str | None:
    """Take ownership of a job for this attempt; ``None`` when there is nothing to do.

    Nothing to do: the job is done or failed, or another attempt runs it with a fresh heartbeat.
    :data:`BUSY` when the job looks running under *this same task id*: a redelivery of the message
    of a worker that died moments ago (heartbeat not stale yet); the caller retries later.
    A job that has used up its attempts is marked failed here.
    """
    with transaction.atomic():
        job = Job.objects.select_for_update().filter(pk=job_id).first()
        if job is None or job.finished:
            return None
        now = timezone.now()
        if job.status == Job.Status.RUNNING and not _is_stale(job, now):
            return BUSY if task_id and job.celery_task_id == task_id else None
        if job.attempts >= settings.GCPS_JOB_MAX_ATTEMPTS:
            _fail(
                job,
                f"gave up after {job.attempts} attempts: the worker running it stopped (killed, out of memory "
                "or past the time limit) each time",
            )
            return None
        job.status = Job.Status.RUNNING
        job.attempts += 1
        job.run_token = uuid.uuid4()
        job.started_at = job.heartbeat_at = now
        job.error = ""
        job.phase = "starting"
        if task_id:
            job.celery_task_id = task_id
        job.save()
        return JobRun(job_id=job.pk, token=job.run_token)


def _fail(job: Job, reason: str) -> None:
    job.status = Job.Status.FAILED
    job.error = reason
    job.finished_at = timezone.now()
    job.save()


def fail_job(run: JobRun, reason: str) -> None:
    """Mark the job failed with ``reason`` if this attempt still owns it."""
    with transaction.atomic():
        job = Job.objects.select_for_update().get(pk=run.job_id)
        if job.run_token == run.token and job.status == Job.Status.RUNNING:
            job.timings = run.timings
            _fail(job, reason)


def release_job(run: JobRun) -> None:
    """Give the job back to the queue (before a retry of a transient failure).

    The attempt is not counted: ``GCPS_JOB_MAX_ATTEMPTS`` bounds the attempts that ended with their
    worker gone, not the database or broker blips a retry gets through.
    """
    Job.objects.filter(pk=run.job_id, run_token=run.token, status=Job.Status.RUNNING).update(
        status=Job.Status.QUEUED, run_token=None, phase="waiting to retry", attempts=Greatest(F("attempts") - 1, 0)
    )


class _Heartbeat(threading.Thread):
    """Keeps ``heartbeat_at`` fresh while the computation holds the main thread."""

    def __init__(self, run: JobRun) -> None:
        super().__init__(name=f"job-{run.job_id}-heartbeat", daemon=True)
        self.run_ = run
        self.stop_event = threading.Event()

    def run(self) -> None:
        try:
            while not self.stop_event.wait(settings.GCPS_JOB_HEARTBEAT_SECONDS):
                try:
                    Job.objects.filter(pk=self.run_.job_id, run_token=self.run_.token).update(
                        heartbeat_at=timezone.now()
                    )
                except Exception:  # a lost database must not kill the computation; the sweep will see it
                    logger.warning("heartbeat of job %s failed", self.run_.job_id, exc_info=True)
                    connection.close()  # a broken connection stays broken: open a new one next time
        finally:
            connection.close()

    def stop(self) -> None:
        self.stop_event.set()
        self.join(timeout=5)


def _handler(kind: str) -> JobHandler:
    return handler_for(kind)


def execute_job(
    job_id: int,
    *,
    task_id: str = "",
    transient: tuple[type[BaseException], ...] = (),
    heartbeat: bool | None = None,
) -> str:
    """Run one attempt of a job. Returns what happened: skipped, busy, done, failed or superseded.

    Exceptions listed in ``transient`` release the job and propagate (the task retries them);
    every other exception fails the job with a message. ``heartbeat`` (default: unless tasks run
    eagerly inside the request) keeps ``heartbeat_at`` fresh from a second thread while it runs.
    """
    if not connection.in_atomic_block:  # a worker's stale connection; never one a caller is using
        close_old_connections()
    run = claim_job(job_id, task_id)
    if run is None:
        return "skipped"
    if not isinstance(run, JobRun):
        return BUSY
    job = Job.objects.get(pk=job_id)
    if heartbeat is None:
        heartbeat = not settings.CELERY_TASK_ALWAYS_EAGER
    beat = _Heartbeat(run) if heartbeat else None
    if beat:
        beat.start()
    try:
        _handler(job.kind)(job, run)
        return "done"
    except SupersededError:
        run.discard_files()
        logger.info("job %s attempt superseded; its files were discarded", job_id)
        return "superseded"
    except transient:
        run.discard_files()
        if not connection.in_atomic_block:  # the connection that failed stays broken: open a new one
            with contextlib.suppress(Exception):
                connection.close()
        with contextlib.suppress(Exception):
            release_job(run)  # queued again at once, so that the task's retry can claim it
        raise
    except Exception as exc:
        run.discard_files()
        phase = ""
        with contextlib.suppress(Exception):  # the database may be what failed
            phase = Job.objects.filter(pk=job_id).values_list("phase", flat=True).first() or ""
        reason = _reason(exc, phase)
        logger.exception("job %s failed: %s", job_id, reason)  # the traceback stays in the log
        fail_job(run, reason)
        return "failed"
    finally:
        if beat:
            beat.stop()


def _reason(exc: Exception, phase: str = "") -> str:
    """What went wrong, in a sentence for the person who asked for the job: no traceback, no source path.

    Errors raised on purpose (:class:`JobFailedError`, ``ValueError`` from option and input checks)
    carry their own sentence; anything else is an internal fault, described by what it is and when
    it happened (the traceback goes to the worker's log, see :func:`execute_job`).
    """
    from celery.exceptions import SoftTimeLimitExceeded

    during = f" during the {phase!r} phase" if phase else ""
    if isinstance(exc, SoftTimeLimitExceeded):
        return f"stopped at the time limit of {settings.CELERY_TASK_SOFT_TIME_LIMIT} s (GCPS_TASK_SOFT_TIME_LIMIT)"
    if isinstance(exc, JobFailedError | ValueError) and _is_plain_sentence(str(exc)):
        return str(exc)
    if isinstance(exc, MemoryError):
        return (
            f"the worker ran out of memory{during}; try a smaller frame or fewer images, or a worker with more memory"
        )
    if isinstance(exc, ImportError):
        return (
            "internal error: a part of the measurement software is missing on the worker; the worker's log has details"
        )
    return (
        f"internal error{during}: the job stopped on an unexpected {type(exc).__name__}; "
        "it has been logged on the worker"
    )


def _is_plain_sentence(text: str) -> bool:
    """True for a message a person can read: not empty, no traceback, no source file path."""
    return bool(text) and len(text) <= 2000 and not _INTERNALS.search(text)


_INTERNALS = re.compile(
    r"Traceback \(most recent call last\)|site-packages|dist-packages"  # a traceback, a library
    r"|File \"[^\"]+\", line \d+|/[\w./-]+\.(py|pyx|so)\b"  # a source location
)


# ----------------------------------------------------------------------------- dead workers


def sweep_stale_jobs() -> dict[str, int]:
    """Requeue (or fail, past the attempt limit) running jobs whose heartbeat went stale.

    Part of :func:`sweep_jobs`. Returns counts.
    """
    now = timezone.now()
    cutoff = now - timedelta(seconds=settings.GCPS_JOB_STALE_SECONDS)
    counts = {"requeued": 0, "failed": 0}
    stale_ids = list(
        Job.objects.filter(status=Job.Status.RUNNING, heartbeat_at__lt=cutoff).values_list("pk", flat=True)
    )
    for job_id in stale_ids:
        with transaction.atomic():
            job = Job.objects.select_for_update().get(pk=job_id)
            if job.status != Job.Status.RUNNING or not _is_stale(job, timezone.now()):
                continue
            if job.attempts >= settings.GCPS_JOB_MAX_ATTEMPTS:
                _fail(
                    job,
                    f"the worker stopped responding (no heartbeat since {job.heartbeat_at:%Y-%m-%d %H:%M:%S} UTC) "
                    f"after {job.attempts} attempts",
                )
                counts["failed"] += 1
            else:
                job.status = Job.Status.QUEUED
                job.run_token = None
                job.phase = "requeued: its worker stopped responding"
                job.save()
                enqueue_job(job, recovered=True)
                counts["requeued"] += 1
    if any(counts.values()):
        logger.warning("stale job sweep: %s", counts)
    return counts


RESEND_SCAN_LIMIT = 10000
"""Most waiting jobs whose delivery markers one sweep reads (oldest first)."""


def resend_unclaimed_jobs() -> dict[str, int]:
    """Send again the jobs whose message was lost: queued for longer than ``GCPS_JOB_RESEND_SECONDS``
    without being claimed, and without a message waiting in the broker.

    The job row is the source of truth: a message lost by the broker (Redis restarted without
    persistence, a send that failed after commit) leaves its job queued, and this sends it again,
    to the head of the queue. A job that merely waits behind a backlog still has its delivery
    marker (:mod:`metrology.jobs.delivery`) and is left alone, so a backlog is not sent again every
    ``GCPS_JOB_RESEND_SECONDS``. Without markers (no Redis broker, Redis unreachable) every such job
    is sent again. Idempotent: should the first message still exist, the job is claimed once
    (:func:`claim_job`) and the other message finds it running or done and is dropped. Returns
    ``{"resent": n, "waiting": m}`` (``m``: jobs left alone, their message still in the broker).
    """
    cutoff = timezone.now() - timedelta(seconds=settings.GCPS_JOB_RESEND_SECONDS)
    waiting = Q(enqueued_at__lt=cutoff)  # jobs never enqueued (acquisitions, run by an agent) stay out
    candidates = list(
        Job.objects.filter(waiting, status=Job.Status.QUEUED)
        .order_by("enqueued_at", "pk")
        .values_list("pk", flat=True)[:RESEND_SCAN_LIMIT]
    )
    in_broker = delivery.waiting_in_broker(candidates) if candidates else set()
    lost = [job_id for job_id in candidates if in_broker is None or job_id not in in_broker]
    resent = 0
    with transaction.atomic():
        # skip_locked: another worker's sweep may be resending the same rows right now
        jobs = Job.objects.select_for_update(skip_locked=True).filter(
            waiting, status=Job.Status.QUEUED, pk__in=lost[:500]
        )
        for job in jobs.order_by("enqueued_at", "pk"):
            enqueue_job(job, recovered=True)
            resent += 1
    if resent:
        logger.warning(
            "job sweep: sent %d queued job(s) again (unclaimed for %d s, no message in the broker)",
            resent,
            settings.GCPS_JOB_RESEND_SECONDS,
        )
    return {"resent": resent, "waiting": len(candidates) - len(lost)}


def sweep_jobs() -> dict[str, int]:
    """The periodic job sweep: take over jobs of dead workers and resend lost messages.

    Run by every worker on a timer (:class:`metrology.jobs.sweeper.PeriodicSweep`), by beat when it
    runs, and once when a worker starts. Returns ``{"requeued", "failed", "resent", "waiting"}`` counts
    and those of the sweeps the apps registered (:func:`metrology.jobs.handlers.register_sweep`).
    """
    counts = sweep_stale_jobs()
    counts.update(resend_unclaimed_jobs())
    for sweep in registered_sweeps():  # the apps' own (acquisitions no agent took: expired)
        counts.update(sweep())
    return counts
