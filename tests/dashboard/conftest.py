"""Fixtures for the page tests: stored captures of the small rig made through the services, jobs run
in-process, and an in-process job worker for the browser tests (the users, their clients, the rig and
the media root are tests/conftest.py's)."""

from __future__ import annotations

import queue
import threading

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from metrology.captures.services import upload_capture
from metrology.core.geometry.crossed_axes import Rig as CoreRig
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip


def upload(owner, rig, z, role: str, **extra):
    data = stack_zip(render_images(CoreRig.from_dict(SMALL_RIG), z, bit_depth=16))
    return upload_capture(
        owner=owner, rig=rig, upload=SimpleUploadedFile(f"{role}.zip", data, "application/zip"), role=role, **extra
    )


@pytest.fixture
def captures(alice, rig):
    """A stored reference and an object (a block 25 mm high) of ``rig``."""
    return upload(alice, rig, 0.0, "reference"), upload(alice, rig, block_heights(), "object")


@pytest.fixture
def run_jobs(django_capture_on_commit_callbacks):
    """Context manager: jobs enqueued inside it run (in-process) when it exits."""
    return lambda: django_capture_on_commit_callbacks(execute=True)


@pytest.fixture
def worker(transactional_db, settings, monkeypatch):
    """Run enqueued jobs in a background thread (its own connection to the file test database)."""
    from django.db import connection

    import metrology.jobs.services as job_services

    settings.GCPS_JOB_PHASE_PAUSE_SECONDS = 0.15  # slow enough for the bar to be seen moving
    jobs: queue.Queue[int | None] = queue.Queue()
    seen: list[tuple[int, str]] = []

    def loop() -> None:
        while (job_id := jobs.get()) is not None:
            seen.append((job_id, job_services.execute_job(job_id)))
        connection.close()

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: jobs.put(job_id))
    yield seen
    jobs.put(None)
    thread.join(timeout=60)
