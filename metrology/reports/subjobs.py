"""A job that waits on other jobs: run them here unless a worker has them, then poll until all are done.

A report job needs its simulated captures and its characterization (each a job of its own) to
finish. Running each one here first means a single worker cannot deadlock waiting on itself;
more workers share the work, and a job whose worker died is taken over while waiting.
"""

from __future__ import annotations

import time

from django.conf import settings

from metrology.jobs import services as job_services
from metrology.jobs.models import Job


def complete_jobs(
    job_ids: list[int],
    *,
    run: job_services.JobRun | None,
    progress: tuple[int, int] = (0, 100),
    label: str = "jobs",
    timeout_s: float | None = None,
) -> None:
    """Run the jobs here unless a worker already has them, then wait until all are done.

    Raises :class:`JobFailedError` naming the first failed job.
    """
    start, end = progress
    n = len(job_ids)
    limit = timeout_s if timeout_s is not None else float(settings.CELERY_TASK_SOFT_TIME_LIMIT)
    deadline = time.monotonic() + limit
    for index, job_id in enumerate(job_ids):
        if run is not None:
            run.progress(start + (end - start) * index // max(n, 1), f"{label} {index + 1}/{n}")
        job_services.execute_job(job_id)
    while True:
        jobs = list(Job.objects.filter(pk__in=job_ids).only("id", "status", "error"))
        failed = [job for job in jobs if job.status == Job.Status.FAILED]
        if failed:
            raise job_services.JobFailedError(f"{label}: job {failed[0].pk} failed: {failed[0].error}")
        pending = [job.pk for job in jobs if job.status != Job.Status.DONE]
        if not pending:
            return
        if time.monotonic() > deadline:
            raise job_services.JobFailedError(f"{label}: jobs {pending} not done after {limit:.0f} s")
        if run is not None:
            run.progress(start + (end - start) * (n - len(pending)) // max(n, 1), f"{label}: waiting")
        time.sleep(0.5)
        for job_id in pending:  # take over a job whose worker died, or one nobody took yet
            job_services.execute_job(job_id)
