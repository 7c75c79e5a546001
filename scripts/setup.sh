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
# The stamp records what is installed: a hash of pyproject.toml, plus "[dev]" with the test extras.
# The dev install also satisfies the plain one, so switching between scripts/demo.sh and
# scripts/test.sh installs nothing until pyproject.toml changes.
stamp=.venv/.gcps-installed
extras=""
[ "${1:-}" = "--dev" ] && extras="[dev]"
hash="$(sha256sum pyproject.toml | cut -c1-16)"
have="$(cat "$stamp" 2>/dev/null || true)"
# uv installs the versions pip would (same resolution of pyproject.toml's bounds) in about a sixth
# of the time: parallel downloads, a cache shared by every clone on the machine, no bytecode
# compiled ahead (Python writes it on first import). pip is the fallback where uv cannot install.
if [ "$have" != "${hash}${extras}" ] && [ "$have" != "${hash}[dev]" ]; then
  if ! { .venv/bin/python -m pip install -qq "uv>=0.9" \
      && .venv/bin/uv pip install --quiet --python .venv/bin/python -e ".${extras}"; }; then
    echo "setup: uv could not install; installing with pip" >&2
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e ".${extras}"
  fi
  echo "${hash}${extras}" > "$stamp"
fi
