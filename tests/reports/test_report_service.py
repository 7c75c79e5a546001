"""Characterization reports: produced through the capture and characterization services, stored, drift."""

from __future__ import annotations

import datetime
import io
import json
import re
from types import SimpleNamespace

import pytest
from django.core.management import CommandError, call_command
from django.utils import timezone
from django_celery_beat.models import PeriodicTask

from metrology.api_errors import BadInput
from metrology.captures.models import Capture
from metrology.captures.services import create_session, upload_capture
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from metrology.jobs.models import Job
from metrology.reports import services
from metrology.reports.models import Report
from metrology.reports.selectors import REPORT_TASK
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG, render_images, stack_zip
from tests.reports.conftest import QUICK

pytestmark = pytest.mark.django_db(transaction=True)

SCRIPT_SRC = re.compile(r"<script[^>]*\bsrc\s*=", re.IGNORECASE)
FIGURE_KEYS = ("in_out", "error_vs_z", "slope_vs_x", "intercept_vs_x", "sigma_vs_x")


def html_of(report: Report) -> str:
    with report.html.open("rb") as handle:
        return handle.read().decode("utf-8")


def test_virtual_stage_report_is_stored_self_contained_and_summarized(rig, media_root):
    report = services.run_characterization_report(rig, source="virtual_stage", options=QUICK)

    assert report.job.status == Job.Status.DONE, report.job.error
    assert report.source == Report.Source.VIRTUAL_STAGE
    path = media_root / report.html.name
    assert path.is_file() and path.stat().st_size > 1_000_000  # plotly.js alone is megabytes
    html = html_of(report)
    assert "plotly.js v" in html or "plotly.js" in html  # the library's banner, inlined
    assert not SCRIPT_SRC.search(html), "the report must load nothing from a network"
    assert "cdn.plot.ly" not in html.split("</head>")[1]
    assert html.count("Plotly.newPlot") == len(FIGURE_KEYS)
    for key in FIGURE_KEYS:
        assert f'id="figure-{key}"' in html
    assert "First report of this rig" in html

    # The stage series went through the capture and characterization services (and their jobs).
    characterization = report.characterization
    assert characterization.job.status == Job.Status.DONE
    stage = Capture.objects.filter(session=report.session, role=Capture.Role.STAGE)
    assert stage.count() == 3 * 2 and all(capture.file for capture in stage)
    assert sorted({capture.z_in_mm for capture in stage}) == [0.0, 8.0, 16.0]

    summary = report.summary
    assert summary["software_version"].startswith("gcps-lab")
    assert summary["rig"]["L_mm"] == SMALL_RIG["L_mm"] and summary["rig"]["name"] == "bench"
    assert summary["positions"]["z_in_mm"] == [0.0, 8.0, 16.0]
    # 8-bit camera with 1.5 grey levels of noise: tens of micrometres, no bias to speak of.
    assert abs(summary["overall"]["mean_error_mm"]) < 0.02
    assert 0.001 < summary["overall"]["std_error_mm"] < 0.1
    assert report.drift["previous"] is None and report.drift["beyond"] == 0
    # every compared figure carries its standard uncertainty, and the report shows it
    assert summary["uncertainty"] and all(u is not None and u > 0 for u in summary["uncertainty"].values())
    assert "Standard uncertainty (1σ)" in html and "Its standard uncertainty (µm)" in html
    job = report.job
    assert job.progress == 100 and set(job.timings) >= {"stage series", "characterization", "render"}


@pytest.mark.slow
def test_second_report_highlights_the_figures_that_drifted(rig):
    # Over this short 16 mm full scale, 10 um of RMS error is 0.06 % FS: widen that tolerance only.
    options = {**QUICK, "tolerances": {"pct_fs": 0.2}}
    first = services.run_characterization_report(rig, source="virtual_stage", options=options)
    calm = services.run_characterization_report(rig, source="virtual_stage", options=options)
    noisy = services.run_characterization_report(
        rig, source="virtual_stage", options={**options, "noise_grey": 8.0, "camera_defocus_px": 0.0}
    )

    assert calm.previous_id == first.pk and noisy.previous_id == calm.pk
    # Fresh noise of the same camera stays within the tolerances (10 um, 0.2 % FS, 0.001).
    assert calm.drift["beyond"] == 0, [item for item in calm.drift["items"] if item["beyond"]]
    items = {item["key"]: item for item in noisy.drift["items"]}
    assert items["overall.std_error_mm"]["beyond"], items["overall.std_error_mm"]
    assert items["overall.std_error_mm"]["change"] > 0.01
    assert noisy.drift["beyond"] >= 1 and "Overall standard deviation of the error" in noisy.drifted
    html = html_of(noisy)
    assert "moved beyond tolerance" in html and 'class="beyond" data-key="overall.std_error_mm"' in html


