"""Uploads of capture stacks through the REST API, shared by the application tests."""

from __future__ import annotations

import io

from metrology.core.geometry.crossed_axes import Rig
from tests.app.stacks import SMALL_RIG, render_images, stack_zip


def upload(api, rig_id, data: bytes, role: str) -> int:
    """Upload the zipped stack ``data`` as a capture of ``role``; its id (the upload must succeed)."""
    handle = io.BytesIO(data)
    handle.name = f"{role}.zip"
    response = api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role}, format="multipart")
    assert response.status_code == 201, response.content
    return response.json()["id"]


def post_capture(api, rig_id: int, data: bytes, role: str):
    """Upload the zipped stack ``data`` as a capture of ``role``; the response, whatever it is."""
    handle = io.BytesIO(data)
    handle.name = f"{role}.zip"
    return api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role}, format="multipart")


def upload_heights(api, rig_id, z, role, **fields) -> dict:
    """Upload SMALL_RIG's noise-free 16-bit stack of heights ``z`` (mm) with ``fields``; the capture (JSON)."""
    handle = io.BytesIO(stack_zip(render_images(Rig.from_dict(SMALL_RIG), z, bit_depth=16)))
    handle.name = f"{role}.zip"
    response = api.post(f"/api/rigs/{rig_id}/captures/", {"file": handle, "role": role, **fields}, format="multipart")
    assert response.status_code == 201, response.content
    return response.json()


def characterize(api, rig_id: int, reference_id: int, series: list[dict], options: dict) -> dict:
    """POST a characterization of ``series`` (``[{"z_in_mm", "captures"}]``) and return it once its
    in-process job is done (the request must be accepted and the job must succeed)."""
    request = {"rig": rig_id, "reference": reference_id, "series": series, "options": options}
    response = api.post("/api/characterizations/", request, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/characterizations/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    return body
