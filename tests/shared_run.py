"""What the pytest-xdist workers of one run share: a temporary folder, and the key of a migrated
database (the embedded SQLite copy of tests/conftest.py, the PostgreSQL template of
tests/app/integration/harness.py)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest


def run_folder(config: pytest.Config) -> Path:
    """The temporary folder of the whole run: the controller's ``basetemp``, which holds each
    worker's own (``popen-gw0``...); without xdist, the process's ``basetemp``."""
    root: Path = config._tmp_path_factory.getbasetemp()  # type: ignore[attr-defined]
    return root.parent if hasattr(config, "workerinput") else root


def migrations_digest() -> str:
    """A hash of every installed app's migration files (and Django's version): what a migrated
    database depends on."""
    import django
    from django.apps import apps

    digest = hashlib.sha256(django.get_version().encode())
    for config in sorted(apps.get_app_configs(), key=lambda c: c.label):
        folder = Path(config.path) / "migrations"
        for path in sorted(folder.glob("*.py")) if folder.is_dir() else ():
            digest.update(f"{config.label}/{path.name}".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]
