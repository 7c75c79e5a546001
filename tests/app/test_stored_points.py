"""A pinhole measurement stores the measured pixels' points and a bit mask (points.npz); the API's
points.npy is the (H, W, 3) float32 map bit for bit as measured; dense points.npy files stored before
still download, mesh and plot."""

from __future__ import annotations

import io

import numpy as np
import pytest
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage

from metrology.dashboard.selectors import measurement_figures
from metrology.measurements import derived, services
from metrology.measurements.models import Measurement
from tests.app.uploads import post_capture
from tests.conftest import logged_in
from tests.pinhole_stacks import capture_zip

pytestmark = [pytest.mark.django_db(transaction=True), pytest.mark.slow]  # a pinhole job: about 5-15 s


def download(api, measurement_id: int, filename: str) -> bytes:
    response = api.get(f"/api/measurements/{measurement_id}/{filename}")
    assert response.status_code == 200, response
    assert response["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-{filename}"'
    return b"".join(response.streaming_content)


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


@pytest.fixture
def measured(api, pinhole_rig, monkeypatch) -> tuple[int, np.ndarray]:
    """A depth measurement of a sphere on the pinhole rig and the points its job stored."""
    kept: list[np.ndarray] = []
    save = services.save_point_map

    def spy(run, prefix, points_mm):
        kept.append(points_mm.copy())
        return save(run, prefix, points_mm)

    monkeypatch.setattr(services, "save_point_map", spy)
    sphere, _truth = capture_zip("sphere")
    obj = post_capture(api, pinhole_rig["id"], sphere, "object")
    assert obj.status_code == 201, obj.content
    response = api.post("/api/measurements/", {"rig": pinhole_rig["id"], "object": obj.json()["id"]}, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    (points,) = kept
    return body["id"], points


def test_points_are_stored_compactly_and_downloaded_bit_for_bit(api, measured, media_root):
    measurement_id, points = measured
    measurement = Measurement.objects.get(pk=measurement_id)
    assert measurement.points_npy.name.endswith("/points.npz")
    data = download(api, measurement_id, "points.npy")
    assert data == npy_bytes(points)  # the bytes numpy.save writes of the measured map
    back = np.load(io.BytesIO(data))
    assert back.shape == (120, 160, 3) and back.dtype == np.float32
    assert np.array_equal(back.view(np.uint32), points.view(np.uint32))
    measured_pixels = int(np.isfinite(points).all(axis=-1).sum())
    assert measured_pixels == 16387  # of 19200
    stored = default_storage.size(measurement.points_npy.name)
    depth = default_storage.size(measurement.height_npy.name)
    assert depth == 160 * 120 * 4 + 128
    # 12 bytes a measured pixel, 1 bit a pixel, 776 bytes of headers: 2.6x the depth map (dense: 3.0x)
    assert stored == 12 * measured_pixels + 160 * 120 // 8 + 776
    assert round(stored / depth, 3) == 2.597


def figures_json(measurement: Measurement) -> dict[str, str]:
    figures, _row, _height = measurement_figures(measurement)
    return {name: figure.to_json() for name, figure in figures.items()}


def test_dense_points_stored_before_still_download_mesh_and_plot(api, measured, media_root):
    measurement_id, points = measured
    measurement = Measurement.objects.get(pk=measurement_id)
    compact_mesh = download(api, measurement_id, "mesh.ply")
    compact_figures = figures_json(measurement)
    # a result stored before this change: a dense (H, W, 3) float32 points.npy
    old = default_storage.save(f"measurements/{measurement_id}/old/points.npy", ContentFile(npy_bytes(points)))
    Measurement.objects.filter(pk=measurement_id).update(points_npy=old)
    measurement = Measurement.objects.get(pk=measurement_id)
    assert measurement.points_npy.name == old
    assert download(api, measurement_id, "points.npy") == npy_bytes(points)
    derived.clear_cache()
    assert download(api, measurement_id, "mesh.ply") == compact_mesh
    assert figures_json(measurement) == compact_figures
    page = logged_in(api.user).get(f"/measurements/{measurement_id}/")
    assert page.status_code == 200 and b"plotly" in page.content.lower()
