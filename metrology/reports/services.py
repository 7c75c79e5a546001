"""Writes for characterization reports: request one, run it (a job), schedule it with Celery beat.

A report job (``Job.Kind.REPORT``, handler :func:`run_report`) does three steps, each through the
existing services so nothing is computed twice or differently:

1. the stage series: for a *virtual stage* it asks the capture service for a simulated reference
   and stage captures (:func:`metrology.captures.services.request_simulated_capture`); for an
   *uploaded series* it takes the rig's newest session of uploaded stage captures;
2. the characterization (:func:`metrology.characterizations.services.request_characterization`);
3. the self-contained HTML (plotly.js inlined, no network needed to open it), its summary and its
   drift against the rig's previous report, stored under an attempt-specific name and published
   with the job's commit (so a half-written report is never visible).

The sub-jobs of steps 1 and 2 are queued like any other job and also run right here when no other
worker has taken them (:func:`_complete_jobs`): a single worker cannot deadlock waiting on itself,
and more workers share the captures. Each step records what it made on the report row, so a
retried attempt picks up where the last one stopped.
"""

from __future__ import annotations

import json
import math
import time
import uuid
from typing import Any

from django.conf import settings
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage
from django.db import transaction
from django.template.loader import render_to_string
from django.utils import timezone
from django_celery_beat.models import CrontabSchedule, IntervalSchedule, PeriodicTask

from metrology.api_errors import BadInput
from metrology.captures.models import Capture
from metrology.captures.services import request_simulated_capture
from metrology.characterizations.models import Characterization
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.reports.models import Report
from metrology.reports.selectors import (
    REPORT_TASK,
    latest_uploaded_stage_session,
    previous_report,
    reference_for_session,
    unfinished_report,
)
from metrology.rigs.models import Rig
from metrology.version import software_version

SOURCES = ("auto", Report.Source.VIRTUAL_STAGE, Report.Source.UPLOADED_SERIES)

# The virtual stage: a reduced version of the paper's section 5 series, with a realistic 8-bit camera.
VIRTUAL_STAGE_DEFAULTS: dict[str, Any] = {
    "z_start_mm": 0.0,
    "z_stop_mm": 80.0,
    "z_step_mm": 8.0,
    "repeats": 2,
    "bit_depth": 8,
    "noise_grey": 1.5,
    "camera_defocus_px": 0.5,
    "seed": None,  # None: derived from the report's id, so successive reports see fresh noise
}
MAX_STAGE_CAPTURES = 400
TOLERANCE_KINDS = ("mm", "pct_fs", "slope")

# Overall figures compared between reports: (key in results["overall"], label, tolerance kind).
DRIFT_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("mean_error_mm", "Overall mean error", "mm"),
    ("std_error_mm", "Overall standard deviation of the error", "mm"),
    ("rms_error_mm", "Overall RMS error", "mm"),
    ("error_pct_fs", "RMS error, % of full scale", "pct_fs"),
    ("max_abs_mean_error_mm", "Largest |mean error| over the positions", "mm"),
    ("max_abs_slope_deviation", "Largest |slope - 1| over the test points", "slope"),
)


# ----------------------------------------------------------------------------- requesting


