"""Load benchmark: the real stack under N concurrent measurements, and under faults.

For each checkout (this one by default; ``--checkout PATH`` again for another, e.g. the commit
before a change, so both are measured in the same run on the same machine), it starts:
a fresh PostgreSQL database, its own redis-server on a free port (no persistence), two Celery
worker processes (solo pool), and a WSGI server (gunicorn if installed, else runserver); it
uploads a reference and a few object captures (realistic 8-bit stacks rendered by the virtual
rig, cached under ``~/.cache/gcps-load/``), warms the workers up, then submits N measurements
through the API and reports:

- jobs per minute (N / time from the first submit to the last job done), drain time;
- time from submit to done per job (the Job row's ``finished_at - created_at``), p50 and p95;
- API latency while loaded (GET of a measurement, p50 and p95; POST p50);
- worker CPU busy fraction (CPU seconds of the two workers / (2 x drain time));
- storage bytes per measurement (files under MEDIA_ROOT/measurements, the derived-file cache excluded);
- one measurement at a time on the warm stack (reference decoded): submit -> done, median;
- time to first byte and total time of mesh.ply / .stl / .obj of one measurement, first and second request.

``--faults`` repeats the run on this checkout with a worker killed (SIGKILL of its process group;
a replacement started at once, as a supervisor would) and with redis-server killed and restarted
empty after a third of the jobs are done, and reports jobs lost (not done within ``--fault-timeout``
seconds of the submissions), jobs attempted more than once (attempts > 1: a killed attempt and
its redelivery; the result is published once), and recovery time (from the
fault until every job that was queued or running at the fault is done).

``--embedded`` also measures one measurement at a time on the embedded default (SQLite,
in-process jobs): POST -> done, median.

    .venv/bin/python benchmarks/load.py                                  # 30 x 640x480, this checkout
    .venv/bin/python benchmarks/load.py --checkout /work/wt/base         # and another checkout, same run
    .venv/bin/python benchmarks/load.py --size 1280x1024 -n 10 --single 5 --embedded
    .venv/bin/python benchmarks/load.py --faults

PostgreSQL must accept ``GCPS_TEST_PG_URL`` (default postgresql://postgres@127.0.0.1:5432/postgres);
the shared Redis is never used. Figures are wall-clock on whatever else the machine is doing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import secrets
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import requests

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.processes import free_port, stop_group  # noqa: E402  (the checkout's own helpers)

PG_ADMIN_URL = os.environ.get("GCPS_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/postgres")
CACHE = Path(os.environ.get("GCPS_LOAD_CACHE", Path.home() / ".cache" / "gcps-load"))
OBJECT_SCENES = ("sphere", "block", "staircase")


# ----------------------------------------------------------------------------- inputs


def stacks(width: int, height: int) -> tuple[bytes, list[bytes], dict[str, Any]]:
    """Reference and object stack zips (realistic 8-bit, virtual rig), rendered once and cached."""
    sys.path.insert(0, str(ROOT))
    from metrology.core.geometry.crossed_axes import PAPER_RIG
    from metrology.core.io import write_stack
    from metrology.core.scenes import make_scene
    from metrology.core.simulate import realistic_8bit, render_stack

    rig = PAPER_RIG.with_parameters(width_px=width, height_px=height)
    folder = CACHE / f"{width}x{height}"
    folder.mkdir(parents=True, exist_ok=True)
    zips = []
    for index, scene in enumerate(("reference", *OBJECT_SCENES)):
        path = folder / f"{scene}.zip"
        if not path.exists():
            print(f"rendering {scene} at {width}x{height} (cached in {folder})", flush=True)
            rendered = render_stack(rig, make_scene(scene, rig=rig), realistic_8bit(seed=index + 1))
            write_stack(rendered.images, path)
        zips.append(path.read_bytes())
    values = {k: getattr(rig, k) for k in ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")}
    return zips[0], zips[1:], values


# ----------------------------------------------------------------------------- processes


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = (len(ordered) - 1) * q / 100
    lo, hi = int(k), min(int(k) + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (k - lo)


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process and its reaped children, seconds (/proc/PID/stat)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return 0.0
    ticks = os.sysconf("SC_CLK_TCK")
    return sum(int(fields[i]) for i in (11, 12, 13, 14)) / ticks


class Stack:
    """PostgreSQL database, redis-server, web server and workers of one checkout."""

    def __init__(self, checkout: Path, workdir: Path) -> None:
        self.checkout = checkout
        self.workdir = workdir
        self.db = f"gcps_load_{secrets.token_hex(5)}"
        self.redis_port = free_port()
        self.media = workdir / "media"
        self.logs = workdir / "logs"
        self.media.mkdir(parents=True)
        self.logs.mkdir()
        self.processes: dict[str, subprocess.Popen] = {}
        self.redis: subprocess.Popen | None = None
        self.env = {
            **{k: v for k, v in os.environ.items() if not k.startswith(("DJANGO_", "GCPS_"))},
            "PYTHONPATH": str(checkout),
            "DJANGO_SETTINGS_MODULE": "metrology.settings",
            "DATABASE_URL": PG_ADMIN_URL.rsplit("/", 1)[0] + f"/{self.db}",
            "REDIS_URL": f"redis://127.0.0.1:{self.redis_port}/0",
            "MEDIA_ROOT": str(self.media),
            "GCPS_VAR_DIR": str(workdir / "var"),
            "SECRET_KEY": secrets.token_urlsafe(50),
            "DEBUG": "0",
            "ALLOWED_HOSTS": "127.0.0.1,localhost",
            "SECURE_SSL_REDIRECT": "0",
            "GCPS_JOB_HEARTBEAT_SECONDS": "2",
            "GCPS_JOB_STALE_SECONDS": "10",
            "GCPS_JOB_SWEEP_SECONDS": "5",
            "GCPS_BROKER_VISIBILITY_TIMEOUT": "20",
            "GCPS_BROKER_RESTORE_INTERVAL": "2",
            "PYTHONUNBUFFERED": "1",
        }
        self.base = ""
        self.token = ""

    # -- lifecycle
    def start(self, workers: int = 2) -> None:
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{self.db}"')
        self.start_redis()
        self.manage("migrate", "--noinput")
        self.token = self.manage("createuser", "load").strip().split()[-1]
        self.start_web()
        for index in range(workers):
            self.start_worker(f"worker{index}")

    def stop(self) -> None:
        for process in list(self.processes.values()) + ([self.redis] if self.redis else []):
            stop_group(process)
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{self.db}" WITH (FORCE)')

    def manage(self, *args: str) -> str:
        result = subprocess.run(
            [sys.executable, "manage.py", *args],
            cwd=self.checkout,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        if result.returncode != 0:
            raise RuntimeError(f"manage.py {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}")
        return result.stdout

    def _spawn(self, name: str, args: list[str]) -> subprocess.Popen:
        log = (self.logs / f"{name}.log").open("ab")
        process = subprocess.Popen(
            args, cwd=self.checkout, env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
        )
        self.processes[name] = process
        return process

    def start_redis(self) -> None:
        """Its own redis-server (never the shared one), without persistence: a restart loses every message."""
        log = (self.logs / "redis.log").open("ab")
        self.redis = subprocess.Popen(
            ["redis-server", "--port", str(self.redis_port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"],
            cwd=self.workdir,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", self.redis_port), timeout=1):
                return
            time.sleep(0.1)
        raise RuntimeError("redis-server did not start")

    def restart_redis(self) -> None:
        assert self.redis is not None
        os.killpg(self.redis.pid, signal.SIGKILL)
        self.redis.wait(timeout=10)
        self.start_redis()

    def start_web(self) -> None:
        port = free_port()
        if shutil.which("gunicorn", path=str(Path(sys.executable).parent)):
            args = [sys.executable, "-m", "gunicorn", "metrology.wsgi", "-b", f"127.0.0.1:{port}", "-w", "2"]
            args += ["--timeout", "120"]
            self.server = "gunicorn, 2 workers"
        else:
            args = [sys.executable, "manage.py", "runserver", f"127.0.0.1:{port}", "--noreload"]
            self.server = "runserver"
        self._spawn("web", args)
        self.base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with contextlib.suppress(requests.ConnectionError):
                requests.get(f"{self.base}/api/schema/", timeout=5)
                return
            time.sleep(0.2)
        log = (self.logs / "web.log").read_text(errors="replace")[-2000:]
        raise RuntimeError(f"web server did not start:\n{log}")

    def start_worker(self, name: str) -> subprocess.Popen:
        args = [sys.executable, "-m", "celery", "-A", "workers", "worker", "-P", "solo", "-n", f"{name}-{self.db}@%h"]
        args += ["--without-gossip", "--without-mingle", "--loglevel=INFO"]
        log = self.logs / f"{name}.log"
        start = log.stat().st_size if log.exists() else 0
        process = self._spawn(name, args)
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            if log.exists() and b"ready." in log.read_bytes()[start:]:
                return process
            if process.poll() is not None:
                raise RuntimeError(f"worker {name} exited: {log.read_text(errors='replace')[-2000:]}")
            time.sleep(0.2)
        raise RuntimeError(f"worker {name} did not become ready; see {log}")

    def kill_worker(self, name: str) -> None:
        process = self.processes.pop(name)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)

    def worker_pids(self) -> list[int]:
        return [p.pid for name, p in self.processes.items() if name.startswith("worker") and p.poll() is None]

    # -- database
    def jobs(self, ids: list[int]) -> dict[int, dict[str, Any]]:
        """Measurement id -> its job's status, attempts, created_at, finished_at (epoch seconds)."""
        import psycopg

        with psycopg.connect(self.env["DATABASE_URL"]) as conn:
            rows = conn.execute(
                "SELECT m.id, j.status, j.attempts, extract(epoch from j.created_at), extract(epoch from j.finished_at)"
                " FROM measurements_measurement m JOIN jobs_job j ON j.id = m.job_id WHERE m.id = ANY(%s)",
                (ids,),
            ).fetchall()
        return {
            r[0]: {"status": r[1], "attempts": r[2], "created": float(r[3]), "finished": r[4] and float(r[4])}
            for r in rows
        }

    def stored_bytes(self) -> int:
        folder = self.media / "measurements"
        return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) if folder.exists() else 0


