"""Shared by the integration tests: the rig they upload to, simulated captures, and the HTTP calls to
the running stack (uploads, polling a resource until it is done)."""

from __future__ import annotations

import functools
import tempfile
import time
from pathlib import Path

import numpy as np
import requests

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import write_stack
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack
from tests.app.integration.harness import template_user_token
from tests.app.stacks import SMALL_RIG

# Bigger than the unit tests' rig so that the measurement (with meshes) takes a moment.
RIG = {**SMALL_RIG, "width_px": 320, "height_px": 240, "name": "integration"}


@functools.cache
def simulated_zip(scene: str, **params) -> tuple[bytes, np.ndarray]:
    """A noise-free 16-bit stack of ``scene`` rendered by the core's simulator, and its truth heights
    (read-only: made once per process for each scene and parameters, as most tests upload the same
    reference and planes; the zip's writing alone is 0.03 s of CPU, a sphere's render 0.26 s)."""
    rig = Rig.from_dict({key: RIG[key] for key in SMALL_RIG})
    rendered = render_stack(rig, make_scene(scene, rig=rig, **params), SimulationOptions(bit_depth=16, seed=1))
    truth = np.array(rendered.truth_mm)
    truth.flags.writeable = False
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "stack.zip"
        write_stack(rendered.images, path)
        return path.read_bytes(), truth


def authenticated(stack) -> requests.Session:
    """An HTTP session on ``stack`` with the token of the user its database was copied with
    (``manage.py createuser`` in the template: :func:`harness.template_user_token`)."""
    key = template_user_token()
    session = requests.Session()
    session.headers["Authorization"] = f"Token {key}"
    session.base = stack.base_url  # type: ignore[attr-defined]
    return session


def measurement_inputs(http, scene: str = "plane", **params) -> tuple[int, int, int]:
    """A rig and its reference and object captures, uploaded through the API: (rig, reference, object)."""
    rig_id = http.post(url(http, "/api/rigs/"), json=RIG).json()["id"]
    reference = upload(http, rig_id, simulated_zip("reference")[0], "reference")
    obj = upload(http, rig_id, simulated_zip(scene, **params)[0], "object")
    return rig_id, reference, obj


def url(http, path: str) -> str:
    return http.base + path


def upload(http, rig_id: int, data: bytes, role: str) -> int:
    response = http.post(
        url(http, f"/api/rigs/{rig_id}/captures/"), files={"file": (f"{role}.zip", data)}, data={"role": role}
    )
    assert response.status_code == 201, response.text
    return response.json()["id"]


def wait_for(http, path: str, done, timeout: float = 120.0, interval: float = 0.25) -> dict:
    deadline = time.monotonic() + timeout
    body: dict = {}
    while time.monotonic() < deadline:
        body = http.get(url(http, path)).json()
        if done(body):
            return body
        time.sleep(interval)
    raise AssertionError(f"timed out waiting on {path}: {body}")


def finished(body: dict) -> bool:
    return body["status"] in ("done", "failed")


def download(http, path: str, timeout: float = 120.0, **kwargs):
    """GET a result file, as a client does: while it answers 202 (a derived file being built), poll
    the job it names until done, then ask again; redirects (S3 presigned URLs) are followed."""
    deadline = time.monotonic() + timeout
    while True:
        response = http.get(url(http, path), **kwargs)
        if response.status_code != 202:
            return response
        assert response.headers["Location"] == response.json()["job_url"]
        job = wait_for(http, response.headers["Location"], finished, timeout=max(1.0, deadline - time.monotonic()))
        assert job["status"] == "done", job
