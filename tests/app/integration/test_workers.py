"""End to end on the real stack: HTTP API -> PostgreSQL -> Redis -> Celery worker process -> results.

Run with ``pytest -m integration``; needs PostgreSQL and Redis on loopback (see harness.py).
"""

from __future__ import annotations

import io
import struct
import time

import numpy as np
import pytest

from tests.app.integration.harness import Stack
from tests.app.integration.helpers import (
    RIG,
    authenticated,
    download,
    finished,
    simulated_zip,
    upload,
    url,
    wait_for,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: The tests on the conftest's ``module_stack``: one pytest-xdist worker runs them, so that the stack
#: is started once (tests/conftest.py groups only the tests of a module's own module-scoped fixtures).
ON_MODULE_STACK = pytest.mark.xdist_group("integration-workers-module-stack")


def ply_vertex_count(data: bytes) -> int:
    header = data[: data.index(b"end_header")].decode("ascii")
    assert header.startswith("ply\nformat binary")
    return int(next(line.split()[2] for line in header.splitlines() if line.startswith("element vertex")))


@ON_MODULE_STACK
def test_measurement_through_api_redis_and_a_worker_process(module_stack: Stack):
    """On the module's running worker (``module_stack``): the test needs a worker, not a fresh one."""
    stack, http = module_stack, authenticated(module_stack)
    rig = http.post(url(http, "/api/rigs/"), json=RIG)
    assert rig.status_code == 201, rig.text
    rig_id = rig.json()["id"]
    reference_zip, _ = simulated_zip("reference")
    object_zip, truth = simulated_zip("block", top_mm=30.0, size_x_mm=200.0, size_y_mm=150.0)
    reference = upload(http, rig_id, reference_zip, "reference")
    obj = upload(http, rig_id, object_zip, "object")

    started = http.post(url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj})
    assert started.status_code == 202, started.text
    measurement_id = started.json()["id"]
    body = wait_for(http, f"/api/measurements/{measurement_id}/", finished)
    assert body["status"] == "done", body
    assert body["progress"] == 100 and body["error"] == ""
    assert body["statistics"]["valid_fraction"] > 0.5

    response = http.get(url(http, f"/api/measurements/{measurement_id}/height.npy"))
    assert response.status_code == 200
    z = np.load(io.BytesIO(response.content))
    assert z.shape == truth.shape == (240, 320)
    both = np.isfinite(z) & np.isfinite(truth)
    assert both.mean() > 0.5
    error = np.abs(z[both] - truth[both])
    # noise-free 16-bit: heights within a few micrometres except at the block's edges
    assert np.median(error) < 0.005, np.median(error)
    assert np.percentile(error, 95) < 0.05, np.percentile(error, 95)

    mesh = download(http, f"/api/measurements/{measurement_id}/mesh.ply")
    assert mesh.status_code == 200 and ply_vertex_count(mesh.content) > 0.5 * both.sum()
    stl = download(http, f"/api/measurements/{measurement_id}/mesh.stl")
    assert stl.status_code == 200
    (triangles,) = struct.unpack("<I", stl.content[80:84])
    assert len(stl.content) == 84 + 50 * triangles and triangles > 0

    # a duplicate delivery of a done job is acknowledged and not recomputed
    from redis import Redis

    job_id = body["job"]
    job_before = http.get(url(http, f"/api/jobs/{job_id}/")).json()
    _send_task(stack, job_id)
    time.sleep(2)
    job_after = http.get(url(http, f"/api/jobs/{job_id}/")).json()
    assert job_after["attempts"] == job_before["attempts"] == 1
    assert job_after["finished_at"] == job_before["finished_at"]
    assert Redis.from_url(stack.env["REDIS_URL"]).llen(stack.queue) == 0


def _send_task(stack, job_id: int) -> None:
    from celery import Celery

    app = Celery(broker=stack.env["REDIS_URL"])
    app.send_task("workers.tasks.run_job", args=[job_id], queue=stack.queue)
    app.close()