def test_drift_against_an_injected_previous_report_respects_the_tolerances():
    previous = SimpleNamespace(
        pk=7,
        created_at=timezone.now(),
        summary={
            "overall": {"mean_error_mm": 0.010, "std_error_mm": 0.030, "error_pct_fs": 0.05},
            "positions": {"z_in_mm": [0.0, 8.0], "mean_error_mm": [0.0, 0.010]},
            "rig": {"L_mm": 1022.0, "alpha_rad": 0.332},
        },
    )
    summary = {
        "overall": {"mean_error_mm": 0.015, "std_error_mm": 0.055, "error_pct_fs": 0.05},
        "positions": {"z_in_mm": [0.0, 8.0, 16.0], "mean_error_mm": [0.002, -0.030, 0.5]},
        "rig": {"L_mm": 1030.0, "alpha_rad": 0.332},
    }
    drift = services.compute_drift(previous, summary, {"mm": 0.010})
    items = {item["key"]: item for item in drift["items"]}
    assert not items["overall.mean_error_mm"]["beyond"]  # moved 5 um
    assert items["overall.std_error_mm"]["beyond"]  # moved 25 um
    assert items["overall.std_error_mm"]["change"] == pytest.approx(0.025)
    assert not items["positions.mean_error_mm@0"]["beyond"]
    assert items["positions.mean_error_mm@8"]["beyond"]  # moved 40 um
    assert "positions.mean_error_mm@16" not in items  # no previous value to compare with
    assert not items["overall.max_abs_slope_deviation"]["beyond"]  # missing on both sides
    assert drift["beyond"] == 2
    assert drift["rig_changes"] == [{"name": "L_mm", "previous": 1022.0, "current": 1030.0}]
    assert services.compute_drift(previous, summary, {"mm": 0.05})["beyond"] == 0


def stage_summary(means_um: list[float], sigma_um: float, n: int) -> dict:
    """A report summary with positions 0, 28, 56 mm (2 repeats): mean errors, their scatter and sample counts."""
    means = [m / 1000 for m in means_um]
    return {
        "repeats": 2,
        "overall": {"mean_error_mm": sum(means) / 3, "std_error_mm": sigma_um / 1000},
        "positions": {
            "z_in_mm": [0.0, 28.0, 56.0],
            "mean_error_mm": means,
            "std_error_mm": [sigma_um / 1000] * 3,
            "n_samples": [n] * 3,
        },
        "rig": {"L_mm": 1022.0},
    }


def test_drift_flags_a_change_only_beyond_its_own_uncertainty():
    """Issue 9: 8.1 -> -2.6 um at Z_in = 56 mm with sigma 25 um over 42 samples is noise, not drift."""
    previous = SimpleNamespace(pk=3, created_at=timezone.now(), summary=stage_summary([1.0, 4.0, 8.1], 25.0, 42))
    drift = services.compute_drift(previous, stage_summary([1.5, 3.0, -2.6], 25.0, 42), {"mm": 0.010})
    item = {item["key"]: item for item in drift["items"]}["positions.mean_error_mm@56"]
    # 42 samples = 21 test points x 2 repeats sharing one reference: 21 independent units per report;
    # standard uncertainty of the difference of two means: sqrt(2) * 25 um / sqrt(21) = 7.7 um
    assert item["uncertainty"] == pytest.approx(2**0.5 * 0.025 / 21**0.5, rel=1e-9)
    assert abs(item["change"]) > item["tolerance"]  # beyond the 10 um tolerance...
    assert not item["beyond"]  # ...but within 3 sigma (23 um): not drift
    assert drift["coverage_factor"] == 3 and drift["beyond"] == 0
    # a real move of 40 um is beyond both
    moved = services.compute_drift(previous, stage_summary([1.5, 3.0, 48.1], 25.0, 42), {"mm": 0.010})
    beyond = {item["key"] for item in moved["items"] if item["beyond"]}
    assert beyond == {"positions.mean_error_mm@56"}  # 40 um; the overall mean moved 13.3 um, within 3 x 7.7 um
    # with many samples the uncertainty is small and the tolerance decides
    precise = services.compute_drift(
        SimpleNamespace(pk=3, created_at=timezone.now(), summary=stage_summary([1.0, 4.0, 8.1], 25.0, 4200)),
        stage_summary([1.5, 3.0, -2.6], 25.0, 4200),
        {"mm": 0.010},
    )
    assert {item["key"]: item for item in precise["items"]}["positions.mean_error_mm@56"]["beyond"]


