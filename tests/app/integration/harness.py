"""Real processes for integration tests: a fresh PostgreSQL database, Redis, the web server, workers.

Everything runs on loopback. Each run creates its own database ``gcps_test_<hex>`` (a copy of one
migrated once per pytest run and shared by its xdist workers) and its own Celery queue, and removes
the database afterwards, so runs do not interfere with each other or with a developer's instance.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
import requests

from tests.processes import free_port
from tests.shared_run import RUN_FOLDER_ENV  # :func:`migrated_template` keeps its lock and record there

if TYPE_CHECKING:
    import psycopg

ROOT = Path(__file__).resolve().parents[3]
PG_ADMIN_URL = os.environ.get("GCPS_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/postgres")
REDIS_URL = os.environ.get("GCPS_TEST_REDIS_URL", "redis://127.0.0.1:6379/0")


def _unavailable(reason: str) -> None:
    if os.environ.get("GCPS_REQUIRE_INTEGRATION") or os.environ.get("CI"):
        pytest.fail(f"integration services unavailable: {reason}")
    pytest.skip(f"integration services unavailable: {reason}")


def check_services() -> None:
    import psycopg
    import redis

    try:
        with psycopg.connect(PG_ADMIN_URL, connect_timeout=3):
            pass
    except psycopg.Error as exc:
        _unavailable(f"PostgreSQL at {PG_ADMIN_URL}: {exc}")
    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=3).ping()
    except redis.RedisError as exc:
        _unavailable(f"Redis at {REDIS_URL}: {exc}")


@contextmanager
def fresh_database(*, migrated: bool = True) -> Iterator[str]:
    """A new PostgreSQL database for this run; dropped (forcibly) afterwards. Yields its URL.

    ``migrated``: a copy of :func:`migrated_template` (``CREATE DATABASE ... TEMPLATE``: 0.06 s,
    where ``manage.py migrate`` takes 3.1 s of CPU in a process of its own), else an empty database."""
    import psycopg

    name = f"gcps_test_{secrets.token_hex(6)}"
    template = f' TEMPLATE "{migrated_template()}"' if migrated else ""
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"{template}')
    try:
        yield database_url(name)
    finally:
        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def database_url(name: str) -> str:
    """The URL of the database ``name`` on the test server of :data:`PG_ADMIN_URL`."""
    return PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"


TEMPLATE_USER = "it-user"
"""The user that :func:`migrated_template` makes (the ``createuser`` command), in every copy of it."""
OTHER_TEMPLATE_USER = "it-other"
"""A second user of the template, for the tests of one user's requests beside another's."""

#: What makes the template, in one ``manage.py shell`` process (each ``manage.py`` process costs
#: about 0.5 s of CPU to start): ``migrate``, then the ``createuser`` command for each user, which
#: prints the user's token on a line of its own (``migrate`` prints nothing at verbosity 0).
MAKE_TEMPLATE = """
from django.core.management import call_command
call_command("migrate", interactive=False, verbosity=0)
for name in {users!r}:
    call_command("createuser", name)