def _number(name: str, value: Any, *, integer: bool = False, minimum: float | None = None) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise BadInput(f"options.{name} must be a finite number, got {value!r}")
    if integer and not float(value).is_integer():
        raise BadInput(f"options.{name} must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise BadInput(f"options.{name} must be at least {minimum:g}, got {value!r}")
    return int(value) if integer else float(value)


def check_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """Virtual-stage options and drift tolerances, validated and completed with the defaults.

    Raises
    ------
    BadInput
        Naming the option and the value.
    """
    options = dict(options or {})
    tolerances = options.pop("tolerances", None) or {}
    unknown = sorted(set(options) - set(VIRTUAL_STAGE_DEFAULTS))
    if unknown:
        raise BadInput(
            f"options: unknown option(s) {', '.join(unknown)}; accepted: "
            f"{', '.join([*VIRTUAL_STAGE_DEFAULTS, 'tolerances'])}"
        )
    checked = {**VIRTUAL_STAGE_DEFAULTS, **options}
    for name in ("z_start_mm", "z_stop_mm"):
        checked[name] = _number(name, checked[name])
    checked["z_step_mm"] = _number("z_step_mm", checked["z_step_mm"])
    if checked["z_step_mm"] <= 0:
        raise BadInput(f"options.z_step_mm must be positive, got {checked['z_step_mm']}")
    checked["repeats"] = _number("repeats", checked["repeats"], integer=True, minimum=1)
    if checked["bit_depth"] not in (8, 16):
        raise BadInput(f"options.bit_depth must be 8 or 16, got {checked['bit_depth']!r}")
    checked["noise_grey"] = _number("noise_grey", checked["noise_grey"], minimum=0)
    checked["camera_defocus_px"] = _number("camera_defocus_px", checked["camera_defocus_px"], minimum=0)
    if checked["seed"] is not None:
        checked["seed"] = _number("seed", checked["seed"], integer=True, minimum=0)
    positions = stage_positions(checked)
    if len(positions) < 2:
        raise BadInput(
            f"options: the stage range {checked['z_start_mm']:g} to {checked['z_stop_mm']:g} mm in steps of "
            f"{checked['z_step_mm']:g} mm gives {len(positions)} position(s); a characterization needs two or more"
        )
    if len(positions) * checked["repeats"] > MAX_STAGE_CAPTURES:
        raise BadInput(
            f"options: {len(positions)} positions x {checked['repeats']} repeats exceeds {MAX_STAGE_CAPTURES} captures"
        )
    if not isinstance(tolerances, dict):
        raise BadInput(f"options.tolerances must be an object like {{'mm': 0.01}}, got {tolerances!r}")
    bad = sorted(set(tolerances) - set(TOLERANCE_KINDS))
    if bad:
        raise BadInput(f"options.tolerances: unknown kind(s) {', '.join(bad)}; accepted: {', '.join(TOLERANCE_KINDS)}")
    checked["tolerances"] = {
        **settings.GCPS_REPORT_DRIFT_TOLERANCE,
        **{kind: _number(f"tolerances.{kind}", value, minimum=0) for kind, value in tolerances.items()},
    }
    return checked


def stage_positions(options: dict[str, Any]) -> list[float]:
    """Stage positions Z_in (mm) from ``z_start_mm`` to ``z_stop_mm`` inclusive, every ``z_step_mm``."""
    from metrology.core.simulate import stage_positions as positions

    start, stop, step = options["z_start_mm"], options["z_stop_mm"], options["z_step_mm"]
    if stop < start:
        return []
    if (stop - start) / step > MAX_STAGE_CAPTURES:
        return positions(start, start + MAX_STAGE_CAPTURES * step, step)  # too many: the caller refuses
    return positions(start, stop, step)


def resolve_source(rig: Rig, source: str) -> str:
    """``auto`` becomes an uploaded series when the rig has one, else the virtual stage."""
    if source not in SOURCES:
        raise BadInput(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    if source == "auto":
        has_series = latest_uploaded_stage_session(rig) is not None
        return Report.Source.UPLOADED_SERIES if has_series else Report.Source.VIRTUAL_STAGE
    return source


@transaction.atomic
def request_report(*, rig: Rig, owner=None, source: str = "auto", options: dict[str, Any] | None = None) -> Report:
    """Create a report of ``rig`` with its queued job (the job runs :func:`run_report`).

    Parameters
    ----------
    rig : Rig
        The rig to characterize; the report belongs to ``owner`` (default: the rig's owner).
    source : {"auto", "virtual_stage", "uploaded_series"}
        Where the stage series comes from; ``auto`` takes the rig's newest uploaded stage series
        when there is one, else simulates the virtual stage.
    options : dict, optional
        Virtual stage: ``z_start_mm``, ``z_stop_mm``, ``z_step_mm`` (default 0 to 80 every 8 mm),
        ``repeats`` (2), ``bit_depth`` (8), ``noise_grey`` (1.5 grey levels), ``camera_defocus_px``
        (0.5), ``seed``; and ``tolerances`` ``{"mm", "pct_fs", "slope"}`` for the drift (defaults
        from ``GCPS_REPORT_DRIFT_TOLERANCE``).

    Raises
    ------
    BadInput
        A bad option or source, or no uploaded stage series (with a stored reference) to report on.
    """
    owner = owner or rig.owner
    if rig.owner_id != owner.pk:
        raise BadInput(f"rig {rig.pk} does not exist among yours")
    source = resolve_source(rig, source)
    parameters = check_options(options)
    session = None
    if source == Report.Source.UPLOADED_SERIES:
        session = latest_uploaded_stage_session(rig)
        if session is None:
            raise BadInput(
                f"rig {rig.pk} has no uploaded stage captures; upload a stage series (role 'stage' with z_in_mm) "
                "or use the virtual stage"
            )
        reference = reference_for_session(session)
        if reference is None:
            raise BadInput(f"rig {rig.pk} has no stored reference capture to measure its stage series against")
        parameters["reference"] = reference.pk
    job = job_services.create_job(
        owner=owner, kind=Job.Kind.REPORT, parameters={"rig": rig.pk, "source": source, "options": parameters}
    )
    report = Report.objects.create(owner=owner, rig=rig, source=source, parameters=parameters, session=session, job=job)
    job.parameters["report"] = report.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return report


@transaction.atomic
def request_scheduled_report(*, rig_id: int, source: str = "auto", options: dict[str, Any] | None = None):
    """What beat runs: a report of the rig unless one is already queued or running (then ``None``).

    Beat messages may arrive twice (``acks_late``) or faster than reports finish; the rig row is
    locked while checking, so at most one report per rig is pending at any time.
    """
    rig = Rig.objects.select_for_update().filter(pk=rig_id).first()
    if rig is None:
        return None
    if unfinished_report(rig) is not None:
        return None
    return request_report(rig=rig, source=source, options=options)


def run_characterization_report(
    rig: Rig, *, owner=None, source: str = "auto", options: dict[str, Any] | None = None, timeout_s: float = 1800.0
) -> Report:
    """Request a report and see it through in this process (or wait for the worker that took it).

    Returns the report, done or failed (``report.job.status``, ``report.job.error``).
    """
    report = request_report(rig=rig, owner=owner, source=source, options=options)
    _complete_jobs([report.job_id], run=None, timeout_s=timeout_s)
    report.refresh_from_db()
    report.job.refresh_from_db()
    return report


# ----------------------------------------------------------------------------- scheduling


def _crontab(spec: str) -> CrontabSchedule:
    fields = spec.split()
    if len(fields) != 5:
        raise BadInput(f"crontab must have five fields 'minute hour day-of-month month day-of-week', got {spec!r}")
    minute, hour, day_of_month, month_of_year, day_of_week = fields
    schedule, _ = CrontabSchedule.objects.get_or_create(
        minute=minute,
        hour=hour,
        day_of_month=day_of_month,
        month_of_year=month_of_year,
        day_of_week=day_of_week,
        timezone=settings.TIME_ZONE,
    )
    return schedule


def schedule_name(rig: Rig) -> str:
    return f"characterization report of rig {rig.pk}"


@transaction.atomic
def schedule_report(
    rig: Rig,
    *,
    every_s: int | None = None,
    crontab: str | None = None,
    source: str = "auto",
    options: dict[str, Any] | None = None,
    enabled: bool = True,
) -> PeriodicTask:
    """Create or update the rig's report schedule: a django-celery-beat ``PeriodicTask``.

    Give either ``every_s`` (an interval in seconds) or ``crontab`` (``"0 6 * * *"``: every day at
    06:00, in ``TIME_ZONE``). Beat's DatabaseScheduler picks changes up without a restart; the
    schedule can be edited or disabled in the admin (Periodic tasks).
    """
    if (every_s is None) == (crontab is None):
        raise BadInput("give either every_s (seconds) or crontab ('minute hour day month weekday')")
    if source not in SOURCES:
        raise BadInput(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    check_options(options)
    interval = cron = None
    if every_s is not None:
        every = _number("every_s", every_s, integer=True, minimum=1)
        interval, _ = IntervalSchedule.objects.get_or_create(every=every, period=IntervalSchedule.SECONDS)
    else:
        cron = _crontab(str(crontab))
    task, _ = PeriodicTask.objects.update_or_create(
        name=schedule_name(rig),
        defaults={
            "task": REPORT_TASK,
            "kwargs": json.dumps({"rig_id": rig.pk, "source": source, "options": dict(options or {})}),
            "interval": interval,
            "crontab": cron,
            "enabled": enabled,
            "description": f"Characterization report of rig {rig.pk} ({rig.name or 'unnamed'}), source {source}",
        },
    )
    return task


@transaction.atomic
def unschedule_report(rig: Rig) -> bool:
    """Remove the rig's report schedule; ``True`` if there was one."""
    task = PeriodicTask.objects.filter(name=schedule_name(rig)).first()
    if task is None:
        return False
    task.delete()
    return True


# ----------------------------------------------------------------------------- running


def _complete_jobs(
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


def _virtual_series(report: Report, run: job_services.JobRun) -> tuple[int, int]:
    """The simulated reference and stage captures of a virtual-stage report: ``(session_id, reference_id)``."""
    from metrology.captures.services import create_session
    from metrology.core.simulate import series_seed

    options = report.parameters
    rig = report.rig
    seed = options["seed"] if options.get("seed") is not None else 1000 * report.pk
    noise = {
        "bit_depth": options["bit_depth"],
        "noise_grey": options["noise_grey"],
        "camera_defocus_px": options["camera_defocus_px"],
    }
    with transaction.atomic():
        if report.session_id is None:
            session = create_session(
                owner=report.owner, rig=rig, name=f"virtual stage of report {report.pk}", notes="made by a report"
            )

            def simulate(role: str, scene: dict, seed_index: tuple[int, int] | None, **extra) -> Capture:
                return request_simulated_capture(
                    owner=report.owner,
                    rig=rig,
                    role=role,
                    scene=scene,
                    options={**noise, "seed": seed if seed_index is None else series_seed(seed, *seed_index)},
                    session_id=session.pk,
                    **extra,
                )

            simulate("reference", {"name": "reference"}, None)
            for i, z_in in enumerate(stage_positions(options)):
                for repeat in range(options["repeats"]):
                    simulate("stage", {"name": "stage"}, (i, repeat), z_in_mm=z_in, repeat=repeat)
            Report.objects.filter(pk=report.pk).update(session=session)
            report.session = session
    captures = list(Capture.objects.filter(session_id=report.session_id).order_by("id"))
    job_ids = [capture.job_id for capture in captures if capture.job_id and not capture.file]
    _complete_jobs(job_ids, run=run, progress=(5, 55), label="simulated captures")
    reference = next(capture for capture in captures if capture.role == Capture.Role.REFERENCE)
    return report.session_id, reference.pk


def run_report(job: Job, run: job_services.JobRun) -> None:
    """Job handler: stage series -> characterization -> HTML report with summary and drift."""
    from metrology.characterizations.services import request_characterization

    report = Report.objects.select_related("rig", "owner", "characterization").get(job=job)
    with run.phase("stage series", 2):
        if report.characterization_id is None:
            if report.source == Report.Source.VIRTUAL_STAGE:
                session_id, reference_id = _virtual_series(report, run)
            else:
                session_id, reference_id = report.session_id, report.parameters["reference"]
            try:
                with transaction.atomic():
                    characterization = request_characterization(
                        owner=report.owner, rig=report.rig, reference_id=reference_id, session_id=session_id
                    )
                    Report.objects.filter(pk=report.pk).update(characterization=characterization)
            except BadInput as exc:
                raise job_services.JobFailedError(f"cannot characterize the stage series: {exc.detail}") from None
            report.characterization = characterization
    with run.phase("characterization", 56):
        _complete_jobs([report.characterization.job_id], run=run, progress=(56, 90), label="characterization")
        characterization = Characterization.objects.select_related("job").get(pk=report.characterization_id)
    with run.phase("render", 92):
        previous = previous_report(report)
        summary = build_summary(report, characterization)
        drift = compute_drift(previous, summary, report.parameters.get("tolerances") or {})
        html = render_report_html(report, characterization, summary, drift)
        name = f"reports/rig_{report.rig_id}/report_{report.pk}_{uuid.uuid4().hex[:12]}.html"
        stored = run.save_file(default_storage, name, ContentFile(html.encode("utf-8")))

    def publish(_job: Job) -> None:
        Report.objects.filter(pk=report.pk).update(html=stored, summary=summary, drift=drift, previous=previous)

    run.commit(publish)


# ----------------------------------------------------------------------------- summary and drift


def build_summary(report: Report, characterization: Characterization) -> dict[str, Any]:
    """The report's figures as JSON: overall, per position, rig parameters, provenance."""
    results = characterization.results or {}
    positions = {key: list(results.get(key, [])) for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples")}
    return {
        "overall": dict(results.get("overall", {})),
        "positions": positions,
        "edge_sigma_ratio": results.get("edge_sigma_ratio"),
        "repeats": results.get("repeats"),
        "n_test_points": len(results.get("test_points", [])),
        "rig": {"id": report.rig_id, "name": report.rig.name, **characterization.rig_values},
        "source": report.source,
        "characterization": characterization.pk,
        "session": characterization.session_id,
        "software_version": software_version(),
        "generated_at": timezone.now().isoformat(),
    }


def _item(key: str, label: str, kind: str, unit: str, old: Any, new: Any, tolerance: float) -> dict[str, Any]:
    comparable = isinstance(old, int | float) and isinstance(new, int | float)
    change = (new - old) if comparable else None
    return {
        "key": key,
        "label": label,
        "kind": kind,
        "unit": unit,
        "previous": old,
        "current": new,
        "change": change,
        "tolerance": tolerance,
        "beyond": bool(comparable and abs(change) > tolerance),
    }


UNITS = {"mm": "mm", "pct_fs": "% FS", "slope": ""}


def compute_drift(previous: Report | None, summary: dict[str, Any], tolerances: dict[str, float]) -> dict[str, Any]:
    """Changes of the report's figures since ``previous``; ``beyond`` marks moves beyond tolerance.

    Compared: the overall figures of :data:`DRIFT_FIGURES` and the mean error at every stage
    position Z_in found in both reports; the rig parameters that changed are listed too.
    """
    tolerances = {**settings.GCPS_REPORT_DRIFT_TOLERANCE, **(tolerances or {})}
    if previous is None:
        return {"previous": None, "tolerances": tolerances, "items": [], "rig_changes": [], "beyond": 0}
    before = previous.summary or {}
    old_overall, new_overall = before.get("overall", {}), summary.get("overall", {})
    items = [
        _item(f"overall.{key}", label, kind, UNITS[kind], old_overall.get(key), new_overall.get(key), tolerances[kind])
        for key, label, kind in DRIFT_FIGURES
    ]
    old_positions = before.get("positions", {})
    old_by_z = dict(zip(old_positions.get("z_in_mm", []), old_positions.get("mean_error_mm", []), strict=False))
    new_positions = summary.get("positions", {})
    for z_in, error in zip(new_positions.get("z_in_mm", []), new_positions.get("mean_error_mm", []), strict=False):
        if z_in in old_by_z:
            items.append(
                _item(
                    f"positions.mean_error_mm@{z_in:g}",
                    f"Mean error at Z_in = {z_in:g} mm",
                    "mm",
                    "mm",
                    old_by_z[z_in],
                    error,
                    tolerances["mm"],
                )
            )
    old_rig, new_rig = before.get("rig", {}), summary.get("rig", {})
    rig_changes = [
        {"name": name, "previous": old_rig.get(name), "current": new_rig.get(name)}
        for name in ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")
        if old_rig.get(name) != new_rig.get(name)
    ]
    return {
        "previous": previous.pk,
        "previous_created_at": previous.created_at.isoformat(),
        "tolerances": tolerances,
        "items": items,
        "rig_changes": rig_changes,
        "beyond": sum(item["beyond"] for item in items),
    }


# ----------------------------------------------------------------------------- HTML


def _figures_html(results: dict[str, Any]) -> list[dict[str, str]]:
    """Each plotly figure of the characterization as an HTML fragment (no plotly.js: it is inlined once)."""
    from metrology.figures import plot_config
    from metrology.figures.characterization import FIGURE_TITLES, characterization_figures

    fragments = []
    for key, figure in characterization_figures(results).items():
        config = plot_config(f"characterization-{key}", "svg")
        html = figure.to_html(full_html=False, include_plotlyjs=False, config=config, div_id=f"figure-{key}")
        fragments.append({"key": key, "title": FIGURE_TITLES.get(key, key.replace("_", " ")), "html": html})
    return fragments


# Summary rows (by the start of their label) -> the drift item that concerns them.
SUMMARY_DRIFT_KEYS: tuple[tuple[str, str], ...] = (
    ("Mean error (all", "overall.mean_error_mm"),
    ("Variability (standard", "overall.std_error_mm"),
    ("RMS error sqrt", "overall.rms_error_mm"),
    ("RMS error, %", "overall.error_pct_fs"),
    ("Largest |mean error|", "overall.max_abs_mean_error_mm"),
    ("Largest |slope - 1|", "overall.max_abs_slope_deviation"),
)


def _summary_rows(results: dict[str, Any], beyond_keys: set[str]) -> list[dict[str, Any]]:
    """The dashboard's summary table rows, each marked ``beyond`` when its figure drifted."""
    from metrology.figures.characterization import summary_rows

    rows = []
    for label, value in summary_rows(results):
        key = next((key for prefix, key in SUMMARY_DRIFT_KEYS if label.startswith(prefix)), None)
        rows.append({"label": label, "value": value, "key": key, "beyond": key in beyond_keys})
    return rows


def render_report_html(
    report: Report, characterization: Characterization, summary: dict[str, Any], drift: dict[str, Any]
) -> str:
    """The self-contained HTML report: plotly.js inlined, figures, summary, rig, drift, provenance."""
    from plotly.offline import get_plotlyjs

    beyond_keys = {item["key"] for item in drift.get("items", []) if item["beyond"]}
    positions = summary.get("positions", {})
    position_rows = []
    for z_in, mean, std, n in zip(
        positions.get("z_in_mm", []),
        positions.get("mean_error_mm", []),
        positions.get("std_error_mm", []),
        positions.get("n_samples", []),
        strict=False,
    ):
        position_rows.append(
            {
                "z_in_mm": z_in,
                "mean_um": None if mean is None else 1000 * mean,
                "std_um": None if std is None else 1000 * std,
                "n": n,
                "beyond": f"positions.mean_error_mm@{z_in:g}" in beyond_keys,
            }
        )
    changed = {change["name"] for change in drift.get("rig_changes", [])}
    rig_rows = [
        {"name": name, "value": summary["rig"].get(name), "changed": name in changed}
        for name in ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")
    ]
    context = {
        "report": report,
        "characterization": characterization,
        "summary": summary,
        "drift": drift,
        "drift_items": drift.get("items", []),
        "summary_rows": _summary_rows(characterization.results or {}, beyond_keys),
        "position_rows": position_rows,
        "rig_rows": rig_rows,
        "figures": _figures_html(characterization.results or {}),
        "plotly_js": get_plotlyjs(),
        "parameters_json": json.dumps(report.parameters, indent=2, sort_keys=True),
        "generated_at": timezone.now(),
    }
    return render_to_string("reports/report.html", context)
