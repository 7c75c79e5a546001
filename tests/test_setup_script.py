"""scripts/setup.sh installs once: the dev install satisfies the plain one (demo <-> test switches
install nothing), and a changed pyproject.toml installs again; it installs with uv, and with pip
where uv cannot be installed or cannot install; the dev install takes the optional STEP reader
(cadquery-ocp) in the same call, wheels only, and without a wheel says that the STEP tests will be
skipped and installs the dev extras alone; the plain install (the users') compiles the installed
packages' bytecode, the dev install does not. Run on a copy, with stand-ins ``.venv/bin/python`` and
``.venv/bin/uv`` that record the install calls instead of installing (and fail the wheels-only call,
as pip and uv do where no wheel exists, when asked to)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

UV = "uv pip install --quiet --python .venv/bin/python"
PIP = "-m pip install --quiet"
STEP = "--only-binary cadquery-ocp,vtk -e .[dev,step]"
DEV = "-e .[dev]"


def make_copy(tmp_path: Path, no_wheel: bool = False, no_uv: bool = False) -> tuple[Path, Path]:
    project = tmp_path / "project"
    (project / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "setup.sh", project / "scripts" / "setup.sh")
    shutil.copy(ROOT / "pyproject.toml", project / "pyproject.toml")
    log = tmp_path / "pip.log"
    bin_dir = project / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    fail = 'case "$*" in *--only-binary*) exit 1;; esac\n' if no_wheel else ""
    # pip installs uv by writing the stand-in uv (unless uv cannot be installed here)
    get_uv = (
        'case "$*" in *"uv>="*) exit 1;; esac\n'
        if no_uv
        else f'case "$*" in *"uv>="*) printf \'#!/bin/sh\\necho "uv $*" >> {log}\\n{fail}\' > {bin_dir}/uv; '
        f"chmod +x {bin_dir}/uv; exit 0;; esac\n"
    )
    python = bin_dir / "python"
    python.write_text(f'#!/bin/sh\n{get_uv}echo "$*" >> {log}\n{fail}')
    python.chmod(0o755)
    return project, log


def installs(project: Path, log: Path, *args: str, said: list[str] | None = None) -> list[str]:
    before = log.read_text().splitlines() if log.exists() else []
    result = subprocess.run(
        ["bash", "scripts/setup.sh", *args], cwd=project, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    if said is not None:
        said.extend(result.stderr.splitlines())
    after = log.read_text().splitlines() if log.exists() else []
    return [line for line in after[len(before) :] if "install" in line and "-e" in line]


def test_dev_install_satisfies_the_demo_and_changes_reinstall(tmp_path):
    if shutil.which("sha256sum") is None:
        raise AssertionError("sha256sum is needed by scripts/setup.sh")
    project, log = make_copy(tmp_path)
    assert installs(project, log, "--dev") == [f"{UV} {STEP}"]
    assert installs(project, log) == []  # the demo after the tests
    assert installs(project, log, "--dev") == []  # and the tests again
    with (project / "pyproject.toml").open("a") as handle:
        handle.write("\n# changed\n")
    assert installs(project, log) == [f"{UV} -e ."]
    assert installs(project, log, "--dev") == [f"{UV} {STEP}"]
    assert installs(project, log) == []


def compiles(log: Path) -> list[str]:
    return [line for line in log.read_text().splitlines() if "compileall" in line]


def test_the_plain_install_compiles_the_bytecode_and_the_dev_install_does_not(tmp_path):
    project, log = make_copy(tmp_path)
    assert installs(project, log, "--dev") == [f"{UV} {STEP}"]
    assert compiles(log) == []
    (project / ".venv" / ".gcps-installed").unlink()
    assert installs(project, log) == [f"{UV} -e ."]
    (line,) = compiles(log)
    assert line.startswith("-m compileall -q -q -j 0 ")
    # a plain install made before its bytecode was compiled (stamp without "+pyc") is done again
    stamp = project / ".venv" / ".gcps-installed"
    stamp.write_text(stamp.read_text().replace("+pyc", ""))
    assert installs(project, log) == [f"{UV} -e ."]
    assert len(compiles(log)) == 2
    assert installs(project, log) == [] and len(compiles(log)) == 2


def test_without_uv_pip_installs(tmp_path):
    project, log = make_copy(tmp_path, no_uv=True)
    assert installs(project, log, "--dev") == [f"{PIP} {STEP}"]


def test_without_a_step_wheel_the_dev_install_goes_on_and_says_so(tmp_path):
    project, log = make_copy(tmp_path, no_wheel=True)
    said: list[str] = []
    # uv cannot, pip (the fallback) cannot either: the dev extras alone, with uv
    assert installs(project, log, "--dev", said=said) == [f"{UV} {STEP}", f"{PIP} {STEP}", f"{UV} {DEV}"]
    assert said == ["setup.sh: no cadquery-ocp wheel for this platform: the STEP tests will be skipped"]
    assert installs(project, log, "--dev") == [] and installs(project, log) == []
    stamp = project / ".venv" / ".gcps-installed"
    stamp.write_text(stamp.read_text().replace("[dev]-step", "[dev]"))  # set up before the STEP extra
    assert installs(project, log, "--dev") == [f"{UV} {STEP}", f"{PIP} {STEP}", f"{UV} {DEV}"]