"""

#: ``gcps_test_template_<creation time, Unix seconds>_<migrations digest>_<random>``: the only
#: databases that :func:`drop_run_templates` and the clean-up of stale templates ever drop.
TEMPLATE_NAME = re.compile(r"gcps_test_template_(\d{10})_[0-9a-f]{16}_[0-9a-f]{12}")
#: A template older than this (seconds) was left by a killed run: the next run that makes one drops it.
STALE_TEMPLATE_S = 86400

_template: str | None = None
_template_tokens: dict[str, str] = {}


def migrated_template() -> str:
    """The database that :func:`fresh_database` copies: migrated once per test RUN, by the first
    pytest-xdist worker that needs it, and shared by the others. It holds two users,
    :data:`TEMPLATE_USER` and :data:`OTHER_TEMPLATE_USER`, whose tokens :func:`template_user_token`
    gives: a test's session needs no ``manage.py createuser`` process of its own (about 0.5 s of CPU
    each); the migration and the users are made in one process (:data:`MAKE_TEMPLATE`). Nothing connects
    to it after that (PostgreSQL copies a template only while no one is connected to it; concurrent
    copies by several workers are fine).

    The workers agree through the run's folder (:data:`RUN_FOLDER_ENV`): under an fcntl lock,
    ``pg-template-<migrations digest>.json`` holds the template's name (written before it is
    created, so that it is dropped even if its maker dies) and, once made, the users' tokens; a
    worker that finds a name without a token drops that database and makes it again. The run's
    controller (or the process, without xdist) drops it at the end of the session
    (:func:`drop_run_templates`, from ``pytest_sessionfinish`` in tests/conftest.py)."""
    global _template
    if _template is None:
        from tests.shared_run import migrations_digest, run_lock

        folder = Path(os.environ[RUN_FOLDER_ENV])
        record = folder / f"pg-template-{migrations_digest()}.json"
        with run_lock(folder, "pg-template"):
            made = json.loads(record.read_text()) if record.exists() else {}
            if "token" not in made:
                made = _make_template(record, made.get("name"))
        _template = made["name"]
        _template_tokens.update(made["token"])
    return _template


def _make_template(record: Path, unfinished: str | None) -> dict[str, Any]:
    """Create and migrate the template that ``record`` names (after dropping ``unfinished``, the one
    a dead worker began, and the stale templates of killed runs); write its name and users' tokens."""
    import psycopg

    digest = record.stem.removeprefix("pg-template-")
    name = f"gcps_test_template_{int(time.time())}_{digest}_{secrets.token_hex(6)}"
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        now = time.time()
        for (existing,) in conn.execute("SELECT datname FROM pg_database").fetchall():
            match = TEMPLATE_NAME.fullmatch(existing)
            if match and (existing == unfinished or now - int(match[1]) > STALE_TEMPLATE_S):
                _drop_template(conn, existing)
        _write_atomically(record, {"name": name})
        conn.execute(f'CREATE DATABASE "{name}"')
    with tempfile.TemporaryDirectory() as scratch:
        maker = Stack(database_url(name), Path(scratch), Path(scratch))
        users = (TEMPLATE_USER, OTHER_TEMPLATE_USER)
        tokens = maker.manage("shell", "--no-imports", "-c", MAKE_TEMPLATE.format(users=users)).split()
        assert len(tokens) == len(users) and all(re.fullmatch("[0-9a-f]{40}", t) for t in tokens), tokens
        made = {"name": name, "token": dict(zip(users, tokens, strict=True))}
    _write_atomically(record, made)
    return made


def _write_atomically(path: Path, content: dict[str, Any]) -> None:
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(content))
    os.replace(partial, path)


def _drop_template(conn: psycopg.Connection, name: str) -> None:
    """Drop ``name`` if it is a template of this suite (:data:`TEMPLATE_NAME`), else nothing."""
    if TEMPLATE_NAME.fullmatch(name):
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def drop_run_templates(folder: Path) -> None:
    """Drop the templates whose records :func:`migrated_template` left in the run's folder
    ``folder``: by the run's controller, once every worker has finished (tests/conftest.py)."""
    records = sorted(folder.glob("pg-template-*.json"))
    if not records:
        return
    import psycopg

    with contextlib.suppress(psycopg.Error), psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        for record in records:
            _drop_template(conn, json.loads(record.read_text())["name"])
            record.unlink()


def template_user_token(user: str = TEMPLATE_USER) -> str:
    """The API token of ``user`` (:data:`TEMPLATE_USER` or :data:`OTHER_TEMPLATE_USER`), valid in
    every database :func:`fresh_database` copies."""
    migrated_template()
    return _template_tokens[user]