# ----------------------------------------------------------------------------- the client


class Client:
    def __init__(self, stack: Stack) -> None:
        self.base = stack.base
        self.session = requests.Session()
        self.session.headers["Authorization"] = f"Token {stack.token}"
        self.get_latency: list[float] = []
        self.post_latency: list[float] = []

    def post(self, path: str, **kwargs: Any) -> requests.Response:
        start = time.perf_counter()
        response = self.session.post(self.base + path, timeout=120, **kwargs)
        self.post_latency.append(time.perf_counter() - start)
        return response

    def get(self, path: str, **kwargs: Any) -> requests.Response:
        start = time.perf_counter()
        response = self.session.get(self.base + path, timeout=120, **kwargs)
        self.get_latency.append(time.perf_counter() - start)
        return response

    def setup(self, values: dict[str, Any], reference: bytes, objects: list[bytes]) -> tuple[int, int, list[int]]:
        rig = self.session.post(self.base + "/api/rigs/", json={**values, "name": "load"}, timeout=60)
        rig.raise_for_status()
        rig_id = rig.json()["id"]

        def upload(data: bytes, role: str) -> int:
            response = self.session.post(
                f"{self.base}/api/rigs/{rig_id}/captures/",
                files={"file": (f"{role}.zip", data)},
                data={"role": role},
                timeout=300,
            )
            if response.status_code != 201:
                raise RuntimeError(f"upload failed: {response.status_code} {response.text[:300]}")
            return response.json()["id"]

        return rig_id, upload(reference, "reference"), [upload(data, "object") for data in objects]

    def submit(self, rig: int, reference: int, obj: int) -> tuple[int | None, int]:
        response = self.post("/api/measurements/", json={"rig": rig, "reference": reference, "object": obj})
        return (response.json()["id"] if response.status_code == 202 else None), response.status_code


