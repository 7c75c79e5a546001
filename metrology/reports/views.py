"""Report pages: the user's reports, one report (with its HTML embedded), the HTML itself and its download.

Thin: parse, call a selector or service, answer. Another user's report is a 404.
"""

from __future__ import annotations

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import FileResponse, Http404, HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.clickjacking import xframe_options_sameorigin
from django.views.decorators.http import require_GET, require_POST

from metrology.errors import BadInput
from metrology.reports import selectors, services
from metrology.reports.selectors import when_text
from metrology.rigs.selectors import get_rig, rigs_for


def _list_page(request: HttpRequest, *, schedule_form: dict | None = None, error: str = "", status: int = 200):
    context = {
        "reports": list(selectors.reports_for(request.user)[:200]),
        "schedules": selectors.report_schedules(request.user),
        "rigs": list(rigs_for(request.user)),
        "schedule_form": schedule_form or {"crontab": "0 6 * * *", "source": "auto"},
        "schedule_error": error,
        "beat_in_process": bool(settings.CELERY_TASK_ALWAYS_EAGER),
        "time_zone": settings.TIME_ZONE,
    }
    return render(request, "reports/list.html", context, status=status)


@login_required
@require_GET
def report_list(request: HttpRequest) -> HttpResponse:
    return _list_page(request)


@login_required
@require_GET
def report_detail(request: HttpRequest, report_id: int) -> HttpResponse:
    report = selectors.get_report(request.user, report_id)
    return render(request, "reports/detail.html", {"report": report, "job": report.job})


def _html_file(request: HttpRequest, report_id: int):
    report = selectors.get_report(request.user, report_id)
    if not report.html:
        raise Http404(f"Report {report_id} has no HTML yet (its job is {report.job.status}).")
    return report, report.html.open("rb")


@login_required
@require_GET
@xframe_options_sameorigin
def report_html(request: HttpRequest, report_id: int) -> FileResponse:
    """The report itself, shown in the browser (and embedded in the detail page)."""
    _report, handle = _html_file(request, report_id)
    return FileResponse(handle, content_type="text/html; charset=utf-8")


@login_required
@require_GET
def report_download(request: HttpRequest, report_id: int) -> FileResponse:
    """The report as a self-contained HTML file to keep or mail."""
    report, handle = _html_file(request, report_id)
    filename = f"gcps-characterization-report-{report.pk}-rig-{report.rig_id}.html"
    return FileResponse(handle, as_attachment=True, filename=filename, content_type="text/html; charset=utf-8")


@login_required
@require_POST
def report_run(request: HttpRequest) -> HttpResponse:
    """Request a report of one of the user's rigs now (the job runs on a worker, or in-process)."""
    rig = get_rig(request.user, request.POST.get("rig", ""))
    try:
        report = services.request_report(rig=rig, owner=request.user, source=request.POST.get("source", "auto"))
    except BadInput as exc:
        messages.error(request, str(exc))
        return redirect("reports:list")
    return redirect("reports:detail", report_id=report.pk)


@login_required
@require_POST
def report_schedule(request: HttpRequest) -> HttpResponse:
    """Create or replace the report schedule of one of the user's rigs from a crontab."""
    rig = get_rig(request.user, request.POST.get("rig", ""))
    form = {key: request.POST.get(key, "").strip() for key in ("rig", "crontab", "source")}
    try:
        task = services.schedule_report(rig, crontab=form["crontab"], source=form["source"] or "auto")
    except BadInput as exc:
        return _list_page(request, schedule_form=form, error=str(exc), status=400)
    messages.success(request, f"Report of {rig} scheduled: {when_text(task)}.")
    return redirect("reports:list")


def _schedule_of(request: HttpRequest, rig_id: int) -> dict:
    schedule = selectors.report_schedule(request.user, get_rig(request.user, rig_id))
    if schedule is None:
        raise Http404(f"Rig {rig_id} has no report schedule.")
    return schedule


@login_required
@require_POST
def report_schedule_run(request: HttpRequest, rig_id: int) -> HttpResponse:
    """Run a schedule now, through the same request beat sends (at most one pending report per rig)."""
    schedule = _schedule_of(request, rig_id)
    try:
        report = services.request_scheduled_report(
            rig_id=schedule["rig"].pk, source=schedule["source"], options=schedule["options"]
        )
    except BadInput as exc:
        messages.error(request, str(exc))
        return redirect("reports:list")
    if report is None:
        messages.info(request, f"A report of {schedule['rig']} is already queued or running.")
        return redirect("reports:list")
    return redirect("reports:detail", report_id=report.pk)


@login_required
@require_POST
def report_schedule_delete(request: HttpRequest, rig_id: int) -> HttpResponse:
    schedule = _schedule_of(request, rig_id)
    services.unschedule_report(schedule["rig"])
    messages.success(request, f"The report schedule of {schedule['rig']} was removed.")
    return redirect("reports:list")
