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
# The stamp records what is installed: a hash of pyproject.toml, plus "[dev]+step" or "[dev]-step"
# with the test extras (with or without the optional STEP reader). The dev install also satisfies the
# plain one, so switching between scripts/demo.sh and scripts/test.sh installs nothing until
# pyproject.toml changes.
stamp=.venv/.gcps-installed
dev=""
[ "${1:-}" = "--dev" ] && dev=1
hash="$(sha256sum pyproject.toml | cut -c1-16)"
have="$(cat "$stamp" 2>/dev/null || true)"
case "$have" in
  "${hash}[dev]+step" | "${hash}[dev]-step") ;;
  "${hash}") [ -z "$dev" ] || have="" ;;
  *) have="" ;;
esac
if [ -z "$have" ]; then
  if [ -z "$dev" ]; then
    install -e .
    echo "${hash}" > "$stamp"
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