def test_standard_uncertainties_of_the_summary_figures():
    """u(mean) = s / sqrt(n / R), u(s) = s / sqrt(2 (N_eff - 1)), and the RMS, % FS and slope from them."""
    from metrology.reports.summary import standard_uncertainties

    summary = stage_summary([10.0, -20.0, 30.0], 30.0, 50)
    summary["overall"].update(
        {
            "mean_error_mm": 0.004,
            "std_error_mm": 0.030,
            "rms_error_mm": (0.004**2 + 0.030**2) ** 0.5,
            "full_scale_mm": 56.0,
        }
    )
    summary["slope_uncertainty"] = 2e-4
    u = standard_uncertainties(summary)
    # 50 samples per position, 2 repeats: 25 test points, the independent units (one shared reference)
    assert u["positions.mean_error_mm@28"] == pytest.approx(0.030 / 25**0.5)
    assert u["overall.mean_error_mm"] == pytest.approx(0.030 / 25**0.5)  # N_eff = 150 / (2 x 3)
    u_m, u_s = 0.030 / 25**0.5, 0.030 / (2 * 24) ** 0.5
    assert u["overall.std_error_mm"] == pytest.approx(u_s)
    rms = summary["overall"]["rms_error_mm"]
    u_rms = ((0.004 * u_m) ** 2 + (0.030 * u_s) ** 2) ** 0.5 / rms
    assert u["overall.rms_error_mm"] == pytest.approx(u_rms)
    assert u["overall.error_pct_fs"] == pytest.approx(100 * u_rms / 56.0)
    assert u["overall.max_abs_mean_error_mm"] == pytest.approx(0.030 / 25**0.5)  # at Z_in = 56 mm (30 um)
    assert u["overall.max_abs_slope_deviation"] == 2e-4
    assert standard_uncertainties({"overall": {"mean_error_mm": 0.01}})["overall.mean_error_mm"] is None


def test_slope_uncertainty_at_the_worst_test_point():
    """u(slope) = sigma_tp / sqrt(R sum (Z_i - mean Z)^2) at the point of largest |slope - 1|."""
    from metrology.reports.summary import slope_uncertainty

    results = {
        "z_in_mm": [0.0, 8.0, 16.0],
        "repeats": 2,
        "test_points": [{"slope": 1.0002, "sigma_mm": 0.01}, {"slope": 0.9990, "sigma_mm": 0.02}, {"slope": None}],
    }
    assert slope_uncertainty(results) == pytest.approx(0.02 / (2 * 128) ** 0.5)  # sum of squares 64 + 0 + 64
    assert slope_uncertainty({"z_in_mm": [0.0], "repeats": 2, "test_points": results["test_points"]}) is None


def test_auto_source_takes_the_newest_uploaded_stage_series(rig, alice):
    core = CoreRig.from_dict(SMALL_RIG)

    def upload(z_mm, role, session, **extra):
        handle = io.BytesIO(stack_zip(render_images(core, z_mm, bit_depth=16)))
        handle.name = f"{role}.zip"
        handle.size = len(handle.getvalue())
        return upload_capture(owner=alice, rig=rig, upload=handle, role=role, session_id=session.pk, **extra)

    session = create_session(owner=alice, rig=rig, name="stage run")
    upload(0.0, "reference", session)
    for z_in in (0.0, 10.0, 20.0):
        upload(z_in, "stage", session, z_in_mm=z_in)

    report = services.run_characterization_report(rig, source="auto")

    assert report.job.status == Job.Status.DONE, report.job.error
    assert report.source == Report.Source.UPLOADED_SERIES and report.session_id == session.pk
    assert report.summary["positions"]["z_in_mm"] == [0.0, 10.0, 20.0]
    assert abs(report.summary["overall"]["mean_error_mm"]) < 1e-3  # exact, noise-free stacks
    assert not Capture.objects.filter(rig=rig, source=Capture.Source.VIRTUAL).exists()


@pytest.mark.parametrize(
    ("source", "options", "words"),
    [
        ("virtual_stage", {"z_step_mm": 0}, "z_step_mm must be positive"),
        ("virtual_stage", {"z_stop_mm": 4.0}, "a characterization needs two or more"),
        ("virtual_stage", {"colour": 1}, "unknown option(s) colour"),
        ("virtual_stage", {"repeats": 1.5}, "repeats must be an integer"),
        ("virtual_stage", {"tolerances": {"um": 3}}, "unknown kind(s) um"),
        ("uploaded_series", {}, "has no uploaded stage captures"),
        ("camera", {}, "source must be one of"),
    ],
)
def test_bad_requests_are_refused_with_a_reason(rig, source, options, words):
    with pytest.raises(BadInput, match=re.escape(words)):
        services.request_report(rig=rig, source=source, options=options)
    assert not Report.objects.exists() and not Job.objects.exists()