class Stack:
    """The application's processes, sharing one environment (database, queue, media folder)."""

    def __init__(
        self,
        database_url: str,
        media_root: Path,
        logs: Path,
        redis_url: str = REDIS_URL,
        extra_env: dict[str, str] | None = None,
    ) -> None:
        self.queue = f"gcps-test-{secrets.token_hex(4)}"
        self.logs = logs
        self.env = {
            **{key: value for key, value in os.environ.items() if not key.startswith(("DJANGO_", "GCPS_"))},
            "DJANGO_SETTINGS_MODULE": "metrology.settings",
            "DATABASE_URL": database_url,
            "REDIS_URL": redis_url,
            "MEDIA_ROOT": str(media_root),
            "GCPS_VAR_DIR": str(media_root.parent / "var"),
            "SECRET_KEY": secrets.token_urlsafe(50),
            "DEBUG": "0",
            "ALLOWED_HOSTS": "127.0.0.1,localhost",
            "SECURE_SSL_REDIRECT": "0",
            "GCPS_CELERY_QUEUE": self.queue,
            # tests poll the API quickly; and runs sharing a Redis must not share throttle counters
            "GCPS_THROTTLE_USER": "100000/minute",
            "GCPS_CACHE_KEY_PREFIX": self.queue,
            "GCPS_JOB_HEARTBEAT_SECONDS": "1",
            "GCPS_JOB_STALE_SECONDS": "3",
            "GCPS_JOB_SWEEP_SECONDS": "2",
            "GCPS_BROKER_VISIBILITY_TIMEOUT": "6",
            "GCPS_BROKER_RESTORE_INTERVAL": "1",
            "PYTHONUNBUFFERED": "1",
            # Celery's Django fix-up runs Django's system checks as a worker starts (0.4 s of CPU a
            # worker, most of it importing the URLconf, which no job needs); as for the web server
            # (``runserver --skip-checks``), the checks have their own test (tests/app/test_settings.py)
            "CELERY_SKIP_CHECKS": "1",
            **(extra_env or {}),  # e.g. the GCPS_S3_* settings of tests/s3.py
        }
        self.processes: list[subprocess.Popen] = []
        self.base_url = ""

    def stored_files(self, prefix: str) -> dict[str, int]:
        """``{storage name: size}`` of the stored files under ``prefix`` (a folder of the storage),
        in the media folder or, with the ``GCPS_S3_*`` settings, in the bucket."""
        bucket = self.env.get("GCPS_S3_BUCKET")
        if not bucket:
            root = Path(self.env["MEDIA_ROOT"])
            return {str(p.relative_to(root)): p.stat().st_size for p in (root / prefix).rglob("*") if p.is_file()}
        import boto3

        client = boto3.client(
            "s3",
            endpoint_url=self.env["GCPS_S3_ENDPOINT_URL"],
            aws_access_key_id=self.env["GCPS_S3_ACCESS_KEY_ID"],
            aws_secret_access_key=self.env["GCPS_S3_SECRET_ACCESS_KEY"],
            region_name=self.env["GCPS_S3_REGION"],
        )
        found = {}
        for page in client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix.rstrip("/") + "/"):
            for item in page.get("Contents", []):
                found[item["Key"]] = item["Size"]
        return found

    def manage(self, *args: str) -> str:
        result = subprocess.run(
            [sys.executable, "manage.py", *args], cwd=ROOT, env=self.env, capture_output=True, text=True, timeout=300
        )
        assert result.returncode == 0, f"manage.py {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
        return result.stdout

    def _spawn(self, name: str, args: list[str], extra_env: dict[str, str] | None = None) -> subprocess.Popen:
        log = (self.logs / f"{name}.log").open("ab")
        process = subprocess.Popen(
            args,
            cwd=ROOT,
            env={**self.env, **(extra_env or {})},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: we can kill it and its children
        )
        self.processes.append(process)
        return process

    def start_web(self, *, threaded: bool = True) -> str:
        """The development server; ``threaded=False`` serves every request on one thread, so its
        database connection is reused across requests as under a WSGI server's sync worker."""
        port = free_port()
        extra = [] if threaded else ["--nothreading"]
        self._spawn(
            "web",
            [sys.executable, "manage.py", "runserver", f"127.0.0.1:{port}", "--noreload", "--skip-checks", *extra],
        )
        return self._wait_until_serving(port, "web")

    def start_asgi(self, *, workers: int = 1) -> str:
        """The documented production web server: gunicorn with uvicorn workers on ``metrology.asgi``."""
        port = free_port()
        gunicorn = [sys.executable, "-m", "gunicorn", "metrology.asgi:application"]
        gunicorn += ["-k", "uvicorn_worker.UvicornWorker"]
        options = ["-w", str(workers), "-b", f"127.0.0.1:{port}", "--graceful-timeout", "5", "--no-control-socket"]
        self._spawn("web-asgi", [*gunicorn, *options])
        return self._wait_until_serving(port, "web-asgi")

    def _wait_until_serving(self, port: int, name: str) -> str:
        self.base_url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                requests.get(f"{self.base_url}/login/", timeout=10)
                return self.base_url
            except requests.RequestException:
                time.sleep(0.2)
        raise AssertionError(f"web server did not start; see {self.logs / (name + '.log')}")

    def start_worker(
        self,
        name: str,
        extra_env: dict[str, str] | None = None,
        pool: tuple[str, ...] = ("-P", "solo"),
        *,
        wait: bool = True,
    ) -> subprocess.Popen:
        """A Celery worker on this stack's queue; with ``wait`` (the default) returns once it is ready,
        else at once (``wait_ready`` waits later: a worker takes 1.6 s to start on a quiet machine and
        much longer on a loaded one)."""
        celery = [sys.executable, "-m", "celery", "-A", "workers", "worker", *pool, "-Q", self.queue]
        options = ["-n", f"{name}-{self.queue}@%h", "--without-gossip", "--without-mingle", "--loglevel=INFO"]
        process = self._spawn(
            name,
            [*celery, *options],
            extra_env,
        )
        if wait:
            self.wait_ready(name, process)
        return process

    def wait_ready(self, name: str, process: subprocess.Popen) -> None:
        """Wait (60 s at most) until the worker ``name`` logs that it is ready."""
        deadline = time.monotonic() + 60
        log = self.logs / f"{name}.log"
        while time.monotonic() < deadline:
            if log.exists() and b"ready." in log.read_bytes():
                return
            if process.poll() is not None:
                raise AssertionError(f"worker {name} exited: {log.read_text(errors='replace')}")
            time.sleep(0.2)
        raise AssertionError(f"worker {name} did not become ready; see {log}")

    @staticmethod
    def kill(process: subprocess.Popen) -> None:
        """SIGKILL the process and its whole process group (as a crash or the OOM killer would)."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)

    def queue_keys(self) -> list[str]:
        """The Redis lists that hold this stack's queued messages: the queue's own and kombu's one list
        per priority step (``<queue>\\x06\\x16<step>``, steps 3, 6 and 9 of the Redis transport)."""
        return [self.queue, *(f"{self.queue}\x06\x16{step}" for step in (3, 6, 9))]

    def stop(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                try:
                    os.killpg(process.pid, signal.SIGTERM)
                    process.wait(timeout=10)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    self.kill(process)
        self.processes.clear()
        import redis

        client = redis.Redis.from_url(self.env["REDIS_URL"], socket_connect_timeout=3)
        with contextlib.suppress(redis.RedisError):  # a fault test may have stopped its own Redis
            client.delete(*self.queue_keys(), f"_kombu.binding.{self.queue}", f"_kombu.binding_permanent.{self.queue}")
            # the jobs' delivery markers and the workers' liveness keys (metrology/jobs/delivery.py)
            for key in client.scan_iter(f"gcps:{self.queue}:*", count=1000):
                client.delete(key)


@contextmanager
def migrated_stack(tmp_path: Path, media_root: Path, extra_env: dict[str, str] | None = None) -> Iterator[Stack]:
    """A :class:`Stack` on a fresh, migrated database (no process started yet); stopped afterwards.
    ``extra_env``: more environment for its processes (e.g. the GCPS_S3_* settings of tests/s3.py)."""
    check_services()
    logs = tmp_path / "logs"
    logs.mkdir()
    with fresh_database() as url:
        stack = Stack(url, media_root, logs, extra_env=extra_env)
        try:
            yield stack
        finally:
            stack.stop()


class RedisServer:
    """A private ``redis-server`` on a free loopback port, without persistence, that a fault test may
    stop and restart (never the shared one). Restarting it loses every key, as a crash would."""

    def __init__(self, logs: Path) -> None:
        self.port = free_port()
        self.logs = logs
        self.process: subprocess.Popen | None = None
        self.url = f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        import redis

        log = (self.logs / f"redis-{self.port}.log").open("ab")
        self.process = subprocess.Popen(
            ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"],
            cwd=self.logs,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with contextlib.suppress(redis.RedisError):
                redis.Redis.from_url(self.url, socket_connect_timeout=1).ping()
                return
            time.sleep(0.1)
        raise AssertionError(f"redis-server on port {self.port} did not start")

    def stop(self) -> None:
        """SIGKILL: no chance to save anything."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self.process = None

    def restart(self, down_s: float = 0.0) -> None:
        self.stop()
        time.sleep(down_s)
        self.start()