def wait_all(stack: Stack, client: Client, ids: list[int], timeout: float, poll: float = 0.5) -> dict[int, dict]:
    """Poll the API (its latency is recorded) and the Job rows until every job ends or ``timeout`` passes."""
    deadline = time.monotonic() + timeout
    state: dict[int, dict] = {}
    while time.monotonic() < deadline:
        for mid in ids[:: max(1, len(ids) // 4)]:  # a few API reads per round: latency while loaded
            with contextlib.suppress(requests.RequestException):
                client.get(f"/api/measurements/{mid}/")
        state = stack.jobs(ids)
        if all(s["status"] in ("done", "failed") for s in state.values()) and len(state) == len(ids):
            return state
        time.sleep(poll)
    return state


# ----------------------------------------------------------------------------- scenarios


def run_load(stack: Stack, args: argparse.Namespace, inputs: tuple, fault: str = "") -> dict[str, Any]:
    reference_zip, object_zips, values = inputs
    client = Client(stack)
    rig, reference, objects = client.setup(values, reference_zip, object_zips)
    # warm-up: both workers import, read and decode the reference once (two jobs at once)
    warm = [client.submit(rig, reference, objects[i % len(objects)])[0] for i in range(2)]
    wait_all(stack, client, [w for w in warm if w], 300)
    client.get_latency.clear()
    client.post_latency.clear()
    stored_before = stack.stored_bytes()

    cpu_before = {pid: cpu_seconds(pid) for pid in stack.worker_pids()}
    start = time.time()
    ids: list[int] = []
    statuses: list[int] = []
    fault_at: float | None = None
    at_fault: list[int] = []
    fault_thread = None
    if fault:

        def inject() -> None:
            nonlocal fault_at, at_fault
            while True:
                state = stack.jobs(ids) if ids else {}
                if (
                    sum(s["status"] == "done" for s in state.values()) >= max(1, args.n // 3)
                    or time.time() - start > 300
                ):
                    break
                time.sleep(0.2)
            at_fault = [m for m, s in state.items() if s["status"] in ("queued", "running")]
            fault_at = time.time()
            if fault == "kill-worker":
                stack.kill_worker("worker0")
                stack.start_worker("worker0b")
            else:
                stack.restart_redis()

        fault_thread = threading.Thread(target=inject)
        fault_thread.start()
    for i in range(args.n):
        mid, status = client.submit(rig, reference, objects[i % len(objects)])
        statuses.append(status)
        if mid is not None:
            ids.append(mid)
    state = wait_all(stack, client, ids, args.fault_timeout if fault else args.timeout)
    end = time.time()
    if fault_thread is not None:
        fault_thread.join()
    cpu_after = {pid: cpu_seconds(pid) for pid in cpu_before}
    done = [s for s in state.values() if s["status"] == "done"]
    last = max((s["finished"] for s in done), default=end)
    drain = last - start
    latencies = [s["finished"] - s["created"] for s in done]
    result: dict[str, Any] = {
        "checkout": str(stack.checkout),
        "server": stack.server,
        "n": args.n,
        "size": args.size,
        "submitted": len(ids),
        "refused": sum(1 for s in statuses if s != 202),
        "done": len(done),
        "failed": sum(1 for s in state.values() if s["status"] == "failed"),
        "jobs_per_minute": 60 * len(done) / drain if drain > 0 else None,
        "drain_s": drain,
        "submit_to_done_p50_s": percentile(latencies, 50),
        "submit_to_done_p95_s": percentile(latencies, 95),
        "api_get_p50_ms": 1000 * percentile(client.get_latency, 50),
        "api_get_p95_ms": 1000 * percentile(client.get_latency, 95),
        "api_post_p50_ms": 1000 * percentile(client.post_latency, 50),
        "worker_cpu_busy": sum(cpu_after[p] - cpu_before[p] for p in cpu_before) / (len(cpu_before) * drain)
        if not fault
        else None,
        "storage_bytes_per_measurement": (stack.stored_bytes() - stored_before) / max(1, len(done)),
    }
    if fault:
        assert fault_at is not None
        lost = [m for m in ids if state.get(m, {}).get("status") != "done"]
        pending = [state[m]["finished"] for m in at_fault if state.get(m, {}).get("status") == "done"]
        result.update(
            {
                "fault": fault,
                "fault_after_s": fault_at - start,
                "jobs_lost": len(lost),
                "jobs_attempted_more_than_once": sum(1 for s in state.values() if s["attempts"] > 1),
                "queued_or_running_at_fault": len(at_fault),
                "recovery_s": (max(pending) - fault_at) if pending and len(pending) == len(at_fault) else None,
            }
        )
        return result
    # one measurement at a time, warm worker, reference decoded: submit -> done
    singles = []
    for i in range(args.single):
        mid, _ = client.submit(rig, reference, objects[i % len(objects)])
        if mid is not None:
            s = wait_all(stack, client, [mid], 120, poll=0.05).get(mid, {})
            if s.get("status") == "done":
                singles.append(s["finished"] - s["created"])
    result["single_submit_to_done_s"] = singles
    result["single_submit_to_done_median_s"] = statistics.median(singles) if singles else None
    result["mesh_files"] = mesh_timings(client, ids[0]) if ids else {}
    return result


def mesh_timings(client: Client, measurement_id: int) -> dict[str, Any]:
    """Time to first byte and total of each mesh download, first and second request, seconds.

    A mesh not built yet answers 202 naming its job; the first request's time includes waiting for
    that job (polled every 0.1 s) and the download that follows."""
    out: dict[str, Any] = {}
    for name in ("mesh.ply", "mesh.stl", "mesh.obj"):
        for attempt in ("first", "second"):
            start = time.perf_counter()
            path = f"{client.base}/api/measurements/{measurement_id}/{name}"
            pending = client.session.get(path, stream=True)
            while pending.status_code == 202:
                job_url = client.base + pending.headers["Location"]
                while client.session.get(job_url).json()["status"] not in ("done", "failed"):
                    time.sleep(0.1)
                pending = client.session.get(path, stream=True)
            pending.close()
            with client.session.get(path, stream=True) as r:
                if r.status_code != 200:
                    out[f"{name} {attempt}"] = {"status": r.status_code}
                    continue
                chunks = r.iter_content(1 << 16)
                next(chunks, b"")
                ttfb = time.perf_counter() - start
                size = 0
                for chunk in chunks:
                    size += len(chunk)
            out[f"{name} {attempt}"] = {"ttfb_s": ttfb, "total_s": time.perf_counter() - start}
    return out


def run_embedded(checkout: Path, args: argparse.Namespace) -> dict[str, Any]:
    """One measurement at a time on the embedded default (SQLite, in-process jobs), POST -> done."""
    width, height = (int(v) for v in args.size.split("x"))
    code = f"""
import io, json, os, statistics, sys, time
import django
django.setup()
from django.core.management import call_command
call_command("migrate", verbosity=0)
from rest_framework.test import APIClient
from metrology.accounts.services import create_user_with_token
from metrology.jobs.models import Job
user, token = create_user_with_token(username="load")
api = APIClient(); api.credentials(HTTP_AUTHORIZATION="Token " + token)
cache = {str(CACHE / f"{width}x{height}")!r}
values = json.loads({json.dumps(json.dumps(args._values))})
rig = api.post("/api/rigs/", {{**values, "name": "load"}}, format="json").json()["id"]
def upload(name, role):
    handle = io.BytesIO(open(os.path.join(cache, name), "rb").read()); handle.name = name
    r = api.post(f"/api/rigs/{{rig}}/captures/", {{"file": handle, "role": role}}, format="multipart")
    assert r.status_code == 201, r.content
    return r.json()["id"]
ref = upload("reference.zip", "reference"); obj = upload("sphere.zip", "object")
times = []
for i in range({args.single} + 1):
    start = time.perf_counter()
    r = api.post("/api/measurements/", {{"rig": rig, "reference": ref, "object": obj}}, format="json")
    body = api.get(f"/api/measurements/{{r.json()['id']}}/").json()
    assert body["status"] == "done", body
    if i:  # the first one warms the process and decodes the reference
        times.append(time.perf_counter() - start)
print(json.dumps(times))
"""
    with tempfile.TemporaryDirectory(prefix="gcps-load-embedded-") as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("DJANGO_", "GCPS_"))}
        env.update(
            PYTHONPATH=str(checkout),
            DJANGO_SETTINGS_MODULE="metrology.settings",
            GCPS_VAR_DIR=tmp,
            MEDIA_ROOT=str(Path(tmp) / "media"),
            ALLOWED_HOSTS="testserver,127.0.0.1,localhost",
        )
        for key in ("DATABASE_URL", "REDIS_URL", "CELERY_BROKER_URL"):
            env.pop(key, None)
        result = subprocess.run(
            [sys.executable, "-c", code], cwd=checkout, env=env, capture_output=True, text=True, timeout=1800
        )
    if result.returncode != 0:
        return {"checkout": str(checkout), "error": result.stderr[-1500:]}
    times = json.loads(result.stdout.strip().splitlines()[-1])
    return {"checkout": str(checkout), "embedded_post_to_done_s": times, "median_s": statistics.median(times)}


def print_result(result: dict[str, Any]) -> None:
    for key, value in result.items():
        if isinstance(value, float):
            value = round(value, 3)
        elif isinstance(value, list):
            value = [round(v, 3) for v in value]
        elif isinstance(value, dict):
            value = {
                k: {kk: round(vv, 3) for kk, vv in v.items()} if isinstance(v, dict) else v for k, v in value.items()
            }
        print(f"  {key:34s} {value}")
    sys.stdout.flush()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-n", type=int, default=30, help="measurements submitted at once (default 30)")
    parser.add_argument("--size", default="640x480", choices=("640x480", "1280x1024"), help="frame size")
    parser.add_argument("--checkout", action="append", type=Path, default=[], help="another checkout to run too")
    parser.add_argument("--only-checkouts", action="store_true", help="run only the --checkout trees, not this one")
    parser.add_argument("--single", type=int, default=5, help="one-at-a-time measurements after the load (default 5)")
    parser.add_argument("--faults", action="store_true", help="also kill a worker, and restart Redis, mid-run")
    parser.add_argument("--embedded", action="store_true", help="also time single measurements on the embedded default")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for the jobs (default 600)")
    parser.add_argument(
        "--fault-timeout", type=float, default=180.0, help="seconds to wait for the jobs of a fault run (default 180)"
    )
    parser.add_argument("--json", type=Path, help="write every result to this JSON file")
    args = parser.parse_args()
    if args.n < 1:
        parser.error(f"-n must be at least 1, got {args.n}")
    width, height = (int(v) for v in args.size.split("x"))
    inputs = stacks(width, height)
    args._values = inputs[2]
    checkouts = ([] if args.only_checkouts else [ROOT]) + [c.resolve() for c in args.checkout]
    for checkout in checkouts:
        if not (checkout / "manage.py").is_file():
            parser.error(f"--checkout {checkout}: no manage.py there")
    results = []
    scenarios = [(c, "") for c in checkouts] + ([(ROOT, "kill-worker"), (ROOT, "restart-redis")] if args.faults else [])
    for checkout, fault in scenarios:
        print(f"\n== {checkout} {fault or 'steady load'}: {args.n} x {args.size}", flush=True)
        with tempfile.TemporaryDirectory(prefix="gcps-load-") as tmp:
            stack = Stack(checkout, Path(tmp))
            try:
                stack.start()
                result = run_load(stack, args, inputs, fault)
            finally:
                stack.stop()
        print_result(result)
        results.append(result)
    if args.embedded:
        for checkout in checkouts:
            print(f"\n== {checkout} embedded default: one {args.size} measurement at a time", flush=True)
            result = run_embedded(checkout, args)
            print_result(result)
            results.append(result)
    steady = [r for r in results if "jobs_per_minute" in r and not r.get("fault")]
    if len(steady) > 1 and steady[0]["drain_s"]:
        for other in steady[1:]:
            ratio = other["drain_s"] / steady[0]["drain_s"]
            print(f"\ndrain time {other['checkout']} / {steady[0]['checkout']}: {ratio:.2f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
