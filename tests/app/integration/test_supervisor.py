"""The topology without containers (issue 23 item 2): ``deploy/supervisord.conf`` as shipped runs the
web server (gunicorn + uvicorn workers), a Celery worker and beat on a private ``redis-server`` and a
fresh PostgreSQL database; a worker SIGKILLed mid-job comes back by itself and the job ends done."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests

from tests.app.integration.harness import ROOT, RedisServer, Stack, check_services, free_port, fresh_database
from tests.app.integration.helpers import authenticated, finished, measurement_inputs, url, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow]

CONF = ROOT / "deploy" / "supervisord.conf"
BIN = Path(sys.executable).parent


class Supervisor:
    def __init__(self, env: dict[str, str], run_dir: Path) -> None:
        self.env = env
        self.run_dir = run_dir
        log = (run_dir / "supervisord.out").open("ab")
        self.process = subprocess.Popen(
            [str(BIN / "supervisord"), "-n", "-c", str(CONF)],
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    def ctl(self, *args: str) -> str:
        result = subprocess.run(
            [str(BIN / "supervisorctl"), "-c", str(CONF), *args], env=self.env, capture_output=True, text=True
        )
        return result.stdout

    def pid(self, name: str) -> int:
        text = self.ctl("pid", name).strip()
        return int(text) if text.isdigit() else 0

    def status(self) -> dict[str, str]:
        rows = (line.split() for line in self.ctl("status").splitlines())
        return {row[0]: row[1] for row in rows if len(row) >= 2}

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)  # supervisord stops its programs, then exits
            try:
                self.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout=10)

    def log(self, name: str) -> str:
        path = self.run_dir / f"{name}.log"
        return path.read_text(errors="replace") if path.exists() else ""


@pytest.fixture
def supervised(tmp_path, media_root) -> Iterator[tuple[Stack, Supervisor]]:
    check_services()
    logs = tmp_path / "logs"
    logs.mkdir()
    redis_server = RedisServer(logs)  # its own port, never the shared Redis
    redis_server.start()
    supervisor: Supervisor | None = None
    try:
        with fresh_database() as database_url:
            stack = Stack(database_url, media_root, logs, redis_url=redis_server.url)
            try:
                port = free_port()
                run_dir = tmp_path / "run"
                run_dir.mkdir()
                env = {
                    **stack.env,
                    "GCPS_RUN_DIR": str(run_dir),
                    "GCPS_BIND": f"127.0.0.1:{port}",
                    "GCPS_WORKERS": "1",
                    # each phase of a job pauses, so the test can kill the worker mid-job
                    "GCPS_JOB_PHASE_PAUSE_MS": "1500",
                }
                supervisor = Supervisor(env, run_dir)
                stack.base_url = f"http://127.0.0.1:{port}"
                deadline = time.monotonic() + 120
                while time.monotonic() < deadline:
                    with contextlib.suppress(requests.RequestException):
                        if requests.get(f"{stack.base_url}/api/schema/", timeout=30).status_code == 200:
                            break
                    time.sleep(0.5)
                else:
                    raise AssertionError(f"the supervised web server did not start: {supervisor.log('web')[-3000:]}")
                yield stack, supervisor
            finally:
                if supervisor is not None:
                    supervisor.stop()
                stack.stop()
    finally:
        redis_server.stop()


def wait_until(condition, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if value := condition():
            return value
        time.sleep(0.25)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def test_a_sigkilled_worker_is_restarted_by_the_supervisor_and_its_job_ends_done(supervised):
    stack, supervisor = supervised
    worker = "gcps:worker-0"
    wait_until(lambda: "ready." in supervisor.log("worker-0"), 90, "the supervised worker")
    # supervisord calls a program RUNNING once it has stayed up for its startsecs (5 s for the
    # worker), which a worker ready sooner on a quiet machine has not yet
    running = {"gcps:beat": "RUNNING", "gcps:web": "RUNNING", worker: "RUNNING"}
    wait_until(lambda: supervisor.status() == running, 30, f"supervisord to report {running}")

    http = authenticated(stack)
    rig_id, reference, obj = measurement_inputs(http, "plane", z_mm=20.0)
    started = http.post(url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj})
    assert started.status_code == 202, started.text
    job_path = f"/api/jobs/{started.json()['job']}/"
    wait_for(http, job_path, lambda body: body["status"] == "running", timeout=60)

    first_pid = supervisor.pid(worker)
    assert first_pid > 0
    os.killpg(first_pid, signal.SIGKILL)  # the worker and its pool, as a crash or the OOM killer would
    killed_at = time.monotonic()
    second_pid = wait_until(lambda: (pid := supervisor.pid(worker)) not in (0, first_pid) and pid, 30, "a new worker")
    back_s = time.monotonic() - killed_at
    assert re.search(r"exited: worker-0 \(terminated by SIGKILL", (supervisord_log := supervisor.log("supervisord")))
    assert "spawned: 'worker-0'" in supervisord_log

    body = wait_for(http, job_path, finished, timeout=120)
    assert body["status"] == "done" and body["attempts"] == 2, body
    assert supervisor.pid(worker) == second_pid  # the restarted worker took the job over and stayed up
    print(f"worker back {back_s:.1f} s after SIGKILL; job done after {time.monotonic() - killed_at:.1f} s")
