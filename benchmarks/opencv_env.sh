#!/usr/bin/env bash
# Create (idempotently) the separate environment for the OpenCV baseline of the
# decode benchmark.  opencv-contrib-python-headless ships its own `cv2`, which
# would shadow the plain opencv-python-headless of the project's .venv, so it
# lives in a venv of its own: benchmarks/.venv-opencv-contrib (git-ignored).
#
# Usage:  bash benchmarks/opencv_env.sh        -> prints the venv's python path
# Then:   "$(bash benchmarks/opencv_env.sh)" benchmarks/opencv_baseline.py --width 1280 --height 1024
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$HERE/.venv-opencv-contrib"
PY="$VENV/bin/python"
PYTHON="${PYTHON:-python3}"

if [ ! -x "$PY" ]; then
    "$PYTHON" -m venv "$VENV" >&2
fi

# Install only if the two packages are not importable yet (keeps reruns fast).
if ! "$PY" -c "import numpy, cv2, cv2.structured_light" >/dev/null 2>&1; then
    "$PY" -m pip install --quiet --upgrade pip >&2
    "$PY" -m pip install --quiet numpy opencv-contrib-python-headless >&2
    "$PY" -c "import numpy, cv2, cv2.structured_light" >&2
fi

echo "$PY"
