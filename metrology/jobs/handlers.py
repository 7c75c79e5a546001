"""The job handlers: one function per job kind, registered by the app that owns the kind.

Each app registers its handler in its ``AppConfig.ready()``::

    register_handler(Job.Kind.MEASUREMENT, run_measurement)

so the jobs app imports no other app (the dependency points from the app to the jobs, never back),
and a reader or mypy can follow the call from :func:`handler_for` to the registered function.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, TypeAlias

from metrology.jobs.models import Job

if TYPE_CHECKING:
    from metrology.jobs.services import JobRun

JobHandler: TypeAlias = "Callable[[Job, JobRun], None]"
"""Computes one attempt of a job: reads ``job.parameters``, reports through ``run`` and ends with
``run.commit(...)``; raises :class:`metrology.jobs.services.JobFailedError` (or ``ValueError``) with
a sentence for a person when the job cannot be done."""

_HANDLERS: dict[Job.Kind, JobHandler] = {}


def register_handler(kind: Job.Kind, handler: JobHandler) -> None:
    """Make ``handler`` the function that runs jobs of ``kind``.

    Registering the same function twice is harmless (``ready()`` may run more than once in tests);
    a second, different function for one kind raises ``ValueError``.
    """
    kind = Job.Kind(kind)
    current = _HANDLERS.get(kind)
    if current is not None and current is not handler:
        raise ValueError(f"job kind {kind.value!r} already has the handler {current.__module__}.{current.__qualname__}")
    _HANDLERS[kind] = handler


def handler_for(kind: str) -> JobHandler:
    """The handler registered for ``kind``; ``LookupError`` naming the kind when none is."""
    try:
        return _HANDLERS[Job.Kind(kind)]
    except (KeyError, ValueError):
        raise LookupError(
            f"no handler is registered for job kind {kind!r} (registered: {sorted(k.value for k in _HANDLERS)})"
        ) from None


def registered_kinds() -> set[Job.Kind]:
    """The kinds that have a handler."""
    return set(_HANDLERS)
