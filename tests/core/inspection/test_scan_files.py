"""Scan files: PLY vertices (x y z, optional sigma_mm) from ASCII, binary little- and big-endian
files, a face element after the vertices ignored; STL facets read as Open3D reads them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metrology.core.inspection.scan import scan_from_ply, scan_from_point_map
from metrology.core.io.meshes import read_ply_vertices, read_stl
from tests.core.inspection.parts import cylinder_part, write_ascii_stl, write_binary_stl, write_ply_points

POINTS = np.array([[0.5, -1.25, 300.0], [1e-3, 2.0, -4.5], [7.0, 8.0, 9.0]])
SIGMA = np.array([0.01, 0.02, 0.03])


def test_ascii_ply_with_faces_after_the_vertices(tmp_path: Path) -> None:
    path = write_ply_points(tmp_path / "a.ply", POINTS, SIGMA, ascii=True)
    scan = scan_from_ply(path.read_bytes())
    np.testing.assert_array_equal(scan.points_mm, POINTS)
    np.testing.assert_array_equal(scan.sigma_mm, SIGMA)
    assert scan.shape == (3,) and not scan.sigma_along_ray


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_ply_either_byte_order(order: str) -> None:
    kind = "little" if order == "<" else "big"
    header = f"ply\nformat binary_{kind}_endian 1.0\ncomment made by hand\nelement vertex 3\n"
    header += "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
    header += "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    rows = np.zeros(3, np.dtype([("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"), ("red", "u1")]))
    rows["x"], rows["y"], rows["z"], rows["red"] = POINTS[:, 0], POINTS[:, 1], POINTS[:, 2], 7
    face = np.array([3], "u1").tobytes() + np.array([0, 1, 2], order + "i4").tobytes()
    columns = read_ply_vertices(header.encode() + rows.tobytes() + face)
    np.testing.assert_array_equal(np.stack([columns[k] for k in "xyz"], axis=1), POINTS.astype(np.float32))
    assert columns["red"].tolist() == [7, 7, 7]
    scan = scan_from_ply(header.encode() + rows.tobytes() + face)
    assert scan.sigma_mm is None


def test_malformed_ply_is_refused() -> None:
    with pytest.raises(ValueError, match="lacks x, y or z"):
        read_ply_vertices(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(ValueError, match="too short"):
        read_ply_vertices(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
                          b"property float y\nproperty float z\nend_header\n" + bytes(12))  # fmt: skip


def test_point_map_and_its_sigma_shape() -> None:
    xyz = np.zeros((2, 3, 3), np.float32)
    xyz[0, 1] = np.nan
    scan = scan_from_point_map(xyz, np.ones((2, 3)))
    assert scan.shape == (2, 3) and scan.valid.tolist() == [True, False, True, True, True, True]
    assert scan.sigma_along_ray
    with pytest.raises(ValueError, match="--sigma has shape"):
        scan_from_point_map(xyz, np.ones((3, 2)))


@pytest.mark.parametrize("writer", [write_binary_stl, write_ascii_stl])
def test_stl_facets_match_what_open3d_reads(tmp_path: Path, writer) -> None:
    import open3d

    nominal = cylinder_part(64)
    path = writer(tmp_path / "c.stl", nominal.vertices, nominal.faces)
    ours = read_stl(path.read_bytes())
    theirs = open3d.io.read_triangle_mesh(str(path))
    corners = np.asarray(theirs.vertices)[np.asarray(theirs.triangles)]
    assert ours.shape == corners.shape == (nominal.triangle_count, 3, 3)
    np.testing.assert_allclose(ours, corners, atol=1e-6)
