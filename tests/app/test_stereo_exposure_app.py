"""A stereo rig's multi-exposure capture through the application (issues 24 and 26, docs/exposures.md
"Stereo rigs"): the upload of ``exposures.json`` + ``cam0/exp0/`` ... ``cam1/exp2/`` is stored with
its exposures (refused naming the camera and the exposure when one is missing), measured by the one
measurement job (points on camera 0's grid against the virtual rig's truth, which exposure measured
each point, each camera's pixels per exposure), and its capture page shows the per-exposure
coverage of camera 0. Noise-free 16-bit renders of the 160x120 stereo rig of tests/app."""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from django.test import Client

from metrology.core.codecs.stack import write_camera_stacks
from metrology.core.scenes import make_scene
from metrology.core.simulate.exposures import render_stereo_exposures
from tests.app.stereo_stacks import RIG, upload_file
from tests.core.exposure_scene import EXPOSURES
from tests.stereo_rig import PLACEMENT, PROJECTOR, codec, facing_both

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.xdist_group("stereo_app")]

SCENE = make_scene("plane", z_mm=0.0)


@pytest.fixture(scope="module")
def rendered():
    return render_stereo_exposures(RIG, SCENE, EXPOSURES, codec("u"), placement=PLACEMENT, projector=PROJECTOR)


def _zip(stacks) -> bytes:
    with tempfile.TemporaryDirectory(prefix="gcps-stereo-hdr-") as tmp:
        return write_camera_stacks(stacks, Path(tmp) / "capture.zip", codec("u")).read_bytes()


def _post(api, rig_id: int, data: bytes):
    form = {"file": upload_file(data, "object.zip"), "role": "object"}
    return api.post(f"/api/rigs/{rig_id}/captures/", form, format="multipart")


def _fetch(api, url: str) -> np.ndarray:
    return np.load(io.BytesIO(b"".join(api.get(url).streaming_content)))


def test_a_stereo_multi_exposure_capture_is_stored_measured_and_shown(api, rendered):
    rig = api.post("/api/rigs/", {**RIG.to_dict(), "name": "stereo hdr"}, format="json").json()
    data = _zip(rendered.stacks)
    # an exposure missing in camera 1: refused naming the camera and the exposure, nothing stored
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w") as dst:
        for name in src.namelist():
            if not name.startswith("cam1/exp1/"):
                dst.writestr(name, src.read(name))
    refused = _post(api, rig["id"], out.getvalue())
    assert refused.status_code == 400, refused.content
    assert "camera 1" in refused.json()["error"] and "exp1" in refused.json()["error"]

    response = _post(api, rig["id"], data)
    assert response.status_code == 201, response.content
    capture = response.json()
    assert [e["name"] for e in capture["exposures"]] == ["exp0", "exp1", "exp2"]
    assert (capture["width_px"], capture["height_px"], capture["bit_depth"]) == (160, 120, 16)

    started = api.post("/api/measurements/", {"rig": rig["id"], "object": capture["id"]}, format="json")
    assert started.status_code == 202, started.content
    body = api.get(f"/api/measurements/{started.json()['id']}/").json()
    assert body["status"] == "done", body
    points = _fetch(api, f"/api/measurements/{body['id']}/points.npy").astype(np.float64)
    truth = rendered.points_mm
    judged = facing_both(SCENE, truth) & np.isfinite(points).all(axis=-1)
    assert judged.sum() > 0.9 * facing_both(SCENE, truth).sum()
    error = np.linalg.norm(points - truth, axis=-1)[judged]
    assert np.median(error) <= 1e-3 and np.percentile(error, 99) <= 5e-3
    stats = body["statistics"]
    exposure = _fetch(api, f"/api/measurements/{body['id']}/exposure.npy")
    measured = np.isfinite(points).all(axis=-1)
    assert np.array_equal(exposure == 255, ~measured)
    counts = stats["points_per_exposure"]
    assert counts == {name: int((exposure == i).sum()) for i, name in enumerate(("exp0", "exp1", "exp2"))}
    assert all(count > 0 for count in counts.values())
    cam1 = stats["camera_pixels_per_exposure"]["cam1"]
    assert sum(cam1.values()) == 160 * 120 and cam1["exp0"] > 0 and cam1["exp2"] > 0

    # the capture page: the exposures and camera 0's pixels per exposure
    client = Client()
    client.force_login(api.user)
    html = client.get(f"/captures/{capture['id']}/").content.decode()
    assert 'id="h-exposures"' in html and "exp0 (1000 µs)" in html, html[:2000]
    assert "could not be decoded" not in html
