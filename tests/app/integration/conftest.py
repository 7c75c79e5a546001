"""Fixtures that start the real stack: PostgreSQL database, Redis queue, web server, Celery workers."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests

from tests.app.integration.harness import Stack, migrated_stack
from tests.app.integration.helpers import authenticated


@pytest.fixture(autouse=True)
def media_root(tmp_path) -> Path:
    """Overrides the app-level fixture: these tests use no in-process Django settings."""
    root = tmp_path / "media"
    root.mkdir()
    return root


def storage_env(request: pytest.FixtureRequest) -> dict[str, str]:
    """With ``GCPS_TEST_S3=1`` every stack stores in a fresh bucket of the session's S3 server
    (tests/s3.py), so the integration tests run against S3; else the local media folder."""
    if os.environ.get("GCPS_TEST_S3") != "1":
        return {}
    s3 = request.getfixturevalue("s3")
    return s3.env(s3.bucket())


@pytest.fixture
def stack_storage_env(request) -> dict[str, str]:
    """The storage settings of a test's stack (:func:`storage_env`)."""
    return storage_env(request)


@pytest.fixture(scope="module")
def module_stack(request, tmp_path_factory) -> Iterator[Stack]:
    """A stack with its web server and one worker (``worker-1``, the default settings), shared by
    the tests of a module that need a running worker but neither a fresh one nor an empty database
    (they share this one): each test's own web server and worker start cost about 0.8 and 1.5 s of
    CPU. Mark those tests with one ``xdist_group`` so that one pytest-xdist worker runs them
    (tests/conftest.py groups by itself only the tests of a module's own module-scoped fixtures)."""
    folder = tmp_path_factory.mktemp("module-stack")
    media = folder / "media"
    media.mkdir()
    with migrated_stack(folder, media, storage_env(request)) as stack:
        stack.start_web()
        stack.start_worker("worker-1")
        yield stack


@pytest.fixture
def stack(tmp_path, media_root, stack_storage_env) -> Iterator[Stack]:
    with migrated_stack(tmp_path, media_root, stack_storage_env) as stack:
        stack.start_web()
        yield stack


@pytest.fixture
def bare_stack(tmp_path, media_root, stack_storage_env) -> Iterator[Stack]:
    """A stack on its fresh database with no process started: the test starts what it needs."""
    with migrated_stack(tmp_path, media_root, stack_storage_env) as stack:
        yield stack


@pytest.fixture
def http(stack) -> requests.Session:
    """An HTTP session authenticated with the token of the user the database was copied with
    (:func:`harness.template_user_token`)."""
    return authenticated(stack)
