"""Celery tasks of the reports: what beat runs from a report schedule (a django-celery-beat PeriodicTask).

The task only requests the report (a queued job, at most one pending per rig); the work itself is
the generic ``run_job`` (metrology/jobs/tasks.py) with its retries, heartbeats and progress on the Job record.
"""

from __future__ import annotations

from celery import shared_task

from metrology.jobs.tasks import RETRY_ON_TRANSIENT_ERRORS


@shared_task(
    name="metrology.reports.tasks.scheduled_characterization_report",
    **RETRY_ON_TRANSIENT_ERRORS,
    soft_time_limit=60,
    time_limit=90,
    ignore_result=True,
)
def scheduled_characterization_report(rig_id: int, source: str = "auto", options: dict | None = None) -> int | None:
    """Request a characterization report of rig ``rig_id``; returns its id, or None when one is pending."""
    from metrology.reports.services import request_scheduled_report

    report = request_scheduled_report(rig_id=int(rig_id), source=source, options=options or {})
    return report.pk if report else None
