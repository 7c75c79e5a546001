#!/usr/bin/env bash
# Create .venv and install GCPS Lab with its dependencies (idempotent).
# Usage: scripts/setup.sh [--dev]
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
# open3d's wheel links libusb-1.0, which Debian's slim images lack
if ! ldconfig -p 2>/dev/null | grep -q "libusb-1.0.so.0"; then
  as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }
  as_root apt-get update -qq && DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq libusb-1.0-0 >/dev/null
fi
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
# install ARGS...: uv installs the versions pip would (the same resolution of pyproject.toml's bounds)
# in about a sixth of the time: parallel downloads, a cache shared by every clone on the machine, no
# bytecode compiled ahead (Python writes it on first import). pip is the fallback where uv cannot.
install() {
  if { [ -x .venv/bin/uv ] || .venv/bin/python -m pip install -qq "uv>=0.9"; } \
    && .venv/bin/uv pip install --quiet --python .venv/bin/python "$@"; then
    return 0
  fi
  .venv/bin/python -m pip install --quiet --upgrade pip && .venv/bin/python -m pip install --quiet "$@"
}
# The stamp records what is installed: a hash of pyproject.toml, plus "+pyc" for the plain install
# (compiled, below), "[dev]+step" or "[dev]-step" with the test extras (with or without the optional
# STEP reader). The dev install also satisfies the plain one, so switching between scripts/demo.sh
# and scripts/test.sh installs nothing until pyproject.toml changes.
stamp=.venv/.gcps-installed
dev=""
[ "${1:-}" = "--dev" ] && dev=1
hash="$(sha256sum pyproject.toml | cut -c1-16)"
have="$(cat "$stamp" 2>/dev/null || true)"
case "$have" in
  "${hash}[dev]+step" | "${hash}[dev]-step") ;;
  "${hash}+pyc") [ -z "$dev" ] || have="" ;;
  *) have="" ;;
esac
if [ -z "$have" ]; then
  if [ -z "$dev" ]; then
    install -e .
    # The plain install is the users': its packages get their bytecode now, as pip's install gives
    # them. Neither uv nor Python writes it otherwise where PYTHONDONTWRITEBYTECODE is set (many
    # shells and container images), and every gcps process then compiles numpy's, OpenCV's... modules
    # from source: `import numpy, cv2` 0.19 s instead of 0.09 s. compileall rather than uv's
    # --compile-bytecode, which compiles only the packages it installs now, not those of an existing
    # .venv (nor pip's fallback). It costs 19 s (13 s of CPU) on a new .venv, 3.6 s when all is
    # compiled (docs/testing.md, "Bytecode of the installed packages"). The dev install is not
    # compiled ahead (+44 s of set-up for 16k modules the suite mostly never imports): scripts/test.sh
    # unsets PYTHONDONTWRITEBYTECODE, so the first process that imports a module writes its bytecode.
    .venv/bin/python -m compileall -q -q -j 0 "$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))')" || true
    echo "${hash}+pyc" > "$stamp"
  # The tests' install takes the optional STEP reader (cadquery-ocp, OpenCASCADE) in the same call
  # where a wheel exists for this platform (docs/testing.md: +1.2 GB); elsewhere the STEP tests skip.
  elif install --only-binary cadquery-ocp,vtk -e ".[dev,step]"; then
    echo "${hash}[dev]+step" > "$stamp"
  else
    echo "setup.sh: no cadquery-ocp wheel for this platform: the STEP tests will be skipped" >&2
    install -e ".[dev]"
    echo "${hash}[dev]-step" > "$stamp"
  fi
fi
