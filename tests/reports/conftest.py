"""Fixtures for the report tests: a temporary MEDIA_ROOT, two users, a small rig, a quick stage range."""

from __future__ import annotations

from pathlib import Path

import pytest

from metrology.accounts.services import create_user_with_token
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG

# Three positions, two repeats: a report in about a second on the 160 x 120 rig.
QUICK = {"z_start_mm": 0.0, "z_stop_mm": 16.0, "z_step_mm": 8.0, "repeats": 2}


@pytest.fixture(autouse=True)
def media_root(settings, tmp_path) -> Path:
    """Every test stores files in its own temporary folder."""
    root = tmp_path / "media"
    root.mkdir()
    settings.MEDIA_ROOT = root
    return root


@pytest.fixture
def alice(db):
    return create_user_with_token(username="alice", password="correct horse battery")[0]


@pytest.fixture
def bob(db):
    return create_user_with_token(username="bob", password="correct horse battery")[0]


@pytest.fixture
def rig(alice):
    return create_rig(owner=alice, data={**SMALL_RIG, "name": "bench"})
