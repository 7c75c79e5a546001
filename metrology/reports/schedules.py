"""Report schedules: a django-celery-beat ``PeriodicTask`` per rig that runs the report task.

Beat's DatabaseScheduler reads these rows (no restart needed); they can also be edited or disabled
in the admin (Periodic tasks).
"""

from __future__ import annotations

import json
from typing import Any

from celery.schedules import crontab as celery_crontab
from django.conf import settings
from django.db import transaction
from django_celery_beat.models import CrontabSchedule, IntervalSchedule, PeriodicTask

from metrology.errors import BadInput
from metrology.reports.options import SOURCES, check_options, checked_number
from metrology.reports.selectors import CRONTAB_FIELDS, REPORT_TASK
from metrology.rigs.models import Rig


def checked_crontab(spec: str) -> dict[str, str]:
    """The five fields of a crontab (``"minute hour day-of-month month day-of-week"``), checked by celery's parser.

    Raises
    ------
    BadInput
        Naming the crontab and what is wrong with it (``"Invalid end range: 99 > 59."``).
    """
    fields = str(spec).split()
    if len(fields) != len(CRONTAB_FIELDS):
        raise BadInput(f"crontab must have five fields 'minute hour day-of-month month day-of-week', got {spec!r}")
    values = dict(zip(CRONTAB_FIELDS, fields, strict=True))
    try:
        celery_crontab(**values)
    except (ValueError, TypeError, IndexError) as exc:
        raise BadInput(f"crontab {spec!r} is not valid: {exc}") from None
    return values


def _crontab(spec: str) -> CrontabSchedule:
    values = checked_crontab(spec)
    schedule, _ = CrontabSchedule.objects.get_or_create(**values, timezone=settings.TIME_ZONE)
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
        every = checked_number("every_s", every_s, integer=True, minimum=1)
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
