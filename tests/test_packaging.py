"""Packaging: the SPDX licence string (no setuptools deprecation warning), and the README's production
command ``gunicorn metrology.asgi:application -k uvicorn_worker.UvicornWorker`` (and the WSGI entry
point) works with the installed dependencies."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_licence_is_an_spdx_string_and_gunicorn_a_dependency():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT"
    assert "setuptools>=77" in project["build-system"]["requires"]  # SPDX strings need setuptools 77
    assert any(dep.startswith("gunicorn>=") for dep in project["project"]["dependencies"])


@pytest.mark.slow
@pytest.mark.parametrize(
    "command",
    [["metrology.wsgi"], ["metrology.asgi:application", "-k", "uvicorn_worker.UvicornWorker"]],
    ids=["wsgi", "asgi"],
)
def test_gunicorn_loads_the_application(tmp_path, command):
    env = {key: value for key, value in os.environ.items() if not key.startswith(("GCPS", "DATABASE", "REDIS"))}
    env.update(DJANGO_SETTINGS_MODULE="metrology.settings", GCPS_VAR_DIR=str(tmp_path), DEBUG="1")
    gunicorn = Path(sys.executable).with_name("gunicorn")
    result = subprocess.run(
        [str(gunicorn), "--check-config", *command],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_docker_image_installs_the_libraries_open3d_loads():
    dockerfile = (ROOT / "Dockerfile").read_text()
    for library in ("libusb-1.0-0", "libgomp1", "libgl1"):
        assert f" {library}" in dockerfile, library