def test_schedule_report_creates_and_updates_one_periodic_task(rig):
    task = services.schedule_report(rig, every_s=3600, options={"repeats": 3})
    assert task.task == REPORT_TASK and task.enabled and task.interval.every == 3600 and task.crontab is None
    assert json.loads(task.kwargs) == {"rig_id": rig.pk, "source": "auto", "options": {"repeats": 3}}

    again = services.schedule_report(rig, crontab="0 6 * * *", source="virtual_stage")
    assert again.pk == task.pk and again.interval is None and again.crontab.hour == "6"
    assert PeriodicTask.objects.filter(task=REPORT_TASK).count() == 1
    with pytest.raises(BadInput, match="five fields"):
        services.schedule_report(rig, crontab="daily")
    with pytest.raises(BadInput, match="either every_s"):
        services.schedule_report(rig)
    assert services.unschedule_report(rig) and not services.unschedule_report(rig)


def test_the_beat_task_requests_a_report_and_runs_it(rig):
    from metrology.reports.tasks import scheduled_characterization_report

    report_id = scheduled_characterization_report.apply(
        kwargs={"rig_id": rig.pk, "source": "virtual_stage", "options": QUICK}
    ).get()
    report = Report.objects.get(pk=report_id)
    assert report.job.status == Job.Status.DONE and report.html
    assert scheduled_characterization_report.apply(kwargs={"rig_id": 999_999}).get() is None


@pytest.mark.django_db(transaction=False)
def test_the_beat_task_skips_a_rig_whose_report_is_still_pending(rig):
    # Without a commit the first report's job is never sent: it stays queued.
    first = services.request_scheduled_report(rig_id=rig.pk, options=QUICK)
    assert first is not None and first.job.status == Job.Status.QUEUED
    assert services.request_scheduled_report(rig_id=rig.pk, options=QUICK) is None
    assert Report.objects.count() == 1


def test_command_prints_the_stored_report_and_its_summary(rig, media_root):
    out = io.StringIO()
    call_command("characterization_report", "bench", "--z-stop", "16", "--z-step", "8", stdout=out)
    text = out.getvalue()
    report = Report.objects.get()
    assert f"report {report.pk} of rig {rig.pk} (virtual stage)" in text
    assert f"html: {report.html.name} in the media storage (page: /reports/{report.pk}/report.html)" in text
    assert (media_root / report.html.name).is_file()
    assert f"page: /reports/{report.pk}/" in text
    assert "mean error" in text and "baseline" in text

    call_command("characterization_report", str(rig.pk), "--schedule-every", "600", stdout=out)
    assert PeriodicTask.objects.get(task=REPORT_TASK).interval.every == 600
    call_command("characterization_report", str(rig.pk), "--unschedule", stdout=out)
    assert not PeriodicTask.objects.filter(task=REPORT_TASK).exists()


def test_command_refuses_an_unknown_or_ambiguous_rig(rig, alice):
    create_rig(owner=alice, data={**SMALL_RIG, "name": "bench"})
    with pytest.raises(CommandError, match="2 rigs are named 'bench'"):
        call_command("characterization_report", "bench")
    with pytest.raises(CommandError, match="no rig with id or name 'nope'"):
        call_command("characterization_report", "nope")
    with pytest.raises(CommandError, match="z_step_mm must be positive"):
        call_command("characterization_report", str(rig.pk), "--z-step", "0")
    with pytest.raises(CommandError, match=r"crontab '0 25 \* \* \*' is not valid: Invalid end range: 25 > 23"):
        call_command("characterization_report", str(rig.pk), "--schedule-crontab", "0 25 * * *")


def test_command_schedules_with_a_crontab_and_prints_the_next_run(rig):
    out = io.StringIO()
    before = timezone.now()
    call_command("characterization_report", str(rig.pk), "--schedule-crontab", "15 4 * * *", stdout=out)
    upcoming = before.replace(hour=4, minute=15, second=0, microsecond=0)
    if upcoming <= before:
        upcoming += datetime.timedelta(days=1)
    assert "scheduled 15 4 * * * (UTC)" in out.getvalue()
    assert f"next run {upcoming:%Y-%m-%d %H:%M} UTC" in out.getvalue()
