"""The Celery app, configured from Django settings (``CELERY_*``), on Redis."""

from __future__ import annotations

import os

from celery import Celery
from celery.signals import worker_init, worker_ready

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "metrology.settings")

app = Celery("gcps", include=["workers.tasks", "metrology.reports.tasks"])
app.config_from_object("django.conf:settings", namespace="CELERY")


@app.on_after_configure.connect
def _beat_schedule(sender: Celery, **_: object) -> None:
    from django.conf import settings

    sender.conf.beat_schedule = {
        "sweep-stale-jobs": {
            "task": "workers.tasks.sweep_stale_jobs",
            "schedule": float(settings.GCPS_JOB_SWEEP_SECONDS),
        },
    }


@worker_ready.connect
def _sweep_on_start(sender: object = None, **_: object) -> None:
    """A fresh worker looks for jobs left running by a worker that died."""
    from workers.tasks import sweep_stale_jobs

    sweep_stale_jobs.delay()


@worker_init.connect
def _retain_freed_memory(**_: object) -> None:
    """Measurements allocate frame-sized arrays again and again: keep freed ones for reuse
    (set before the pool forks, so every child inherits it)."""
    from metrology.core.allocation import retain_freed_memory

    retain_freed_memory()
