#!/usr/bin/env bash
# Set up and run the demo on the embedded default (SQLite, files under var/, tasks in-process):
# a virtual rig, simulated captures, a measurement, a calibration and a characterization,
# then the server on http://127.0.0.1:${PORT:-8000}/ (log in as "demo", password "demo").
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
.venv/bin/python manage.py migrate --noinput
.venv/bin/python manage.py demo
exec .venv/bin/python manage.py runserver "127.0.0.1:${PORT:-8000}"
