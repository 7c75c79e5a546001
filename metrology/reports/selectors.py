"""Reads for reports, scoped to the user, and what a report is compared against."""

from __future__ import annotations

import json

from django.db.models import QuerySet
from django.http import Http404
from django_celery_beat.models import PeriodicTask

from metrology.captures.models import Capture, CaptureSession
from metrology.jobs.models import Job
from metrology.reports.models import Report
from metrology.rigs.models import Rig

REPORT_TASK = "metrology.reports.tasks.scheduled_characterization_report"


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
    from metrology.reports.schedules import next_run_at, when_text  # schedules reads REPORT_TASK from here

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
