"""scripts/setup.sh installs once: the dev install satisfies the plain one (demo <-> test switches
install nothing), and a changed pyproject.toml installs again. Run on a copy, with a stand-in
``.venv/bin/python`` that records the pip calls instead of installing."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_copy(tmp_path: Path) -> tuple[Path, Path]:
    project = tmp_path / "project"
    (project / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "setup.sh", project / "scripts" / "setup.sh")
    shutil.copy(ROOT / "pyproject.toml", project / "pyproject.toml")
    log = tmp_path / "pip.log"
    python = project / ".venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text(f'#!/bin/sh\necho "$*" >> {log}\n')
    python.chmod(0o755)
    return project, log


def installs(project: Path, log: Path, *args: str) -> list[str]:
    before = log.read_text().splitlines() if log.exists() else []
    result = subprocess.run(
        ["bash", "scripts/setup.sh", *args], cwd=project, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    after = log.read_text().splitlines() if log.exists() else []
    return [line for line in after[len(before) :] if "install" in line and "-e" in line]


def test_dev_install_satisfies_the_demo_and_changes_reinstall(tmp_path):
    if shutil.which("sha256sum") is None:
        raise AssertionError("sha256sum is needed by scripts/setup.sh")
    project, log = make_copy(tmp_path)
    assert installs(project, log, "--dev") == ["-m pip install --quiet -e .[dev]"]
    assert installs(project, log) == []  # the demo after the tests
    assert installs(project, log, "--dev") == []  # and the tests again
    with (project / "pyproject.toml").open("a") as handle:
        handle.write("\n# changed\n")
    assert installs(project, log) == ["-m pip install --quiet -e ."]
    assert installs(project, log, "--dev") == ["-m pip install --quiet -e .[dev]"]
    assert installs(project, log) == []
