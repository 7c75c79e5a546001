"""Reads for jobs, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.jobs.models import Job


def jobs_for(user) -> QuerySet[Job]:
    return Job.objects.filter(owner=user)


def jobs_filtered(user, *, kind: str = "", status: str = "") -> QuerySet[Job]:
    """The user's jobs, newest first, of ``kind`` and in ``status`` when given (``Job.Kind`` and
    ``Job.Status`` values; an empty string keeps every one)."""
    jobs = jobs_for(user)
    if kind:
        jobs = jobs.filter(kind=kind)
    if status:
        jobs = jobs.filter(status=status)
    return jobs.order_by("-created_at", "-id")


def get_job(user, job_id) -> Job:
    job = jobs_for(user).filter(pk=job_id).first() if str(job_id).isdigit() else None
    if job is None:
        raise Http404(f"No job {job_id} among yours.")
    return job
