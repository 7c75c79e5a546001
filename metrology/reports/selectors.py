"""Reads for reports, scoped to the user, and what a report is compared against."""

from __future__ import annotations

import datetime
import json
from zoneinfo import ZoneInfo

from celery.schedules import crontab as celery_crontab
from django.db.models import QuerySet
from django.http import Http404
from django.utils import timezone
from django_celery_beat.models import CrontabSchedule, PeriodicTask

from metrology.captures.models import Capture, CaptureSession
from metrology.jobs.models import Job
from metrology.reports.models import Report
from metrology.rigs.models import Rig

REPORT_TASK = "metrology.reports.tasks.scheduled_characterization_report"
"""The Celery task that a report schedule (a django-celery-beat ``PeriodicTask``) runs."""

CRONTAB_FIELDS = ("minute", "hour", "day_of_month", "month_of_year", "day_of_week")


def reports_for(user) -> QuerySet[Report]:
    """The user's reports, newest first."""
    return Report.objects.filter(owner=user).select_related("rig", "job", "characterization")


def get_report(user, report_id) -> Report:
    report = reports_for(user).filter(pk=report_id).first() if str(report_id).isdigit() else None
    if report is None:
        raise Http404(f"No report {report_id} among yours.")
    return report


def previous_report(report: Report) -> Report | None:
    """The rig's latest finished report requested before ``report`` (what drift is measured against)."""
    return (
        Report.objects.filter(rig_id=report.rig_id, job__status=Job.Status.DONE, pk__lt=report.pk)
        .exclude(html="")
        .order_by("-pk")
        .first()
    )


def unfinished_report(rig: Rig) -> Report | None:
    """A report of ``rig`` still queued or running, if any."""
    return Report.objects.filter(rig=rig, job__status__in=(Job.Status.QUEUED, Job.Status.RUNNING)).first()


def latest_uploaded_stage_session(rig: Rig) -> CaptureSession | None:
    """The newest session of ``rig`` holding stored, uploaded stage captures (a real stage series)."""
    capture = (
        Capture.objects.filter(rig=rig, role=Capture.Role.STAGE, source=Capture.Source.UPLOAD)
        .exclude(file="")
        .select_related("session")
        .order_by("-session_id", "-id")
        .first()
    )
    return capture.session if capture else None


def reference_for_session(session: CaptureSession) -> Capture | None:
    """A stored reference capture for a stage series: the session's own, else the rig's newest."""
    stored = Capture.objects.filter(rig_id=session.rig_id, role=Capture.Role.REFERENCE).exclude(file="")
    return stored.filter(session=session).order_by("-id").first() or stored.order_by("-id").first()


def report_schedules(user) -> list[dict]:
    """The user's scheduled reports, one dict per schedule.

    ``task`` (the PeriodicTask), ``rig``, ``when`` (crontab or interval in words), ``source``,
    ``options`` (what the report will be asked for) and ``next_run`` (None when disabled).
    """
    tasks = PeriodicTask.objects.filter(task=REPORT_TASK).select_related("interval", "crontab")
    rigs = {rig.pk: rig for rig in Rig.objects.filter(owner=user)}
    schedules = []
    for task in tasks:
        try:
            kwargs = json.loads(task.kwargs or "{}")
        except ValueError:
            continue
        rig_id = kwargs.get("rig_id") if isinstance(kwargs, dict) else None
        if rig_id in rigs:
            schedules.append(
                {
                    "task": task,
                    "rig": rigs[rig_id],
                    "when": when_text(task),
                    "source": kwargs.get("source", "auto"),
                    "options": kwargs.get("options") or {},
                    "next_run": next_run_at(task),
                }
            )
    return schedules


def report_schedule(user, rig: Rig) -> dict | None:
    """The schedule of ``rig`` (one of the user's), as in :func:`report_schedules`, or None."""
    return next((item for item in report_schedules(user) if item["rig"].pk == rig.pk), None)


def crontab_text(schedule: CrontabSchedule) -> str:
    """``"30 6 * * * (UTC)"``: the five fields as typed, and the time zone they are read in."""
    fields = (schedule.minute, schedule.hour, schedule.day_of_month, schedule.month_of_year, schedule.day_of_week)
    return f"{' '.join(fields)} ({schedule.timezone})"


def when_text(task: PeriodicTask) -> str:
    """A schedule in words: its crontab, or "every N s"."""
    if task.crontab is not None:
        return crontab_text(task.crontab)
    if task.interval is not None:
        return f"every {task.interval.every} {task.interval.period}"
    return "no schedule"


def next_run_at(task: PeriodicTask, now: datetime.datetime | None = None) -> datetime.datetime | None:
    """When beat will next send ``task`` (None when disabled or unscheduled); never before ``now``.

    A crontab fires at its next matching minute after ``now`` (in the schedule's time zone); an
    interval ``every`` after its last run, or at once when it never ran (beat runs a new interval
    schedule on its first tick).
    """
    now = now or timezone.now()
    if not task.enabled:
        return None
    if task.crontab is not None:
        zone = ZoneInfo(str(task.crontab.timezone))
        local_now = now.astimezone(zone)
        values = {name: getattr(task.crontab, name) for name in CRONTAB_FIELDS}
        cron = celery_crontab(**values, nowfun=lambda: local_now)
        return (local_now + cron.remaining_estimate(local_now)).astimezone(now.tzinfo)
    if task.interval is not None:
        if task.last_run_at is None:
            return now
        every = datetime.timedelta(**{str(task.interval.period): task.interval.every})
        return max(now, task.last_run_at + every)
    return None
