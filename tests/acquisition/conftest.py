"""Fixtures for acquisition tests: a temporary MEDIA_ROOT, a user with a token, a small rig."""

from __future__ import annotations

from pathlib import Path

import pytest
from django.test import Client

from metrology.accounts.services import create_user_with_token
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG

PASSWORD = "a-long-test-password-42"


@pytest.fixture(autouse=True)
def media_root(settings, tmp_path) -> Path:
    root = tmp_path / "media"
    root.mkdir()
    settings.MEDIA_ROOT = root
    return root


@pytest.fixture
def alice_token(db):
    user, token = create_user_with_token(username="alice", password=PASSWORD)
    return user, token


@pytest.fixture
def alice(alice_token):
    return alice_token[0]


@pytest.fixture
def client_alice(alice) -> Client:
    client = Client()
    client.force_login(alice)
    return client


@pytest.fixture
def rig(alice):
    return create_rig(owner=alice, data={**SMALL_RIG, "name": "bench"})
