"""Result files derived on request: meshes streamed while built, a bounded LRU cache, legacy stored files."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest
from django.core.files.base import ContentFile
from django.core.files.storage import default_storage
from django.http import FileResponse, StreamingHttpResponse

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.mesh import mesh_from_heights, open3d_mesh, surface_mesh
from metrology.measurements import derived
from metrology.measurements.derived_cache import DerivedFileCache
from metrology.measurements.models import Measurement
from tests.app.stacks import SMALL_RIG, block_heights, render_images, stack_zip
from tests.app.uploads import upload

o3d = pytest.importorskip("open3d")

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
    assert set(body["files"]) == stored_names | {"height.tiff", "mesh.ply", "mesh.stl", "mesh.obj", "points.npy"}
    measurement = Measurement.objects.get(pk=measurement_id)
    assert not (measurement.mesh_ply or measurement.mesh_stl or measurement.mesh_obj or measurement.height_tiff)
    assert not measurement.points_npy  # the paper's rig: the points are the heights on the camera rays
    folder = media_root / "measurements" / str(measurement_id)
    stored = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
    float32_map = SMALL_RIG["width_px"] * SMALL_RIG["height_px"] * 4
    assert stored < 3 * float32_map, (stored, float32_map)  # two float32 maps and their .npy headers
    assert cache_files(media_root) == []


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj"])
def test_mesh_is_streamed_then_served_from_the_cache(api, measurement_id, media_root, tmp_path, fmt):
    first = api.get(f"/api/measurements/{measurement_id}/mesh.{fmt}")
    assert first.status_code == 200 and isinstance(first, StreamingHttpResponse)
    assert not isinstance(first, FileResponse)  # built while sent, not read from a file
    assert first["Content-Disposition"] == f'attachment; filename="measurement-{measurement_id}-mesh.{fmt}"'
    data = b"".join(first.streaming_content)
    (cached,) = cache_files(media_root)
    assert cached.read_bytes() == data and cached.suffix == f".{fmt}"

    second = api.get(f"/api/measurements/{measurement_id}/mesh.{fmt}")
    assert isinstance(second, FileResponse)
    assert b"".join(second.streaming_content) == data

    # the geometry of today's mesh of the stored height map and points (open3d parses the file)
    z = heights(api, measurement_id)
    points = api.get(f"/api/measurements/{measurement_id}/points.npy")
    points_mm = np.load(io.BytesIO(b"".join(points.streaming_content)))
    mesh = open3d_mesh(surface_mesh(Rig.from_dict(SMALL_RIG), z, points_mm=points_mm))
    # the stored float32 points are the heights on the camera rays (mesh_from_heights's vertices)
    by_heights = np.asarray(mesh_from_heights(Rig.from_dict(SMALL_RIG), z).vertices)
    np.testing.assert_allclose(np.asarray(mesh.vertices), by_heights, rtol=0, atol=1e-4)
    (tmp_path / f"m.{fmt}").write_bytes(data)
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
    assert isinstance(again, FileResponse) and np.array_equal(
        np.load(io.BytesIO(b"".join(again.streaming_content))), points, equal_nan=True
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
    assert not isinstance(again, FileResponse)
    assert b"".join(again.streaming_content) == data
    assert len(cache_files(media_root)) == 1


def test_cache_is_bounded_and_evicts_the_least_recently_used(api, measurement_id, media_root, settings):
    base = f"/api/measurements/{measurement_id}"
    sizes = {}
    for fmt in ("ply", "stl", "obj"):
        sizes[fmt] = len(b"".join(api.get(f"{base}/mesh.{fmt}").streaming_content))
    derived.clear_cache()
    settings.GCPS_MESH_CACHE_BYTES = sizes["ply"] + sizes["stl"] + sizes["obj"] // 2  # room for two of three
    b"".join(api.get(f"{base}/mesh.ply").streaming_content)
    b"".join(api.get(f"{base}/mesh.stl").streaming_content)
    ply, stl = (p for p in cache_files(media_root) if p.suffix in (".ply", ".stl"))
    os.utime(ply, (1_000_000, 1_000_000))
    os.utime(stl, (2_000_000, 2_000_000))
    assert isinstance(api.get(f"{base}/mesh.ply"), FileResponse)  # a hit makes the PLY the most recent
    b"".join(api.get(f"{base}/mesh.obj").streaming_content)
    kept = {p.suffix for p in cache_files(media_root)}
    assert kept == {".ply", ".obj"}, kept  # the STL, least recently used, was evicted
    assert sum(p.stat().st_size for p in cache_files(media_root)) <= settings.GCPS_MESH_CACHE_BYTES


def test_a_cache_smaller_than_the_file_still_serves_it(api, measurement_id, media_root, settings):
    settings.GCPS_MESH_CACHE_BYTES = 0
    first = b"".join(api.get(f"/api/measurements/{measurement_id}/mesh.stl").streaming_content)
    assert cache_files(media_root) == []
    tiff = api.get(f"/api/measurements/{measurement_id}/height.tiff")
    assert tiff.status_code == 200 and b"".join(tiff.streaming_content).startswith(b"II")
    assert cache_files(media_root) == []
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


# ----------------------------------------------------------------------------- the cache itself


def test_concurrent_fills_of_one_name_do_not_corrupt_each_other(tmp_path):
    cache = DerivedFileCache(tmp_path / "cache", max_bytes=10_000)
    content = [bytes([n]) * 100 for n in range(10)]
    first = cache.fill("a.ply", iter(content))
    second = cache.fill("a.ply", iter(content))
    got_first, got_second = [], []
    for _ in range(5):  # interleaved: both write their own temporary file
        got_first.append(next(first))
        got_second.append(next(second))
    assert cache.get("a.ply") is None  # nothing visible under the name before a writer finishes
    got_first.extend(first)
    assert cache.get("a.ply").read_bytes() == b"".join(content)
    got_second.extend(second)
    assert b"".join(got_first) == b"".join(got_second) == b"".join(content)
    assert cache.get("a.ply").read_bytes() == b"".join(content)
    assert [p.name for p in (tmp_path / "cache").iterdir()] == ["a.ply"]  # no temporary file left


def test_an_abandoned_fill_leaves_nothing(tmp_path):
    cache = DerivedFileCache(tmp_path / "cache", max_bytes=10_000)

    def failing():
        yield b"x" * 10
        raise OSError("disk gone")

    stream = cache.fill("a.stl", iter([b"1" * 10, b"2" * 10]))
    next(stream)
    stream.close()  # the client went away
    with pytest.raises(OSError, match="disk gone"):
        list(cache.fill("b.stl", failing()))
    assert list((tmp_path / "cache").iterdir()) == []


def test_eviction_order_and_bad_input(tmp_path):
    tmp_path = tmp_path / "cache"
    cache = DerivedFileCache(tmp_path, max_bytes=250)
    for n, name in enumerate(("a", "b", "c")):
        list(cache.fill(name, [b"x" * 100]))
        os.utime(tmp_path / name, (1000 + n, 1000 + n))
    # filling c evicted a (the oldest); b is refreshed by a hit, so d evicts c
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b", "c"]
    cache.get("b")
    list(cache.fill("d", [b"x" * 100]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b", "d"]
    assert cache.total_bytes() == 200
    with pytest.raises(ValueError, match="max_bytes must be a non-negative integer, got -1"):
        DerivedFileCache(tmp_path, -1)
    with pytest.raises(ValueError, match="plain file name"):
        cache.get("../etc/passwd")
