"""Fixtures that start the real stack: PostgreSQL database, Redis queue, web server, Celery workers."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import requests

from tests.app.integration.harness import Stack, check_services, fresh_database
from tests.app.integration.helpers import authenticated


@pytest.fixture(autouse=True)
def media_root(tmp_path) -> Path:
    """Overrides the app-level fixture: these tests use no in-process Django settings."""
    root = tmp_path / "media"
    root.mkdir()
    return root


@pytest.fixture
def stack(tmp_path, media_root) -> Iterator[Stack]:
    check_services()
    logs = tmp_path / "logs"
    logs.mkdir()
    with fresh_database() as database_url:
        stack = Stack(database_url, media_root, logs)
        try:
            stack.manage("migrate", "--noinput")
            stack.start_web()
            yield stack
        finally:
            stack.stop()


@pytest.fixture
def http(stack) -> requests.Session:
    """An HTTP session authenticated with the token of a user made by ``manage.py createuser``."""
    return authenticated(stack)
