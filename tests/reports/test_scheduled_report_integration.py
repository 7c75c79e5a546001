"""A report schedule on the real stack: celery beat (DatabaseScheduler) + a celery worker on Redis + PostgreSQL.

Run with ``pytest -m integration``; needs PostgreSQL and Redis on loopback (tests/app/integration/harness.py
makes a fresh database and queue per run and removes them afterwards).
"""

from __future__ import annotations

import json
import re
import sys
import time

import pytest

from tests.app.integration.harness import Stack, check_services, fresh_database
from tests.app.stacks import SMALL_RIG

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SETUP = """
import json
from metrology.accounts.services import create_user_with_token
from metrology.reports.services import schedule_report
from metrology.rigs.services import create_rig
owner, _ = create_user_with_token(username="beat-test")
rig = create_rig(owner=owner, data={rig})
task = schedule_report(rig, every_s=3, source="virtual_stage", options={options})
print("RESULT " + json.dumps({{"rig": rig.pk, "task": task.pk}}))
"""
OPTIONS = {"z_start_mm": 0.0, "z_stop_mm": 16.0, "z_step_mm": 8.0, "repeats": 2}


class BeatStack(Stack):
    def start_beat(self):
        """``celery -A workers beat`` with the settings' scheduler (django-celery-beat's DatabaseScheduler)."""
        return self._spawn("beat", [sys.executable, "-m", "celery", "-A", "workers", "beat", "--loglevel=INFO"])


def finished_reports(database_url: str) -> list[tuple]:
    import psycopg

    with psycopg.connect(database_url) as conn:
        return conn.execute(
            "SELECT r.id, r.html, r.summary, j.status, j.error FROM reports_report r "
            "JOIN jobs_job j ON j.id = r.job_id WHERE j.status IN ('done', 'failed') ORDER BY r.id"
        ).fetchall()


def test_beat_schedule_makes_a_worker_store_a_report(tmp_path, media_root):
    check_services()
    media, logs = media_root, tmp_path / "logs"  # media_root: the conftest's fresh folder
    logs.mkdir()
    with fresh_database() as database_url:
        stack = BeatStack(database_url, media, logs)
        try:
            code = SETUP.format(rig=repr({**SMALL_RIG, "name": "beat rig"}), options=repr(OPTIONS))
            made = json.loads(re.search(r"^RESULT (.*)$", stack.manage("shell", "-c", code), re.M).group(1))
            stack.start_worker("worker-reports")
            beat = stack.start_beat()

            started = time.monotonic()
            rows: list[tuple] = []
            while time.monotonic() - started < 90 and not rows:
                assert beat.poll() is None, (logs / "beat.log").read_text(errors="replace")
                rows = finished_reports(database_url)
                time.sleep(0.5)
            elapsed = time.monotonic() - started
            assert rows, f"no report after {elapsed:.0f} s; logs: {sorted(p.name for p in logs.iterdir())}"
            report_id, html_name, summary, status, error = rows[0]
            assert status == "done", error
            html = (media / html_name).read_text(encoding="utf-8")
            assert "Plotly.newPlot" in html and not re.search(r"<script[^>]*\bsrc\s*=", html, re.I)
            assert summary["rig"]["id"] == made["rig"] and summary["positions"]["z_in_mm"] == [0.0, 8.0, 16.0]

            beat_log = (logs / "beat.log").read_text(errors="replace")
            assert "DatabaseScheduler" in beat_log
            assert "Scheduler: Sending due task characterization report of rig" in beat_log
            worker_log = (logs / "worker-reports.log").read_text(errors="replace")
            assert "metrology.reports.tasks.scheduled_characterization_report" in worker_log
            print(f"report {report_id} stored {elapsed:.1f} s after beat started: {html_name}")
        finally:
            stack.stop()
