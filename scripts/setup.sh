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
  .venv/bin/python -m pip install --quiet --upgrade pip
  if [ -z "$dev" ]; then
    .venv/bin/python -m pip install --quiet -e .
    echo "${hash}" > "$stamp"
  # The tests' install takes the optional STEP reader (cadquery-ocp, OpenCASCADE) in the same pip call
  # where a wheel exists for this platform (docs/testing.md: +11 s, +1.2 GB); elsewhere the STEP tests skip.
  elif .venv/bin/python -m pip install --quiet --only-binary cadquery-ocp,vtk -e ".[dev,step]"; then
    echo "${hash}[dev]+step" > "$stamp"
  else
    echo "setup.sh: no cadquery-ocp wheel for this platform: the STEP tests will be skipped" >&2
    .venv/bin/python -m pip install --quiet -e ".[dev]"
    echo "${hash}[dev]-step" > "$stamp"
  fi
fi
