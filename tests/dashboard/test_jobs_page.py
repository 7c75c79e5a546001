"""The jobs page (``/jobs/``): the user's jobs, newest first, filtered by kind and state, 50 a page."""

from __future__ import annotations

import re
from html import unescape

from metrology.jobs.models import Job
from metrology.jobs.services import create_job


def job_rows(html: str) -> list[int]:
    """The job numbers listed in the jobs page's table, in order."""
    return [int(n) for n in re.findall(r'<td><a href="/jobs/(\d+)/">#\d+</a></td>', html)]


def test_the_jobs_page_lists_the_users_jobs_filtered_by_kind_and_state(client_alice, alice, bob):
    measurement = create_job(owner=alice, kind=Job.Kind.MEASUREMENT, parameters={})
    failed = create_job(owner=alice, kind=Job.Kind.CALIBRATION, parameters={})
    Job.objects.filter(pk=failed.pk).update(status=Job.Status.FAILED, error="the master block was not found")
    running = create_job(owner=alice, kind=Job.Kind.MEASUREMENT, parameters={})
    Job.objects.filter(pk=running.pk).update(status=Job.Status.RUNNING, progress=40, phase="decoding")
    others = create_job(owner=bob, kind=Job.Kind.MEASUREMENT, parameters={})
    page = client_alice.get("/jobs/")
    html = unescape(page.content.decode())
    assert page.status_code == 200
    assert job_rows(html) == [running.pk, failed.pk, measurement.pk] and others.pk not in job_rows(html)
    assert 'href="/jobs/" aria-current="page">Jobs</a>' in html  # in the navigation
    assert "the master block was not found" in html and "40 %" in html and "decoding" in html
    html = client_alice.get("/jobs/?kind=measurement").content.decode()
    assert job_rows(html) == [running.pk, measurement.pk] and "matching the filters" in html
    html = client_alice.get("/jobs/?kind=measurement&status=queued").content.decode()
    assert job_rows(html) == [measurement.pk]
    html = client_alice.get("/jobs/?status=failed").content.decode()
    assert job_rows(html) == [failed.pk]
    html = client_alice.get("/jobs/?kind=report").content.decode()
    assert job_rows(html) == [] and "No job of yours matches these filters" in html
    # a value that is not a kind is refused by the form and filters nothing
    html = client_alice.get("/jobs/?kind=nonsense").content.decode()
    assert job_rows(html) == [running.pk, failed.pk, measurement.pk]
    assert 'href="/jobs/">All jobs</a>' in client_alice.get("/").content.decode()


def test_the_jobs_page_pages_by_fifty(client_alice, alice):
    jobs = [create_job(owner=alice, kind=Job.Kind.MEASUREMENT, parameters={}) for _ in range(55)]
    first = client_alice.get("/jobs/?kind=measurement").content.decode()
    assert len(job_rows(first)) == 50 and "page 1 of 2" in first
    assert 'href="?kind=measurement&amp;page=2"' in first
    second = client_alice.get("/jobs/?kind=measurement&page=2").content.decode()
    assert job_rows(second) == [job.pk for job in jobs[:5]][::-1]
