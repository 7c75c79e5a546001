"""What the pytest-xdist workers of one run share: a temporary folder, the key of a migrated
database (the embedded SQLite copy of tests/conftest.py, the PostgreSQL template of
tests/app/integration/harness.py), and arrays that one of them made (:func:`arrays_made_once`)."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

RUN_FOLDER_ENV = "GCPS_TEST_RUN_FOLDER"
"""The environment variable that names the run's folder (:func:`run_folder`), set for every test
session by tests/conftest.py."""


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


@contextlib.contextmanager
def run_lock(folder: Path, name: str) -> Iterator[None]:
    """Hold the run's exclusive lock ``name`` (the file ``<name>.lock`` in the run's ``folder``,
    fcntl, released when the file closes): what one worker makes for the run is made under it, and
    the others wait for it and read what was made."""
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def arrays_made_once(name: str, make: Callable[[], tuple[np.ndarray, ...]]) -> tuple[np.ndarray, ...]:
    """``make()``'s arrays, made by the first process of the run that asks for ``name`` and kept in
    the run's folder (``<name>.npy``, one per array, under an fcntl lock), so that the run's other
    workers read them instead of making them again; without a run folder (no test session), made.
    The arrays read back equal the ones made, bit for bit (``.npy`` keeps dtype and shape)."""
    folder = os.environ.get(RUN_FOLDER_ENV)
    if folder is None:
        return make()
    index = Path(folder) / f"{name}.count"
    with run_lock(Path(folder), name):
        if index.exists():
            count = int(index.read_text())
            return tuple(np.load(Path(folder) / f"{name}-{i}.npy") for i in range(count))
        arrays = make()
        for i, array in enumerate(arrays):
            np.save(Path(folder) / f"{name}-{i}.npy", array)
        index.write_text(str(len(arrays)))  # last: a maker that dies before leaves no index
        return arrays
