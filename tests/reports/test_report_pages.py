"""Report pages: login required, each user sees only their own reports, view and download the HTML."""

from __future__ import annotations

import datetime
import html

import pytest
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage
from django.test import Client

from metrology.jobs.models import Job
from metrology.reports.models import Report
from metrology.reports.services import schedule_report

pytestmark = pytest.mark.django_db

HTML = "<!DOCTYPE html><html><body><h1>Characterization report</h1></body></html>"


def make_report(rig, *, status=Job.Status.DONE, beyond=0) -> Report:
    job = Job.objects.create(owner=rig.owner, kind=Job.Kind.REPORT, status=status, progress=40, phase="render")
    name = (
        default_storage.save(f"reports/rig_{rig.pk}/page-test.html", ContentFile(HTML.encode()))
        if status == "done"
        else ""
    )
    return Report.objects.create(
        owner=rig.owner,
        rig=rig,
        source=Report.Source.VIRTUAL_STAGE,
        job=job,
        html=name,
        summary={"overall": {"mean_error_mm": 0.0042, "std_error_mm": 0.025, "error_pct_fs": 0.031}},
        drift={"previous": 1 if beyond else None, "beyond": beyond, "items": []},
    )


def client_for(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


@pytest.mark.parametrize("path", ["/reports/", "/reports/1/", "/reports/1/report.html", "/reports/1/download/"])
def test_pages_need_a_login(path):
    response = Client().get(path)
    assert response.status_code == 302 and response.url.startswith("/login/?next=")


def test_empty_list_says_how_to_make_a_report(alice):
    response = client_for(alice).get("/reports/")
    assert response.status_code == 200
    text = response.content.decode()
    assert "No reports yet" in text and "python manage.py characterization_report RIG" in text
    assert "No report is scheduled" in text


def test_list_shows_own_reports_newest_first_and_schedules(rig, alice):
    older, newer = make_report(rig), make_report(rig, beyond=3)
    schedule_report(rig, every_s=86400)
    text = client_for(alice).get("/reports/").content.decode()
    assert text.index(f"Report {newer.pk}<") < text.index(f"Report {older.pk}<")
    assert "3 beyond tolerance" in text and "4.2 µm" in text
    assert "every day" in text or "86400" in text


def test_detail_embeds_the_report_and_download_is_an_attachment(rig, alice):
    report = make_report(rig)
    client = client_for(alice)
    detail = client.get(f"/reports/{report.pk}/").content.decode()
    assert f'<iframe src="/reports/{report.pk}/report.html"' in detail
    assert f'href="/reports/{report.pk}/download/"' in detail

    inline = client.get(f"/reports/{report.pk}/report.html")
    assert inline.status_code == 200 and inline["Content-Type"].startswith("text/html")
    assert inline["X-Frame-Options"] == "SAMEORIGIN"
    assert b"".join(inline.streaming_content).decode() == HTML

    download = client.get(f"/reports/{report.pk}/download/")
    assert download.status_code == 200
    assert download["Content-Disposition"].startswith("attachment;")
    assert f"gcps-characterization-report-{report.pk}-rig-{rig.pk}.html" in download["Content-Disposition"]


def test_a_running_report_shows_its_progress_and_a_failed_one_its_reason(rig, alice):
    running = make_report(rig, status=Job.Status.RUNNING)
    text = client_for(alice).get(f"/reports/{running.pk}/").content.decode()
    assert 'http-equiv="refresh"' in text and 'value="40"' in text
    assert client_for(alice).get(f"/reports/{running.pk}/download/").status_code == 404
    failed = make_report(rig, status=Job.Status.FAILED)
    Job.objects.filter(pk=failed.job_id).update(error="characterization: job 9 failed: no valid pixels")
    text = client_for(alice).get(f"/reports/{failed.pk}/").content.decode()
    assert "This report failed: characterization: job 9 failed: no valid pixels" in text


def test_another_users_report_is_not_found(rig, bob):
    report = make_report(rig)
    client = client_for(bob)
    for path in (f"/reports/{report.pk}/", f"/reports/{report.pk}/report.html", f"/reports/{report.pk}/download/"):
        assert client.get(path).status_code == 404, path
    assert f"Report {report.pk}<" not in client.get("/reports/").content.decode()
    response = client.post("/reports/run/", {"rig": rig.pk})
    assert response.status_code == 404


def test_reports_and_their_schedules_are_in_the_admin(rig, django_user_model):
    admin_user = django_user_model.objects.create_superuser("root", "root@example.com", "pw-for-tests-only")
    report = make_report(rig, beyond=2)
    schedule_report(rig, every_s=60)
    client = client_for(admin_user)
    changelist = client.get("/admin/reports/report/")
    assert changelist.status_code == 200 and f"report {report.pk} of bench" in changelist.content.decode()
    assert client.get(f"/admin/reports/report/{report.pk}/change/").status_code == 200
    tasks = client.get("/admin/django_celery_beat/periodictask/").content.decode()
    assert f"characterization report of rig {rig.pk}" in tasks


def test_run_now_form_queues_a_report_and_lands_on_its_page(rig, alice):
    response = client_for(alice).post("/reports/run/", {"rig": rig.pk, "source": "virtual_stage"})
    report = Report.objects.get()
    assert response.status_code == 302 and response.url == f"/reports/{report.pk}/"
    assert report.job.status == Job.Status.QUEUED  # no commit in this test: the job was not sent
    refused = client_for(alice).post("/reports/run/", {"rig": rig.pk, "source": "uploaded_series"}, follow=True)
    assert "has no uploaded stage captures" in refused.content.decode()


def expected_next_daily(hour: int, minute: int, now: datetime.datetime) -> datetime.datetime:
    """The next hh:mm (UTC) strictly after ``now``."""
    candidate = now.replace(hour=hour, minute=minute, second=0, microsecond=0)
    return candidate if candidate > now else candidate + datetime.timedelta(days=1)


def test_schedule_a_report_from_the_reports_page_and_see_its_next_run(rig, alice, settings):
    from django.utils import timezone
    from django_celery_beat.models import PeriodicTask

    client = client_for(alice)
    before = timezone.now()
    response = client.post("/reports/schedule/", {"rig": rig.pk, "crontab": "30 6 * * *", "source": "virtual_stage"})
    assert response.status_code == 302 and response.url == "/reports/"
    task = PeriodicTask.objects.get(name=f"characterization report of rig {rig.pk}")
    assert (task.crontab.minute, task.crontab.hour, task.enabled) == ("30", "6", True)
    text = client.get("/reports/").content.decode()
    assert 'id="schedules"' in text and "30 6 * * *" in text
    expected = expected_next_daily(6, 30, before)
    assert f"{expected:%Y-%m-%d %H:%M} UTC" in text, text[text.index('id="schedules"') :][:1500]
    # the demo (embedded default) runs no beat: the page says so and offers to run the schedule now
    settings.CELERY_TASK_ALWAYS_EAGER = True
    text = client.get("/reports/").content.decode()
    assert "no beat process" in text and f'action="/reports/schedule/{rig.pk}/run/"' in text
    settings.CELERY_TASK_ALWAYS_EAGER = False  # with a broker: say what must run for the schedule to fire
    text = client.get("/reports/").content.decode()
    assert "no beat process" not in text and "celery -A workers beat" in text


@pytest.mark.parametrize(
    ("crontab", "words"),
    [
        ("99 * * * *", "Invalid end range: 99 > 59"),
        ("0 25 * * *", "Invalid end range: 25 > 23"),
        ("daily", "five fields"),
        ("0 6 31 2 *", "never occurs"),
        ("", "five fields"),
    ],
)
def test_a_bad_crontab_is_refused_in_words_and_nothing_is_stored(rig, alice, crontab, words):
    from django_celery_beat.models import PeriodicTask

    response = client_for(alice).post("/reports/schedule/", {"rig": rig.pk, "crontab": crontab, "source": "auto"})
    assert response.status_code == 400
    text = html.unescape(response.content.decode())
    assert 'class="alert"' in text and "crontab" in text and words in text
    assert not PeriodicTask.objects.filter(name=f"characterization report of rig {rig.pk}").exists()


def test_run_a_schedule_now_and_remove_it(rig, alice, bob):
    from django_celery_beat.models import PeriodicTask

    options = {"z_start_mm": 0.0, "z_stop_mm": 16.0, "z_step_mm": 8.0, "repeats": 2}
    schedule_report(rig, crontab="0 6 * * *", source="virtual_stage", options=options)
    assert client_for(bob).post(f"/reports/schedule/{rig.pk}/run/").status_code == 404  # not bob's rig
    response = client_for(alice).post(f"/reports/schedule/{rig.pk}/run/")
    report = Report.objects.get()
    assert response.status_code == 302 and response.url == f"/reports/{report.pk}/"
    assert report.source == "virtual_stage" and report.parameters["z_stop_mm"] == 16.0  # the schedule's options
    assert client_for(bob).post(f"/reports/schedule/{rig.pk}/delete/").status_code == 404
    removed = client_for(alice).post(f"/reports/schedule/{rig.pk}/delete/")
    assert removed.status_code == 302 and not PeriodicTask.objects.filter(task__endswith="characterization_report")
    assert client_for(alice).post(f"/reports/schedule/{rig.pk}/run/").status_code == 404  # no schedule any more


def test_next_run_of_crontab_and_interval_schedules(rig):
    from metrology.reports.selectors import next_run_at

    now = datetime.datetime(2026, 11, 30, 7, 0, tzinfo=datetime.UTC)
    daily = schedule_report(rig, crontab="30 6 * * *")
    assert next_run_at(daily, now=now) == datetime.datetime(2026, 12, 1, 6, 30, tzinfo=datetime.UTC)
    weekdays = schedule_report(rig, crontab="0 9 * * 1-5")  # 2026-11-30 is a Monday
    assert next_run_at(weekdays, now=now) == datetime.datetime(2026, 11, 30, 9, 0, tzinfo=datetime.UTC)
    hourly = schedule_report(rig, every_s=3600)
    hourly.last_run_at = now - datetime.timedelta(minutes=10)
    assert next_run_at(hourly, now=now) == now + datetime.timedelta(minutes=50)
    hourly.last_run_at = None  # beat runs a new interval schedule at once
    assert next_run_at(hourly, now=now) == now
