#!/usr/bin/env bash
# Set up and run the whole test suite (core, application, integration with real PostgreSQL,
# Redis and Celery worker processes, and headless-browser tests). Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev
scripts/services.sh
export PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1
.venv/bin/ruff check metrology workers tests benchmarks
.venv/bin/ruff format --check metrology workers tests benchmarks
.venv/bin/mypy
exec .venv/bin/python -m pytest "$@"