@ON_MODULE_STACK
def test_simulated_capture_is_rendered_by_the_worker(module_stack: Stack):
    http = authenticated(module_stack)
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    response = http.post(
        url(http, f"/api/rigs/{rig_id}/captures/simulate/"),
        json={"role": "stage", "z_in_mm": 8.0, "scene": {"name": "stage"}, "options": {"bit_depth": 8, "seed": 3}},
    )
    assert response.status_code == 202, response.text
    capture = response.json()
    assert capture["status"] in ("queued", "running", "stored") and capture["job"]
    body = wait_for(http, f"/api/captures/{capture['id']}/", lambda b: b["status"] in ("stored", "failed"))
    assert body["status"] == "stored", http.get(url(http, f"/api/jobs/{capture['job']}/")).json()
    assert (body["height_px"], body["width_px"], body["bit_depth"]) == (240, 320, 8)
    assert len(body["checksum_sha256"]) == 64


def test_killed_worker_mid_job_then_a_new_worker_finishes_it(stack, http):
    # The first worker pauses 1.5 s between phases so that it is surely killed mid-job.
    first = stack.start_worker("worker-1", {"GCPS_JOB_PHASE_PAUSE_MS": "1500"})
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    reference = upload(http, rig_id, simulated_zip("reference")[0], "reference")
    object_zip, truth = simulated_zip("sphere", radius_mm=80.0)
    obj = upload(http, rig_id, object_zip, "object")
    measurement_id = http.post(
        url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj}
    ).json()["id"]

    running = wait_for(
        http, f"/api/measurements/{measurement_id}/", lambda b: b["status"] == "running" and b["progress"] >= 20
    )
    stack.kill(first)
    killed_at = time.monotonic()
    # nothing half-written is visible: no result file is served, the job is still "running"
    after_kill = http.get(url(http, f"/api/measurements/{measurement_id}/")).json()
    assert after_kill["status"] == "running" and after_kill["files"] == {}, (running, after_kill)
    assert http.get(url(http, f"/api/measurements/{measurement_id}/height.npy")).status_code == 404

    # a new worker takes it over once the heartbeat is stale (startup sweep or redelivered message)
    time.sleep(max(0.0, 4.0 - (time.monotonic() - killed_at)))
    stack.start_worker("worker-2")
    body = wait_for(http, f"/api/measurements/{measurement_id}/", finished, timeout=120)
    job = http.get(url(http, f"/api/jobs/{body['job']}/")).json()
    if body["status"] == "failed":  # allowed by the contract, but it must say why
        assert body["error"], body
        return
    assert job["attempts"] == 2, job
    z = np.load(io.BytesIO(http.get(url(http, f"/api/measurements/{measurement_id}/height.npy")).content))
    both = np.isfinite(z) & np.isfinite(truth)
    assert np.median(np.abs(z[both] - truth[both])) < 0.005
    # only the finishing attempt's files remain under the measurement's folder
    stored = stack.stored_files(f"measurements/{measurement_id}")
    attempts = {name.rsplit("/", 2)[1] for name in stored if name.endswith(".npy")}
    assert len(attempts) == 1, attempts
    time.sleep(3)  # the original message comes back after the visibility timeout: it must not rerun the job
    again = http.get(url(http, f"/api/jobs/{body['job']}/")).json()
    assert again["attempts"] == 2 and again["status"] == "done" and again["finished_at"] == job["finished_at"]


def test_killed_pool_process_is_requeued_and_the_job_finishes(stack, http):
    """A prefork child killed mid-job (as by the OOM killer or the hard time limit): reject_on_worker_lost."""
    import psutil

    worker = stack.start_worker(
        "worker-prefork", {"GCPS_JOB_PHASE_PAUSE_MS": "1500"}, pool=("-P", "prefork", "--concurrency", "1")
    )
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    reference = upload(http, rig_id, simulated_zip("reference")[0], "reference")
    obj = upload(http, rig_id, simulated_zip("plane", z_mm=20.0)[0], "object")
    measurement_id = http.post(
        url(http, "/api/measurements/"), json={"rig": rig_id, "reference": reference, "object": obj}
    ).json()["id"]
    wait_for(http, f"/api/measurements/{measurement_id}/", lambda b: b["status"] == "running" and b["progress"] >= 20)
    children = psutil.Process(worker.pid).children()
    assert len(children) == 1
    children[0].kill()
    body = wait_for(http, f"/api/measurements/{measurement_id}/", finished, timeout=120)
    assert body["status"] == "done", body
    job = http.get(url(http, f"/api/jobs/{body['job']}/")).json()
    assert job["attempts"] == 2, job
    z = np.load(io.BytesIO(http.get(url(http, f"/api/measurements/{measurement_id}/height.npy")).content))
    assert abs(float(np.nanmedian(z)) - 20.0) < 0.01
