#!/usr/bin/env bash
# Set up and run the whole test suite (core, application, integration with real PostgreSQL,
# Redis and Celery worker processes, and headless-browser tests). Extra arguments go to pytest.
# The tests run on GCPS_TEST_WORKERS pytest-xdist workers (default 4 on 2 cores: many tests wait on
# servers, workers and browsers; docs/testing.md has the measurements); GCPS_TEST_WORKERS=0 runs
# them in this one process. Tests marked xdist_group(name) run one after another on one worker.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --dev
scripts/services.sh
export PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1
# Bytecode is written and reused. With PYTHONDONTWRITEBYTECODE set (as in many container images)
# every Python process the suite starts (pytest workers, web servers, Celery workers, agents,
# commands) compiled each module it imported from source again: measured on 2 cores with nothing
# else running, a pytest worker's collection took 11-13 s of CPU instead of 6 s, a Celery worker's
# start 2.2-2.5 s instead of 1.8-1.9 s (the installed packages' bytecode present in both). The
# project's own modules are compiled here, beside ruff; installed packages' modules are written by
# the first process that imports them.
unset PYTHONDONTWRITEBYTECODE
.venv/bin/python -m compileall -q -j 0 metrology workers tests manage.py > /dev/null &
compile_pid=$!
# the compiled kernels, the stereo model's included, compiled once here (about 20 s of CPU in two
# processes on a clean clone) rather than by each pytest worker (the stereo tests of several
# workers compiled the same kernels at once) and each Celery worker started before the first had
# written numba's cache
.venv/bin/python -m metrology.core.compiled &
warm_pid=$!
# pytest's assertion-rewritten test modules, written once here rather than by each of the workers
# that start together on a fresh clone (13-14 s of CPU per worker's collection instead of 7)
.venv/bin/python -m tests.rewritten_bytecode &
rewrite_pid=$!
.venv/bin/ruff check metrology workers tests benchmarks
.venv/bin/ruff format --check metrology workers tests benchmarks
wait "$warm_pid"
wait "$compile_pid"
wait "$rewrite_pid"
# mypy (18 s of CPU on a clean clone) checks the types beside the tests, which often wait on
# servers and browsers; its verdict counts as a test's
mypy_log=$(mktemp)
.venv/bin/mypy > "$mypy_log" 2>&1 &
mypy_pid=$!
workers=${GCPS_TEST_WORKERS:-4}
status=0
if [ "$workers" = 0 ]; then
  .venv/bin/python -m pytest "$@" || status=$?
else
  .venv/bin/python -m pytest -n "$workers" --dist loadgroup --no-loadscope-reorder "$@" || status=$?
fi
mypy_status=0
wait "$mypy_pid" || mypy_status=$?
cat "$mypy_log"
rm -f "$mypy_log"
if [ "$mypy_status" != 0 ]; then
  echo "mypy failed" >&2
  [ "$status" != 0 ] || status=$mypy_status
fi
exit "$status"
