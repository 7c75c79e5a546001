"""Tests of metrology.core.mesh: grid triangulation, point clouds, meshes and their files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG, Rig, points_from_heights
from metrology.core.mesh import (
    default_max_jump_mm,
    grid_mesh_from_heights,
    grid_triangles,
    mesh_file_chunks,
    mesh_from_heights,
    point_cloud_from_heights,
    surface_mesh,
    write_mesh,
    write_point_cloud,
)

o3d = pytest.importorskip("open3d")

SMALL_RIG = PAPER_RIG.with_parameters(width_px=40, height_px=30, fw_mm=40 * 0.78125)


def triangle_normals_z(xyz: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (xyz[triangles[:, i]] for i in range(3))
    return np.cross(b - a, c - a)[:, 2]


# ------------------------------------------------------------------------ grid_triangles


@pytest.mark.parametrize("shape", [(2, 2), (3, 5), (30, 40)])
def test_plane_gives_two_triangles_per_cell(shape: tuple[int, int]) -> None:
    height, width = shape
    z = np.full(shape, 12.5)
    triangles = grid_triangles(np.ones(shape, bool), z, 3.0)
    assert triangles.dtype == np.int32
    assert triangles.shape == (2 * (height - 1) * (width - 1), 3)
    # Every vertex is used and no triangle is degenerate.
    assert set(np.unique(triangles)) == set(range(height * width))
    assert (np.diff(np.sort(triangles, axis=1), axis=1) > 0).all()


def test_winding_points_up_on_a_tilted_plane() -> None:
    rig = SMALL_RIG
    k, j = np.mgrid[0 : rig.height_px, 0 : rig.width_px]
    z = 10.0 + 0.3 * j - 0.2 * k  # tilted plane, mm
    xyz = points_from_heights(rig, z).reshape(-1, 3)
    triangles = grid_triangles(np.ones(rig.shape, bool), z, default_max_jump_mm(rig))
    assert len(triangles) == 2 * (rig.height_px - 1) * (rig.width_px - 1)
    assert (triangle_normals_z(xyz, triangles) > 0).all()


def test_step_of_20_mm_is_not_bridged() -> None:
    rig = SMALL_RIG
    z = np.full(rig.shape, 5.0)
    z[:, 20:] = 25.0  # a 20 mm step between columns 19 and 20
    z[10:20, 5:12] = 25.0  # and a raised block with four edges
    triangles = grid_triangles(np.ones(rig.shape, bool), z, default_max_jump_mm(rig))
    zv = z.ravel()[triangles]
    assert (zv.max(axis=1) - zv.min(axis=1) == 0).all(), "a triangle spans a step"
    # Every cell that does not straddle a step keeps its two triangles; corner cells of the
    # block keep the one triangle that lies on a single level.
    n_cells = (rig.height_px - 1) * (rig.width_px - 1)
    straddling = 0
    for k in range(rig.height_px - 1):
        for j in range(rig.width_px - 1):
            straddling += len(np.unique(z[k : k + 2, j : j + 2])) > 1
    assert len(triangles) > 2 * (n_cells - straddling)
    # With no threshold the step is bridged.
    bridged = grid_triangles(np.ones(rig.shape, bool), z, np.inf)
    assert len(bridged) == 2 * n_cells


def test_diagonal_step_follows_the_diagonal() -> None:
    k, j = np.mgrid[0:6, 0:6]
    z = np.where(j > k, 20.0, 0.0)  # step along the main diagonal
    triangles = grid_triangles(np.ones(z.shape, bool), z, 2.0)
    zv = z.ravel()[triangles]
    assert (zv.max(axis=1) == zv.min(axis=1)).all()
    # The cells on the step (on the diagonal and just above it) have three corners on one
    # level: they split along a-d and keep the one triangle on that level.
    assert len(triangles) == 2 * 5 * 5 - 5 - 4


def test_nan_holes_are_excluded() -> None:
    rig = SMALL_RIG
    z = np.full(rig.shape, 3.0)
    z[5:8, 10:14] = np.nan
    z[0, 0] = np.nan
    valid = np.isfinite(z)
    triangles = grid_triangles(valid, z, default_max_jump_mm(rig))
    assert triangles.max() < valid.sum()
    # Vertex n is the n-th valid pixel in row-major order; no triangle touches the hole.
    pixel_of_vertex = np.flatnonzero(valid.ravel())
    assert valid.ravel()[pixel_of_vertex[triangles]].all()
    # Cells with three valid corners keep one triangle: the corner cell (0, 0) and the
    # four cells at the hole's corners; cells touching the hole's sides lose both.
    n_cells = (rig.height_px - 1) * (rig.width_px - 1)
    cells_with_nan = 1 + (3 + 1) * (4 + 1)
    expected = 2 * (n_cells - cells_with_nan) + 1 + 4
    assert len(triangles) == expected


def test_isolated_valid_pixels_make_no_triangle() -> None:
    valid = np.zeros((5, 5), bool)
    valid[0, 0] = valid[2, 2] = valid[4, 3] = valid[4, 4] = True
    z = np.where(valid, 1.0, np.nan)
    assert grid_triangles(valid, z, 1.0).shape == (0, 3)


def test_grid_triangles_bad_input() -> None:
    with pytest.raises(ValueError, match="valid must be a 2-D bool array"):
        grid_triangles(np.ones((3, 3)), np.zeros((3, 3)), 1.0)
    with pytest.raises(ValueError, match=r"z_mm must have the shape of valid \(3, 3\)"):
        grid_triangles(np.ones((3, 3), bool), np.zeros((3, 4)), 1.0)
    with pytest.raises(ValueError, match="max_jump_mm must be positive"):
        grid_triangles(np.ones((3, 3), bool), np.zeros((3, 3)), 0.0)
    z = np.zeros((3, 3))
    z[1, 1] = np.nan
    with pytest.raises(ValueError, match=r"not finite at 1 pixel\(s\) marked valid"):
        grid_triangles(np.ones((3, 3), bool), z, 1.0)


# ------------------------------------------------------------------------ open3d geometry


def sample_heights(rig: Rig) -> np.ndarray:
    k, j = np.mgrid[0 : rig.height_px, 0 : rig.width_px]
    z = 4.0 + 0.05 * j + 0.02 * k
    z[8:16, 10:22] += 20.0  # block
    z[20:24, 30:35] = np.nan  # shadow
    return z


def test_mesh_vertices_are_the_triangulated_points() -> None:
    rig = SMALL_RIG
    z = sample_heights(rig)
    mesh = mesh_from_heights(rig, z)
    valid = np.isfinite(z)
    vertices = np.asarray(mesh.vertices)
    np.testing.assert_array_equal(vertices, points_from_heights(rig, z)[valid])
    triangles = np.asarray(mesh.triangles)
    np.testing.assert_array_equal(triangles, grid_triangles(valid, z, default_max_jump_mm(rig)))
    assert mesh.has_vertex_normals() and mesh.has_triangle_normals()
    assert (np.asarray(mesh.triangle_normals)[:, 2] > 0).all()
    normals = np.asarray(mesh.vertex_normals)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-9)
    assert (normals[:, 2] > 0).all()


def test_point_cloud_from_heights() -> None:
    rig = SMALL_RIG
    z = sample_heights(rig)
    cloud = point_cloud_from_heights(rig, z)
    valid = np.isfinite(z)
    np.testing.assert_array_equal(np.asarray(cloud.points), points_from_heights(rig, z)[valid])
    normals = np.asarray(cloud.normals)
    assert normals.shape == (valid.sum(), 3)
    assert (normals[:, 2] > 0).all()


def test_shape_unlike_the_rig_is_refused() -> None:
    with pytest.raises(ValueError, match=r"rig's shape \(30, 40\)"):
        mesh_from_heights(SMALL_RIG, np.zeros((30, 41)))


def test_all_nan_gives_an_empty_mesh(tmp_path: Path) -> None:
    mesh = mesh_from_heights(SMALL_RIG, np.full(SMALL_RIG.shape, np.nan))
    assert len(mesh.vertices) == 0 and len(mesh.triangles) == 0


# ------------------------------------------------------------------------ files


@pytest.mark.parametrize("ext", [".ply", ".stl", ".obj"])
def test_mesh_files_round_trip(tmp_path: Path, ext: str) -> None:
    rig = SMALL_RIG
    z = sample_heights(rig)
    mesh = mesh_from_heights(rig, z)
    path = write_mesh(mesh, tmp_path / f"object{ext}")
    assert path == tmp_path / f"object{ext}"
    assert [p.name for p in tmp_path.iterdir()] == [f"object{ext}"], "temporary or extra files left behind"
    again = o3d.io.read_triangle_mesh(str(path))
    assert len(again.triangles) == len(mesh.triangles)
    used = np.unique(np.asarray(mesh.triangles))
    if ext == ".stl":  # STL stores triangles only: compare the vertices they use
        assert len(again.vertices) == len(used)
    else:
        assert len(again.vertices) == len(mesh.vertices)
    if ext == ".ply":  # doubles, same order
        np.testing.assert_array_equal(np.asarray(again.vertices), np.asarray(mesh.vertices))
    used_xyz = np.asarray(mesh.vertices)[used]
    # STL stores float32; OBJ 5 decimals, read back by open3d in float32 (< 0.1 um here)
    tol = {".ply": 0.0, ".stl": 1e-4, ".obj": 1e-4}[ext]
    np.testing.assert_allclose(again.get_min_bound(), used_xyz.min(axis=0), atol=tol)
    np.testing.assert_allclose(again.get_max_bound(), used_xyz.max(axis=0), atol=tol)


def test_obj_keeps_vertex_order_normals_and_faces(tmp_path: Path) -> None:
    rig = SMALL_RIG
    mesh = mesh_from_heights(rig, sample_heights(rig))
    lines = write_mesh(mesh, tmp_path / "object.obj").read_text().splitlines()
    v = np.array([line.split()[1:] for line in lines if line.startswith("v ")], float)
    vn = np.array([line.split()[1:] for line in lines if line.startswith("vn ")], float)
    f = [line.split()[1:] for line in lines if line.startswith("f ")]
    np.testing.assert_allclose(v, np.asarray(mesh.vertices), rtol=0, atol=5e-6)  # 5 decimals of a mm
    np.testing.assert_allclose(vn, np.asarray(mesh.vertex_normals), rtol=0, atol=5e-7)
    faces = np.array([[int(corner.split("//")[0]) for corner in face] for face in f]) - 1
    np.testing.assert_array_equal(faces, np.asarray(mesh.triangles))
    assert all(corner.split("//")[0] == corner.split("//")[1] for face in f for corner in face)
    bare = o3d.geometry.TriangleMesh(mesh.vertices, mesh.triangles)
    text = write_mesh(bare, tmp_path / "bare.OBJ").read_text()
    assert "vn " not in text and "//" not in text


def test_stl_is_binary_with_normals(tmp_path: Path) -> None:
    rig = SMALL_RIG
    mesh = mesh_from_heights(rig, np.full(rig.shape, 7.0))
    bare = o3d.geometry.TriangleMesh(mesh.vertices, mesh.triangles)  # no normals
    path = write_mesh(bare, tmp_path / "plane.STL")
    data = path.read_bytes()
    n_triangles = int.from_bytes(data[80:84], "little")
    assert n_triangles == 2 * (rig.height_px - 1) * (rig.width_px - 1)
    assert len(data) == 84 + 50 * n_triangles
    record = np.frombuffer(data[84:], dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]))
    np.testing.assert_allclose(record["n"], np.tile([0.0, 0.0, 1.0], (n_triangles, 1)), atol=1e-6)
    np.testing.assert_allclose(record["v"][..., 2], 7.0)
    assert not bare.has_triangle_normals(), "write_mesh must not modify its argument"


def test_ply_is_binary(tmp_path: Path) -> None:
    mesh = mesh_from_heights(SMALL_RIG, sample_heights(SMALL_RIG))
    header = write_mesh(mesh, tmp_path / "m.ply").read_bytes()[:200]
    assert b"format binary_little_endian" in header


def test_point_cloud_file_round_trip(tmp_path: Path) -> None:
    rig = SMALL_RIG
    z = sample_heights(rig)
    cloud = point_cloud_from_heights(rig, z)
    path = write_point_cloud(cloud, tmp_path / "cloud.ply")
    again = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(again.points), np.asarray(cloud.points))
    np.testing.assert_allclose(np.asarray(again.normals), np.asarray(cloud.normals))
    with pytest.raises(ValueError, match=r"extension must be one of \.ply"):
        write_point_cloud(cloud, tmp_path / "cloud.xyz")


def test_write_mesh_refuses_other_extensions(tmp_path: Path) -> None:
    mesh = mesh_from_heights(SMALL_RIG, sample_heights(SMALL_RIG))
    for name in ["m.off", "m.gltf", "m"]:
        with pytest.raises(ValueError, match=r"extension must be one of \.ply, \.stl, \.obj"):
            write_mesh(mesh, tmp_path / name)
    assert not list(tmp_path.iterdir())


def test_write_mesh_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import metrology.core.io as gio

    mesh = mesh_from_heights(SMALL_RIG, sample_heights(SMALL_RIG))

    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(gio.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_mesh(mesh, tmp_path / "m.ply")
    assert not list(tmp_path.iterdir())


def test_mesh_module_imports_open3d_lazily() -> None:
    import subprocess
    import sys

    code = "import sys, metrology.core.mesh; print('open3d' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


# ------------------------------------------------------------------------ streamed files


def body(data: bytes, fmt: str) -> bytes:
    """A mesh file without its header comment (the writer's name)."""
    if fmt == "ply":
        return data[data.index(b"end_header\n") :]
    if fmt == "stl":
        return data[80:]
    return data


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj"])
def test_streamed_mesh_files_are_the_written_files(tmp_path: Path, fmt: str) -> None:
    """The streamed writers give the bytes of write_mesh (header comments aside) and parse to its geometry."""
    rig = SMALL_RIG
    z = sample_heights(rig)
    mesh = mesh_from_heights(rig, z)
    written = write_mesh(mesh, tmp_path / f"written.{fmt}").read_bytes()
    chunks = list(mesh_file_chunks(surface_mesh(rig, z), fmt, chunk_rows=100))  # several chunks of each part
    assert len(chunks) > 3
    streamed = b"".join(chunks)
    assert body(streamed, fmt) == body(written, fmt)
    (tmp_path / f"streamed.{fmt}").write_bytes(streamed)
    again = o3d.io.read_triangle_mesh(str(tmp_path / f"streamed.{fmt}"))
    reference = o3d.io.read_triangle_mesh(str(tmp_path / f"written.{fmt}"))
    assert len(again.triangles) == len(mesh.triangles) > 0
    np.testing.assert_array_equal(np.asarray(again.vertices), np.asarray(reference.vertices))
    np.testing.assert_array_equal(np.asarray(again.triangles), np.asarray(reference.triangles))
    if fmt == "ply":  # float64 and the same order: the mesh itself, normals included
        np.testing.assert_array_equal(np.asarray(again.vertices), np.asarray(mesh.vertices))
        np.testing.assert_array_equal(np.asarray(again.vertex_normals), np.asarray(mesh.vertex_normals))


def test_grid_mesh_normals_match_open3d() -> None:
    rig = SMALL_RIG
    z = sample_heights(rig)
    z[2, 2] = 50.0  # a spike: its four neighbours' triangles are dropped, vertex (2, 2) is isolated
    mesh = mesh_from_heights(rig, z)
    grid = grid_mesh_from_heights(rig, z)
    np.testing.assert_array_equal(grid.vertices, np.asarray(mesh.vertices))
    np.testing.assert_array_equal(grid.triangles, np.asarray(mesh.triangles))
    np.testing.assert_allclose(grid.triangle_normals(), np.asarray(mesh.triangle_normals), rtol=0, atol=1e-15)
    normals = grid.vertex_normals()
    np.testing.assert_allclose(normals, np.asarray(mesh.vertex_normals), rtol=0, atol=1e-15)
    isolated = np.setdiff1d(np.arange(len(grid.vertices)), grid.triangles.ravel())
    assert len(isolated) >= 1
    np.testing.assert_array_equal(normals[isolated], np.tile([0.0, 0.0, 1.0], (len(isolated), 1)))


def test_mesh_file_chunks_start_before_the_normals_and_check_input() -> None:
    rig = SMALL_RIG
    with pytest.raises(ValueError, match="fmt must be one of ply, stl, obj, got 'vrml'"):
        mesh_file_chunks(lambda: surface_mesh(rig, sample_heights(rig)), "vrml")  # at once, before building
    lazy = mesh_file_chunks(lambda: surface_mesh(rig, np.zeros((3, 3))), "ply")  # nothing computed yet
    with pytest.raises(ValueError, match="rig's shape"):
        next(lazy)
    header = next(mesh_file_chunks(lambda: surface_mesh(rig, sample_heights(rig)), "ply"))
    assert header.startswith(b"ply\n") and header.endswith(b"end_header\n")
    n_valid = int(np.isfinite(sample_heights(rig)).sum())
    assert f"element vertex {n_valid}\n".encode() in header
