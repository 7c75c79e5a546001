"""Derived result files: built by a job when first asked for, served from the storage with ranges.

A bounded folder of them, and the legacy stored files still served."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest
from django.core.files.base import ContentFile
from django.core.files.storage import FileSystemStorage, default_storage
from django.http import FileResponse

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.mesh import mesh_from_heights, open3d_mesh, surface_mesh
from metrology.jobs.models import Job
from metrology.measurements import derived
from metrology.measurements.derived_cache import DerivedFiles
from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload

pytestmark = pytest.mark.django_db(transaction=True)


@pytest.fixture
def measurement_id(api, rig) -> int:
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, block_heights(), bit_depth=16)), "object")
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    assert response.status_code == 202, response.content
    body = api.get(f"/api/measurements/{response.json()['id']}/").json()
    assert body["status"] == "done", body
    return body["id"]


def heights(api, measurement_id: int) -> np.ndarray:
    response = api.get(f"/api/measurements/{measurement_id}/height.npy")
    return np.load(io.BytesIO(b"".join(response.streaming_content)))


def cache_files(media_root: Path) -> list[Path]:
    folder = media_root / derived.CACHE_PREFIX
    return sorted(folder.iterdir()) if folder.is_dir() else []


def test_measurement_stores_heights_only_under_3x_the_height_map(api, measurement_id, media_root):
    body = api.get(f"/api/measurements/{measurement_id}/").json()
    stored_names = {"height.npy", "gray_only_height.npy"}
    assert set(body["files"]) == stored_names | {
        "height.tiff",
        "mesh.ply",
        "mesh.stl",
        "mesh.obj",
        "points.npy",
        "points.e57",
    }
    measurement = Measurement.objects.get(pk=measurement_id)
    assert not (measurement.mesh_ply or measurement.mesh_stl or measurement.mesh_obj or measurement.height_tiff)
    assert not measurement.points_npy  # the paper's rig: the points are the heights on the camera rays
    folder = media_root / "measurements" / str(measurement_id)
    stored = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
    float32_map = SMALL_RIG["width_px"] * SMALL_RIG["height_px"] * 4
    assert stored < 3 * float32_map, (stored, float32_map)  # two float32 maps and their .npy headers
    assert cache_files(media_root) == []


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj"])
def test_mesh_is_built_by_a_job_then_served_from_the_storage(api, measurement_id, media_root, tmp_path, fmt):
    # the tests run jobs inline (GCPS_EMBEDDED_JOBS=inline): the job is done when the request answers
    first = api.get(f"/api/measurements/{measurement_id}/mesh.{fmt}")
    assert first.status_code == 200 and isinstance(first, FileResponse), first
    assert first["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-mesh.{fmt}"'
    assert first["Accept-Ranges"] == "bytes"
    data = b"".join(first.streaming_content)
    assert int(first["Content-Length"]) == len(data)
    (cached,) = cache_files(media_root)
    assert cached.read_bytes() == data and cached.suffix == f".{fmt}"
    (job,) = Job.objects.filter(kind=Job.Kind.DERIVED_FILE)
    assert job.status == Job.Status.DONE and job.parameters["filename"] == f"mesh.{fmt}"

    second = api.get(f"/api/measurements/{measurement_id}/mesh.{fmt}")
    assert isinstance(second, FileResponse)
    assert b"".join(second.streaming_content) == data
    assert Job.objects.filter(kind=Job.Kind.DERIVED_FILE).count() == 1  # served, not built again

    # the geometry of today's mesh of the stored height map and points (open3d parses the file)
    z = heights(api, measurement_id)
    points = api.get(f"/api/measurements/{measurement_id}/points.npy")
    points_mm = np.load(io.BytesIO(b"".join(points.streaming_content)))
    mesh = open3d_mesh(surface_mesh(Rig.from_dict(SMALL_RIG), z, points_mm=points_mm))
    # the stored float32 points are the heights on the camera rays (mesh_from_heights's vertices)
    by_heights = np.asarray(mesh_from_heights(Rig.from_dict(SMALL_RIG), z).vertices)
    np.testing.assert_allclose(np.asarray(mesh.vertices), by_heights, rtol=0, atol=1e-4)
    (tmp_path / f"m.{fmt}").write_bytes(data)
    import open3d as o3d  # here: importing it costs every pytest worker a second at collection

    again = o3d.io.read_triangle_mesh(str(tmp_path / f"m.{fmt}"))
    assert len(again.triangles) == len(mesh.triangles) > 1000
    if fmt == "ply":
        np.testing.assert_array_equal(np.asarray(again.vertices), np.asarray(mesh.vertices))
        np.testing.assert_array_equal(np.asarray(again.triangles), np.asarray(mesh.triangles))
        np.testing.assert_array_equal(np.asarray(again.vertex_normals), np.asarray(mesh.vertex_normals))
    else:  # STL: float32 triangle corners; OBJ: 5 decimals; open3d may reorder vertices: compare corner sets
        expected = np.unique(np.asarray(mesh.vertices)[np.asarray(mesh.triangles)].reshape(-1, 3), axis=0)
        got = np.unique(np.asarray(again.vertices)[np.asarray(again.triangles)].reshape(-1, 3), axis=0)
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4)


def test_points_of_the_papers_rig_are_derived_from_the_heights_and_cached(api, measurement_id, media_root):
    """``points.npy`` of a crossed-axes measurement: ``(H, W, 3)`` float32 mm, exactly the heights on
    the camera rays (what a job stores for a model whose points do not follow from its heights)."""
    response = api.get(f"/api/measurements/{measurement_id}/points.npy")
    assert response.status_code == 200
    points = np.load(io.BytesIO(b"".join(response.streaming_content)))
    z = heights(api, measurement_id)
    expected = Rig.from_dict(SMALL_RIG).prepare().points_from_heights(z).astype(np.float32)
    assert points.shape == (*z.shape, 3) and points.dtype == np.float32
    np.testing.assert_array_equal(points, expected)
    assert [p.suffix for p in cache_files(media_root)] == [".npy"]
    again = api.get(f"/api/measurements/{measurement_id}/points.npy")
    assert (
        isinstance(again, FileResponse)
        and Job.objects.filter(kind=Job.Kind.DERIVED_FILE).count() == 1
        and np.array_equal(np.load(io.BytesIO(b"".join(again.streaming_content))), points, equal_nan=True)
    )


def test_tiff_is_derived_and_cached(api, measurement_id, media_root):
    import cv2

    response = api.get(f"/api/measurements/{measurement_id}/height.tiff")
    assert response.status_code == 200
    data = b"".join(response.streaming_content)
    tiff = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(tiff, heights(api, measurement_id))
    assert [p.suffix for p in cache_files(media_root)] == [".tiff"]


def test_deleted_cache_is_rebuilt_identically(api, measurement_id, media_root):
    url = f"/api/measurements/{measurement_id}/mesh.ply"
    data = b"".join(api.get(url).streaming_content)
    derived.clear_cache()
    assert cache_files(media_root) == []
    again = api.get(url)
    assert b"".join(again.streaming_content) == data
    assert len(cache_files(media_root)) == 1
    assert Job.objects.filter(kind=Job.Kind.DERIVED_FILE, status=Job.Status.DONE).count() == 2


def test_the_folder_is_bounded_and_removes_the_oldest(api, measurement_id, media_root, settings):
    base = f"/api/measurements/{measurement_id}"
    sizes = {}
    for fmt in ("ply", "stl", "obj"):
        sizes[fmt] = len(b"".join(api.get(f"{base}/mesh.{fmt}").streaming_content))
    derived.clear_cache()
    settings.GCPS_MESH_CACHE_BYTES = sizes["ply"] + sizes["stl"] + sizes["obj"] // 2  # room for two of three
    b"".join(api.get(f"{base}/mesh.ply").streaming_content)
    b"".join(api.get(f"{base}/mesh.stl").streaming_content)
    ply, stl = (p for p in cache_files(media_root) if p.suffix in (".ply", ".stl"))
    os.utime(ply, (2_000_000, 2_000_000))
    os.utime(stl, (1_000_000, 1_000_000))  # the STL is the oldest
    b"".join(api.get(f"{base}/mesh.obj").streaming_content)
    kept = {p.suffix for p in cache_files(media_root)}
    assert kept == {".ply", ".obj"}, kept  # the STL, oldest, was removed
    assert sum(p.stat().st_size for p in cache_files(media_root)) <= settings.GCPS_MESH_CACHE_BYTES


def test_a_cache_smaller_than_the_file_still_serves_it(api, measurement_id, media_root, settings):
    settings.GCPS_MESH_CACHE_BYTES = 0
    first = b"".join(api.get(f"/api/measurements/{measurement_id}/mesh.stl").streaming_content)
    assert [p.suffix for p in cache_files(media_root)] == [".stl"]  # the file just built is kept
    tiff = api.get(f"/api/measurements/{measurement_id}/height.tiff")
    assert tiff.status_code == 200 and b"".join(tiff.streaming_content).startswith(b"II")
    assert [p.suffix for p in cache_files(media_root)] == [".tiff"]  # and the one before removed
    assert first[80:84] != b""


def test_measurements_with_stored_meshes_keep_serving_them(api, measurement_id, media_root):
    """Measurements computed before meshes were derived have mesh and TIFF files of their own."""
    measurement = Measurement.objects.get(pk=measurement_id)
    legacy = {}
    for name, field in (("mesh.ply", "mesh_ply"), ("mesh.obj", "mesh_obj"), ("height.tiff", "height_tiff")):
        legacy[name] = f"stored {name}".encode()
        stored = default_storage.save(f"measurements/{measurement_id}/old/{name}", ContentFile(legacy[name]))
        setattr(measurement, field, stored)
    measurement.save()
    for name, data in legacy.items():
        response = api.get(f"/api/measurements/{measurement_id}/{name}")
        assert response.status_code == 200 and b"".join(response.streaming_content) == data
    assert cache_files(media_root) == []


def test_derived_files_of_an_unfinished_measurement_are_404(api, rig, monkeypatch):
    import metrology.jobs.services as job_services

    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: None)
    core = Rig.from_dict(SMALL_RIG)
    reference = upload(api, rig["id"], stack_zip(render_images(core, 0.0, bit_depth=16)), "reference")
    obj = upload(api, rig["id"], stack_zip(render_images(core, 5.0, bit_depth=16)), "object")
    response = api.post("/api/measurements/", {"rig": rig["id"], "reference": reference, "object": obj}, format="json")
    body = response.json()
    assert body["files"] == {}
    missing = api.get(f"/api/measurements/{body['id']}/mesh.ply")
    assert missing.status_code == 404 and "its job is queued" in missing.json()["error"]


def test_a_derived_file_not_built_yet_answers_202_with_its_job(api, measurement_id, monkeypatch):
    import metrology.jobs.services as job_services

    sent = []
    monkeypatch.setattr(job_services, "_send", lambda job_id, **_: sent.append(job_id))  # no worker takes it yet
    url = f"/api/measurements/{measurement_id}/mesh.obj"
    first = api.get(url)
    assert first.status_code == 202, first
    body = first.json()
    assert first["Location"] == body["job_url"] == f"/api/jobs/{body['job']}/" and first["Retry-After"] == "2"
    assert body["status"] == "queued" and sent == [body["job"]]
    again = api.get(url)  # asked again while queued: the same job, not a second one
    assert again.status_code == 202 and again.json()["job"] == body["job"] and sent == [body["job"]]
    assert api.get(body["job_url"]).json()["status"] == "queued"
    from metrology.dashboard.selectors import job_result_url

    assert job_result_url(Job.objects.get(pk=body["job"])) == url  # the jobs page links to the file
    page = api.get(url, HTTP_ACCEPT="text/html,application/xhtml+xml")  # a browser following the link
    assert page.status_code == 202 and page["Refresh"] == "2" and b"mesh.obj is being built" in page.content
    assert job_services.execute_job(body["job"]) == "done"  # what a worker does
    assert api.get(body["job_url"]).json()["status"] == "done"
    done = api.get(url)
    assert done.status_code == 200 and b"".join(done.streaming_content).startswith(b"# ")


def test_ranges_of_a_stored_file(api, measurement_id):
    url = f"/api/measurements/{measurement_id}/mesh.ply"
    data = b"".join(api.get(url).streaming_content)
    size = len(data)
    part = api.get(url, HTTP_RANGE="bytes=10-99")
    assert part.status_code == 206 and part["Content-Range"] == f"bytes 10-99/{size}"
    assert part["Content-Length"] == "90" and b"".join(part.streaming_content) == data[10:100]
    tail = api.get(url, HTTP_RANGE="bytes=-7")
    assert tail.status_code == 206 and b"".join(tail.streaming_content) == data[-7:]
    rest = api.get(url, HTTP_RANGE=f"bytes={size - 3}-")
    assert (
        rest["Content-Range"] == f"bytes {size - 3}-{size - 1}/{size}" and b"".join(rest.streaming_content) == data[-3:]
    )
    past = api.get(url, HTTP_RANGE=f"bytes={size}-")
    assert past.status_code == 416 and past["Content-Range"] == f"bytes */{size}"
    several = api.get(url, HTTP_RANGE="bytes=0-1,5-6")  # several ranges: the whole file
    assert several.status_code == 200 and b"".join(several.streaming_content) == data
    stored = api.get(f"/api/measurements/{measurement_id}/height.npy", HTTP_RANGE="bytes=0-5")
    assert stored.status_code == 206 and b"".join(stored.streaming_content) == b"\x93NUMPY"


def test_accel_redirect_hands_the_file_to_the_proxy(api, measurement_id, media_root, settings):
    settings.GCPS_ACCEL_REDIRECT = True
    response = api.get(f"/api/measurements/{measurement_id}/mesh.stl")
    assert response.status_code == 200 and response.content == b""
    (cached,) = cache_files(media_root)
    assert response["X-Accel-Redirect"] == f"/protected/derived/{cached.name}"
    assert response["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-mesh.stl"'
    stored = api.get(f"/api/measurements/{measurement_id}/height.npy")
    name = Measurement.objects.get(pk=measurement_id).height_npy.name
    assert stored["X-Accel-Redirect"] == f"/protected/{name}" and (media_root / name).is_file()


# ----------------------------------------------------------------------------- the folder itself


def test_trim_removes_the_oldest_but_never_the_file_kept(tmp_path):
    storage = FileSystemStorage(location=tmp_path)
    files = DerivedFiles(storage, "derived", max_bytes=250)
    for n, name in enumerate(("a", "b", "c")):
        storage.save(f"derived/{name}", ContentFile(b"x" * 100))
        os.utime(tmp_path / "derived" / name, (1000 + n, 1000 + n))
    assert [name for _when, _size, name in files.entries()] == ["derived/a", "derived/b", "derived/c"]
    assert files.trim(keep="derived/c") == 100
    assert sorted(p.name for p in (tmp_path / "derived").iterdir()) == ["b", "c"]
    assert DerivedFiles(storage, "derived", 0).trim(keep="derived/b") == 100
    assert files.total_bytes() == 100 and files.entries()[0][2] == "derived/b"
    files.clear()
    assert files.entries() == [] and DerivedFiles(storage, "nothing", 0).entries() == []
    with pytest.raises(ValueError, match="max_bytes must be a non-negative integer, got -1"):
        DerivedFiles(storage, "derived", -1)
