"""Point-cloud export: E57 (pye57) and PLY with sigma_mm / deviation_mm, written and read back.

- E57: a (H, W, 3) map with holes, an intensity (modulation) map and a pose written, read back with
  pye57: the points in the file's frame are ``R x + t`` within float32 rounding of metres relative
  to the centroid (0.01 um here), the intensity to float32, the pixel of every point exact.
- PLY point clouds: our reader and Open3D's read the same x y z (float64: bit for bit) and the
  float32 sigma_mm / deviation_mm; without them the file is the plain x y z cloud.
- Mesh PLY (GridMesh): a deviation adds one float32 property after sigma_mm; without it the bytes
  are those written before (the header without it, the same vertex records).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from metrology.core.io.points import ply_point_cloud, read_ply, write_ply_point_cloud
from metrology.core.mesh import GridMesh, ply_chunks

pye57 = pytest.importorskip("pye57", reason="E57 export needs pye57 (pip install 'gcps-lab[e57]', part of [dev])")
from metrology.core.io.e57 import read_e57, write_e57  # noqa: E402


def _grid(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-50, 50, (24, 32, 3)) + np.array([10.0, -5.0, 600.0])
    points[3, 4] = np.nan
    points[10, :5, 2] = np.nan
    return points, rng.uniform(0.0, 1.0, (24, 32))


def test_e57_round_trip_with_pose_intensity_and_pixels(tmp_path):
    points, modulation = _grid()
    rotation = Rotation.from_euler("xyz", [10.0, -20.0, 35.0], degrees=True).as_matrix()
    translation = np.array([100.0, -20.0, 5.0])
    path = write_e57(tmp_path / "scan.e57", points, intensity=modulation, rotation=rotation, translation_mm=translation)
    scans = read_e57(path)
    assert len(scans) == 1
    scan = scans[0]
    ok = np.isfinite(points).all(axis=-1)
    assert len(scan.points_mm) == ok.sum() == 24 * 32 - 6
    rows, cols = np.nonzero(ok)
    np.testing.assert_array_equal(scan.row, rows)
    np.testing.assert_array_equal(scan.column, cols)
    expected = points[rows, cols] @ rotation.T + translation
    assert np.abs(scan.points_mm - expected).max() < 1e-5  # mm: float32 metres around the centroid
    np.testing.assert_allclose(scan.intensity, modulation[rows, cols], atol=1e-7)
    # the pose is in the file, as E57 defines it (a reader that ignores it gets the stored coordinates)
    e57 = pye57.E57(str(path))
    header = e57.get_header(0)
    np.testing.assert_allclose(header.rotation_matrix, rotation, atol=1e-12)
    raw = e57.read_scan_raw(0)
    stored_mm = np.column_stack([raw["cartesianX"], raw["cartesianY"], raw["cartesianZ"]]) * 1000.0
    assert np.abs(stored_mm).max() < 100.0  # centred: the centroid went into the pose
    e57.close()


def test_e57_identity_pose_and_bad_input(tmp_path):
    points, _ = _grid(1)
    flat = points.reshape(-1, 3)
    scan = read_e57(write_e57(tmp_path / "flat.e57", flat))[0]
    ok = np.isfinite(flat).all(axis=1)
    assert np.abs(scan.points_mm - flat[ok]).max() < 1e-5
    assert scan.intensity is None
    np.testing.assert_array_equal(scan.row, np.flatnonzero(ok))
    with pytest.raises(ValueError, match="rotation matrix"):
        write_e57(tmp_path / "bad.e57", flat, rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="intensity must have shape"):
        write_e57(tmp_path / "bad.e57", points, intensity=np.ones(3))
    assert not (tmp_path / "bad.e57").exists()
    with pytest.raises(ValueError, match="not a readable E57"):
        (tmp_path / "junk.e57").write_bytes(b"not an e57 file")
        read_e57(tmp_path / "junk.e57")


def test_ply_point_cloud_round_trip(tmp_path):
    import open3d as o3d

    points, _ = _grid(2)
    kept = points[np.isfinite(points).all(axis=-1)]
    rng = np.random.default_rng(5)
    sigma, deviation = rng.uniform(0.001, 0.01, len(kept)), rng.normal(0, 0.05, len(kept))
    normals = rng.normal(size=kept.shape)
    path = write_ply_point_cloud(tmp_path / "cloud.ply", kept, normals=normals, sigma_mm=sigma, deviation_mm=deviation)
    data = read_ply(path.read_bytes())
    np.testing.assert_array_equal(data.points, kept)
    np.testing.assert_array_equal(data.vertex["sigma_mm"], sigma.astype(np.float32))
    np.testing.assert_array_equal(data.vertex["deviation_mm"], deviation.astype(np.float32))
    np.testing.assert_array_equal(data.vertex["nx"], normals[:, 0])
    assert data.faces.shape == (0, 3)
    cloud = o3d.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(np.asarray(cloud.points), kept)
    # without the optional arrays: the plain x y z cloud
    plain = ply_point_cloud(kept)
    header = plain[: plain.index(b"end_header")].decode()
    assert [line for line in header.splitlines() if line.startswith("property")] == [
        "property double x",
        "property double y",
        "property double z",
    ]
    assert len(plain) - plain.index(b"end_header\n") - len(b"end_header\n") == 24 * len(kept)
    with pytest.raises(ValueError, match=r"sigma_mm must have shape"):
        ply_point_cloud(kept, sigma_mm=sigma[:-1])


def test_read_ply_ascii_and_open3d_meshes(tmp_path):
    import open3d as o3d

    text = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    text += b"property float sigma_mm\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    text += b"0 0 0 0.5\n1 0 0 0.25\n0 1 0 0.125\n3 0 1 2\n"
    data = read_ply(text)
    np.testing.assert_array_equal(data.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(data.vertex["sigma_mm"], [0.5, 0.25, 0.125])
    np.testing.assert_array_equal(data.faces, [[0, 1, 2]])
    mesh = o3d.geometry.TriangleMesh.create_box(2.0, 3.0, 4.0)
    o3d.io.write_triangle_mesh(str(tmp_path / "box.ply"), mesh, write_ascii=False)
    box = read_ply((tmp_path / "box.ply").read_bytes())
    np.testing.assert_array_equal(box.points, np.asarray(mesh.vertices))
    np.testing.assert_array_equal(box.faces, np.asarray(mesh.triangles))
    with pytest.raises(ValueError, match="not a PLY"):
        read_ply(b"solid box\n")
    with pytest.raises(ValueError, match="truncated"):
        read_ply((tmp_path / "box.ply").read_bytes()[:-40])


def test_mesh_ply_with_deviation_and_unchanged_without():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]], dtype=np.float64)
    triangles = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32)
    valid = np.ones((2, 2), dtype=bool)
    plain = GridMesh(vertices, triangles)
    with_sigma = plain.with_sigma(np.full((2, 2), 0.002), valid)
    both = with_sigma.with_deviation(np.array([[0.1, -0.2], [0.3, 0.0]]), valid)
    plain_bytes, sigma_bytes, both_bytes = (b"".join(ply_chunks(m)) for m in (plain, with_sigma, both))
    assert b"deviation_mm" not in plain_bytes + sigma_bytes and b"sigma_mm" not in plain_bytes
    assert both_bytes.index(b"property float sigma_mm\nproperty float deviation_mm\n") > 0
    data = read_ply(both_bytes)
    np.testing.assert_array_equal(data.points, vertices)
    np.testing.assert_array_equal(data.vertex["deviation_mm"], np.float32([0.1, -0.2, 0.3, 0.0]))
    np.testing.assert_array_equal(data.vertex["sigma_mm"], np.float32([0.002] * 4))
    np.testing.assert_array_equal(data.faces, triangles)
    # the plain file is open3d's layout, as before: 48-byte vertex records then 13-byte faces
    body = plain_bytes[plain_bytes.index(b"end_header\n") + len(b"end_header\n") :]
    assert len(body) == 4 * 48 + 2 * 13
