"""The Celery app, configured from Django settings (``CELERY_*``), on Redis.

The tasks live beside their services (``metrology/<app>/tasks.py``) and are found by
:meth:`Celery.autodiscover_tasks` over the installed Django apps; this package holds only the app.
It imports nothing of the apps (tasks are named by string), so no app depends on it in a cycle.
"""

from __future__ import annotations

import os

from celery import Celery
from celery.signals import worker_init

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "metrology.settings")

app = Celery("gcps")
app.config_from_object("django.conf:settings", namespace="CELERY")
app.autodiscover_tasks()


@app.on_after_configure.connect
def _beat_schedule(sender: Celery, **_: object) -> None:
    from django.conf import settings

    sender.conf.beat_schedule = {
        "sweep-stale-jobs": {
            "task": "workers.tasks.sweep_stale_jobs",
            "schedule": float(settings.GCPS_JOB_SWEEP_SECONDS),
        },
    }


@worker_init.connect
def _retain_freed_memory(**_: object) -> None:
    """Measurements allocate frame-sized arrays again and again: keep freed ones for reuse
    (set before the pool forks, so every child inherits it)."""
    from metrology.core.allocation import retain_freed_memory

    retain_freed_memory()
