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
worker has taken them (:func:`metrology.reports.subjobs.complete_jobs`): a single worker cannot
deadlock waiting on itself, and more workers share the captures. Each step records what it made on
the report row, so a retried attempt picks up where the last one stopped.

This module requests and runs reports; the other concerns live beside it and are re-exported here
under their old names (``from metrology.reports.services import schedule_report`` keeps working):

- :mod:`metrology.reports.options` -- option checks, stage positions, the source;
- :mod:`metrology.reports.schedules` -- the beat schedules (``PeriodicTask`` rows);
- :mod:`metrology.reports.subjobs` -- waiting on the captures' and characterization's jobs;
- :mod:`metrology.reports.summary` -- the report's figures as JSON, with their uncertainties;
- :mod:`metrology.reports.drift` -- the comparison with the previous report;
- :mod:`metrology.reports.rendering` -- the self-contained HTML.
"""

from __future__ import annotations

import uuid
from typing import Any

from django.core.files.base import ContentFile
from django.core.files.storage import default_storage
from django.db import transaction

from metrology.captures.models import Capture
from metrology.captures.services import request_simulated_capture
from metrology.characterizations.models import Characterization
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.reports.drift import DRIFT_FIGURES, UNITS, compute_drift
from metrology.reports.models import Report
from metrology.reports.options import (
    MAX_STAGE_CAPTURES,
    SOURCES,
    TOLERANCE_KINDS,
    VIRTUAL_STAGE_DEFAULTS,
    check_options,
    resolve_source,
    stage_positions,
)
from metrology.reports.rendering import SUMMARY_DRIFT_KEYS, render_report_html
from metrology.reports.schedules import schedule_name, schedule_report, unschedule_report
from metrology.reports.selectors import (
    latest_uploaded_stage_session,
    previous_report,
    reference_for_session,
    unfinished_report,
)
from metrology.reports.subjobs import complete_jobs
from metrology.reports.summary import build_summary
from metrology.rigs.models import Rig

__all__ = [
    "DRIFT_FIGURES",
    "MAX_STAGE_CAPTURES",
    "SOURCES",
    "SUMMARY_DRIFT_KEYS",
    "TOLERANCE_KINDS",
    "UNITS",
    "VIRTUAL_STAGE_DEFAULTS",
    "build_summary",
    "check_options",
    "complete_jobs",
    "compute_drift",
    "render_report_html",
    "request_report",
    "request_scheduled_report",
    "resolve_source",
    "run_characterization_report",
    "run_report",
    "schedule_name",
    "schedule_report",
    "stage_positions",
    "unschedule_report",
]


# ----------------------------------------------------------------------------- requesting


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
    complete_jobs([report.job_id], run=None, timeout_s=timeout_s)
    report.refresh_from_db()
    report.job.refresh_from_db()
    return report


# ----------------------------------------------------------------------------- running


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
    session_id = report.session_id
    with transaction.atomic():
        if session_id is None:
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
            session_id = session.pk
    captures = list(Capture.objects.filter(session_id=session_id).order_by("id"))
    job_ids = [capture.job_id for capture in captures if capture.job_id and not capture.file]
    complete_jobs(job_ids, run=run, progress=(5, 55), label="simulated captures")
    reference = next(capture for capture in captures if capture.role == Capture.Role.REFERENCE)
    return session_id, reference.pk


def run_report(job: Job, run: job_services.JobRun) -> None:
    """Job handler: stage series -> characterization -> HTML report with summary and drift."""
    from metrology.characterizations.services import request_characterization

    report = Report.objects.select_related("rig", "owner", "characterization").get(job=job)
    with run.phase("stage series", 2):
        if report.characterization_id is None:
            if report.source == Report.Source.VIRTUAL_STAGE:
                session_id, reference_id = _virtual_series(report, run)
            elif report.session_id is None:  # the uploaded series' session was deleted since (SET_NULL)
                raise job_services.JobFailedError("cannot characterize the stage series: its session was deleted")
            else:
                session_id, reference_id = report.session_id, report.parameters["reference"]
            try:
                with transaction.atomic():
                    characterization = request_characterization(
                        owner=report.owner, rig=report.rig, reference_id=reference_id, session_id=session_id
                    )
                    Report.objects.filter(pk=report.pk).update(characterization=characterization)
            except BadInput as exc:
                raise job_services.JobFailedError(f"cannot characterize the stage series: {exc}") from None
            report.characterization = characterization
    with run.phase("characterization", 56):
        requested = report.characterization
        assert requested is not None, "set by the stage-series phase (or by an earlier attempt of this job)"
        complete_jobs([requested.job_id], run=run, progress=(56, 90), label="characterization")
        characterization = Characterization.objects.select_related("job").get(pk=requested.pk)
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
