"""Fixtures for the page tests: a temporary MEDIA_ROOT, two users with passwords, logged-in clients,
a small rig with stored captures, finished results made through the services, and an in-process job
worker for the browser tests."""

from __future__ import annotations

import queue
import threading
from pathlib import Path

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from metrology.accounts.services import create_user_with_token
from metrology.captures.services import upload_capture
from metrology.core.rig import Rig as CoreRig
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip

PASSWORD = "a-long-test-password-42"


@pytest.fixture(autouse=True)
def media_root(settings, tmp_path) -> Path:
    root = tmp_path / "media"
    root.mkdir()
    settings.MEDIA_ROOT = root
    return root


@pytest.fixture
def alice(db):
    return create_user_with_token(username="alice", password=PASSWORD)[0]


@pytest.fixture
def bob(db):
    return create_user_with_token(username="bob", password=PASSWORD)[0]


def logged_in(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


@pytest.fixture
def client_alice(alice) -> Client:
    return logged_in(alice)


@pytest.fixture
def client_bob(bob) -> Client:
    return logged_in(bob)


@pytest.fixture
def rig(alice):
    return create_rig(owner=alice, data={**SMALL_RIG, "name": "bench"})


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
    monkeypatch.setattr(job_services, "_send", jobs.put)
    yield seen
    jobs.put(None)
    thread.join(timeout=60)
