"""Configuration from the environment: strict parsers, the embedded default, production checks."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PRODUCTION = {
    "DATABASE_URL": "postgres://gcps:secret@db:5432/gcps",
    "REDIS_URL": "redis://redis:6379/0",
    "SECRET_KEY": "k" * 20 + "Zq8#vN2!pLx7@rT4$wY9^mB3&cF6*hJ1",
    "ALLOWED_HOSTS": "gcps.example.org",
}


def run_python(code: str, env: dict[str, str], tmp_path: Path) -> subprocess.CompletedProcess:
    clean = {key: value for key, value in os.environ.items() if not key.startswith(("DJANGO", "GCPS", "DATABASE"))}
    clean.pop("REDIS_URL", None)
    clean.pop("CELERY_BROKER_URL", None)
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env={**clean, "GCPS_VAR_DIR": str(tmp_path / "var"), "DJANGO_SETTINGS_MODULE": "metrology.settings", **env},
        capture_output=True,
        text=True,
        timeout=120,
    )


SHOW = "import django; django.setup(); from django.conf import settings as s; print({})"


@pytest.mark.slow
def test_embedded_default_uses_sqlite_local_media_and_in_process_tasks(tmp_path):
    result = run_python(
        SHOW.format(
            "s.DATABASES['default']['ENGINE'], s.CELERY_TASK_ALWAYS_EAGER, s.DEBUG, s.MEDIA_ROOT, "
            "s.DATABASES['default']['CONN_MAX_AGE']"
        ),
        {},
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    # connections kept for the next request of their thread, as with DATABASE_URL (60 s under WSGI)
    assert result.stdout.strip() == f"django.db.backends.sqlite3 True True {tmp_path / 'var' / 'media'} 60"


@pytest.mark.slow
def test_production_settings_use_postgres_and_redis(tmp_path):
    result = run_python(
        SHOW.format("s.DATABASES['default']['ENGINE'], s.CELERY_TASK_ALWAYS_EAGER, s.DEBUG, s.CELERY_BROKER_URL"),
        PRODUCTION,
        tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "django.db.backends.postgresql False False redis://redis:6379/0"


@pytest.mark.slow
def test_check_deploy_is_clean_in_production(tmp_path):
    result = run_python(
        "import sys; from django.core.management import execute_from_command_line as run; "
        "run(['manage.py', 'check', '--deploy', '--fail-level', 'WARNING'])",
        PRODUCTION,
        tmp_path,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "System check identified no issues" in result.stdout


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"DEBUG": "maybe"}, "DEBUG must be one of"),
        ({"GCPS_MAX_UPLOAD_BYTES": "lots"}, "GCPS_MAX_UPLOAD_BYTES must be an integer, got 'lots'"),
        ({"GCPS_MAX_UPLOAD_BYTES": "0"}, "GCPS_MAX_UPLOAD_BYTES must be at least 1"),
        ({"DEBUG": "1", "DATABASE_URL": "mysql://x"}, "DATABASE_URL must start with one of"),
        ({"DEBUG": "1", "REDIS_URL": "localhost:6379"}, "REDIS_URL must start with one of redis, rediss://"),
        ({**PRODUCTION, "SECRET_KEY": ""}, "SECRET_KEY must be set when DEBUG is off"),
        ({**PRODUCTION, "SECRET_KEY": "short"}, "SECRET_KEY must be at least 50 characters"),
        ({"ALLOWED_HOSTS": " , "}, "ALLOWED_HOSTS must be a comma-separated list"),
    ],
)
def test_bad_environment_names_the_variable(tmp_path, env, message):
    result = run_python(SHOW.format("1"), env, tmp_path)
    assert result.returncode != 0
    assert "ImproperlyConfigured" in result.stderr and message in result.stderr, result.stderr[-2000:]


def test_upload_limit_defaults_to_512_mb(settings):
    assert settings.GCPS_MAX_UPLOAD_BYTES == 512 * 1024 * 1024 or "GCPS_MAX_UPLOAD_BYTES" in os.environ


@pytest.mark.django_db
def test_the_embedded_database_runs_in_wal_mode_with_normal_sync():
    """WAL (readers beside a writer) with ``synchronous=NORMAL`` (1): commits are not synced one by
    one (docs/operations.md, "On the embedded default")."""
    from django.db import connection

    if connection.vendor != "sqlite":
        pytest.skip("the embedded default's SQLite options; this run uses DATABASE_URL")
    with connection.cursor() as cursor:
        assert cursor.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert cursor.execute("PRAGMA synchronous").fetchone()[0] == 1
