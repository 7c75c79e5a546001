"""Celery tasks of the jobs: thin, they take ids and call :mod:`metrology.jobs.services`.

Found by the Celery app's autodiscovery (``workers/celery.py``). The registered names are the ones
these tasks had when they lived in ``workers/tasks.py``, so messages already queued and beat entries
keep resolving.
"""

from __future__ import annotations

from celery import shared_task
from celery.signals import task_received, worker_ready, worker_shutdown
from django.conf import settings
from django.db import InterfaceError, OperationalError
from kombu.exceptions import OperationalError as BrokerOperationalError

from metrology.jobs import delivery
from metrology.jobs.services import BUSY, execute_job
from metrology.jobs.services import sweep_jobs as _sweep_jobs
from metrology.jobs.sweeper import PeriodicSweep

# Errors known to be transient: the database or the broker was briefly unreachable.
TRANSIENT_ERRORS: tuple[type[BaseException], ...] = (
    OperationalError,
    InterfaceError,
    ConnectionError,
    BrokerOperationalError,
)


RETRY_ON_TRANSIENT_ERRORS: dict[str, object] = {
    "acks_late": True,
    "reject_on_worker_lost": True,
    "autoretry_for": TRANSIENT_ERRORS,
    "retry_backoff": 5,
    "retry_backoff_max": 120,
    "retry_jitter": True,
    "max_retries": 5,
}
"""Task options shared by every task: redelivered if the worker dies, retried with jittered
exponential back-off (5 s to 2 min, 5 times) when the broker or database blips."""


@shared_task(bind=True, name="workers.tasks.run_job", **RETRY_ON_TRANSIENT_ERRORS)
def run_job(self, job_id: int) -> str:
    """Run (or skip, when already done or taken) the job ``job_id``."""
    outcome = execute_job(job_id, task_id=self.request.id or "", transient=TRANSIENT_ERRORS)
    if outcome == BUSY:
        # This message came back while its job still looks running: the worker that had it died
        # moments ago (prefork child killed, time limit). Look again once the heartbeat is stale.
        raise self.retry(countdown=settings.GCPS_JOB_STALE_SECONDS + 1)
    return outcome


@shared_task(name="workers.tasks.sweep_stale_jobs", acks_late=True, ignore_result=True)
def sweep_stale_jobs() -> dict[str, int]:
    """Requeue or fail jobs whose worker stopped sending heartbeats, and resend queued jobs nobody claimed."""
    return _sweep_jobs()


@task_received.connect
def _message_received(sender: object = None, request: object = None, **_: object) -> None:
    """This worker holds the job's message: its delivery marker names this worker
    (:mod:`metrology.jobs.delivery`), so that should the worker die before running it, the sweep
    sends the job again instead of taking it to be still waiting in the queue."""
    if getattr(request, "name", "") != run_job.name:
        return
    args = getattr(request, "args", None) or ()
    if args and isinstance(args[0], int):
        delivery.mark_received(args[0])


_periodic_sweep: PeriodicSweep | None = None


@worker_ready.connect
def _sweep_on_start(sender: object = None, **_: object) -> None:
    """A fresh worker looks for jobs left by a worker that died, then keeps sweeping on a timer
    (recovery does not depend on beat)."""
    global _periodic_sweep
    sweep_stale_jobs.delay()
    if _periodic_sweep is None:
        _periodic_sweep = PeriodicSweep()
        _periodic_sweep.start()


@worker_shutdown.connect
def _stop_sweeping(sender: object = None, **_: object) -> None:
    global _periodic_sweep
    if _periodic_sweep is not None:
        _periodic_sweep.stop()
        _periodic_sweep = None
