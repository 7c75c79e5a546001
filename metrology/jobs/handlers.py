"""The job handlers: one function per job kind, registered by the app that owns the kind.

Each app registers its handler in its ``AppConfig.ready()``, by its dotted path::

    register_handler(Job.Kind.MEASUREMENT, "metrology.measurements.services.run_measurement")

so the jobs app imports no other app (the dependency points from the app to the jobs, never back),
and ``django.setup()`` imports none of the services: they load the pipelines (SciPy, OpenCV) and
are imported when a job of their kind first runs, or when a worker starts (:func:`preload_job_code`,
on Celery's ``worker_init``), so that the worker's first job does not pay for them. A reader
follows the path; ``tests/test_startup_imports.py`` checks that every kind's path resolves.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeAlias, cast

from django.utils.module_loading import import_string

from metrology.jobs.models import Job

if TYPE_CHECKING:
    from metrology.jobs.services import JobRun

JobHandler: TypeAlias = "Callable[[Job, JobRun], None]"
"""Computes one attempt of a job: reads ``job.parameters``, reports through ``run`` and ends with
``run.commit(...)``; raises :class:`metrology.jobs.services.JobFailedError` (or ``ValueError``) with
a sentence for a person when the job cannot be done."""

_HANDLERS: dict[Job.Kind, JobHandler | str] = {}


def _name(handler: JobHandler | str) -> str:
    return handler if isinstance(handler, str) else f"{handler.__module__}.{handler.__qualname__}"


def register_handler(kind: Job.Kind, handler: JobHandler | str) -> None:
    """Make ``handler`` (a function, or the dotted path of one) the function that runs jobs of ``kind``.

    Registering the same function twice is harmless (``ready()`` may run more than once in tests);
    a second, different function for one kind raises ``ValueError``.
    """
    kind = Job.Kind(kind)
    current = _HANDLERS.get(kind)
    if current is not None and _name(current) != _name(handler):
        raise ValueError(f"job kind {kind.value!r} already has the handler {_name(current)}")
    _HANDLERS[kind] = handler


def handler_for(kind: str) -> JobHandler:
    """The handler registered for ``kind`` (its module imported if it was registered by path);
    ``LookupError`` naming the kind when none is."""
    try:
        handler = _HANDLERS[Job.Kind(kind)]
    except (KeyError, ValueError):
        raise LookupError(
            f"no handler is registered for job kind {kind!r} (registered: {sorted(k.value for k in _HANDLERS)})"
        ) from None
    return cast("JobHandler", import_string(handler)) if isinstance(handler, str) else handler


_SWEEPS: dict[str, None] = {}


def register_sweep(path: str) -> None:
    """Add the function at dotted ``path`` to the periodic job sweep
    (:func:`metrology.jobs.services.sweep_jobs`): called with no argument, it returns counts
    (``dict[str, int]``) merged into the sweep's. An app that owns jobs no worker runs (the
    acquisitions, run by a rig's agent) registers here what must happen to them over time.
    Registering a path twice is harmless."""
    _SWEEPS[path] = None


def registered_sweeps() -> list[Callable[[], dict[str, int]]]:
    """The functions registered with :func:`register_sweep`, in registration order."""
    return [cast("Callable[[], dict[str, int]]", import_string(path)) for path in _SWEEPS]


def registered_kinds() -> set[Job.Kind]:
    """The kinds that have a handler."""
    return set(_HANDLERS)


#: What the handlers compute with, imported inside their functions (a web process loads it when a
#: request needs it): the measurement core and its pipelines (SciPy, OpenCV), the figures of a
#: report (Plotly).
JOB_LIBRARIES = ("metrology.core", "metrology.pipeline", "metrology.figures")


def preload_job_code(**_: object) -> None:
    """Import every registered handler and every module of :data:`JOB_LIBRARIES`.

    A receiver of Celery's ``worker_init`` (connected by the jobs app): the worker pays for these
    imports once as it starts, before its pool forks (the children inherit them), rather than on
    its first job; so for the core's compiled kernels (numba reads their disk cache), which it
    also loads (:func:`metrology.core.compiled.warm_all`).
    """
    for kind in sorted(_HANDLERS):
        handler_for(kind)
    for name in JOB_LIBRARIES:
        package = importlib.import_module(name)
        for module in pkgutil.walk_packages(package.__path__, f"{name}."):
            importlib.import_module(module.name)
    # numba is now imported: the decoders take their compiled kernels, loaded (or compiled) now
    # rather than by the first decode of a job
    from metrology.core.compiled import warm_all

    warm_all()
