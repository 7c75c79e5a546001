"""Nominal meshes: binary and ASCII STL read by our parser, PLY and OBJ through Open3D, all to the
same validated model; degenerate faces dropped and counted; inward faces flipped; open meshes
warned; empty and malformed files refused; a validated model written as a binary PLY (how the
application stores a STEP file's tessellation) read back bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metrology.core.inspection.nominal import nominal_from_arrays, read_nominal
from metrology.core.io.meshes import read_mesh_arrays, triangle_mesh_ply_bytes
from tests.core.inspection.parts import cube, write_ascii_stl, write_binary_stl


def _same_surface(a_vertices: np.ndarray, a_faces: np.ndarray, b_vertices: np.ndarray, b_faces: np.ndarray) -> None:
    key = lambda v, f: sorted(tuple(map(tuple, np.round(v[tri], 9))) for tri in f)  # noqa: E731
    assert key(a_vertices, a_faces) == key(b_vertices, b_faces)


@pytest.mark.parametrize("form", ["binary.stl", "ascii.stl", "part.ply", "part.obj"])
def test_every_format_reads_the_same_cube(tmp_path: Path, form: str) -> None:
    import open3d

    box = cube(10.0)
    path = tmp_path / form
    if form == "binary.stl":
        write_binary_stl(path, box.vertices, box.faces)
    elif form == "ascii.stl":
        write_ascii_stl(path, box.vertices, box.faces)
    else:
        mesh = open3d.geometry.TriangleMesh(
            open3d.utility.Vector3dVector(box.vertices), open3d.utility.Vector3iVector(box.faces)
        )
        assert open3d.io.write_triangle_mesh(str(path), mesh, write_ascii=form.endswith(".obj"))
    nominal = read_nominal(path)
    assert nominal.units == "mm" and nominal.triangle_count == 12 and nominal.vertices.shape == (8, 3)
    assert nominal.oriented and not nominal.warnings and nominal.signed_volume_mm3 == pytest.approx(1000.0)
    assert nominal.size_mm == [10.0, 10.0, 10.0]
    import hashlib

    assert nominal.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    _same_surface(nominal.vertices, nominal.faces, box.vertices, box.faces)


def test_a_validated_model_written_as_ply_reads_back_bit_for_bit(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    box = cube(10.0)
    vertices = box.vertices + rng.normal(scale=1e-3, size=box.vertices.shape)  # not representable in float32
    path = tmp_path / "tessellation.ply"
    path.write_bytes(triangle_mesh_ply_bytes(vertices, box.faces))
    read_vertices, read_faces = read_mesh_arrays(path)
    np.testing.assert_array_equal(read_vertices, vertices)  # doubles: exact
    np.testing.assert_array_equal(read_faces, box.faces)  # the winding kept
    again = read_nominal(path)
    assert again.triangle_count == 12 and again.oriented and not again.flipped and not again.warnings
    with pytest.raises(ValueError, match="does not exist"):
        triangle_mesh_ply_bytes(vertices, box.faces + 8)


def test_degenerate_faces_are_dropped_and_counted() -> None:
    box = cube()
    extra = np.array([[0, 0, 1], [2, 2, 3]])  # a repeated corner; a face with two equal corners
    vertices = np.vstack([box.vertices, [[0.5, 0.5, 0.5]]])
    sliver = np.array([[0, 8, 8]])
    nominal = nominal_from_arrays(vertices, np.vstack([box.faces, extra, sliver]))
    assert nominal.degenerate_faces == 3 and nominal.triangle_count == 12 and nominal.oriented


def test_inward_faces_are_flipped_with_a_warning() -> None:
    box = cube()
    nominal = nominal_from_arrays(box.vertices, box.faces[:, ::-1])
    assert nominal.flipped and nominal.signed_volume_mm3 == pytest.approx(1.0)
    assert "flipped" in nominal.warnings[0]
    np.testing.assert_allclose(nominal.face_normals(), cube().face_normals())


def test_open_and_inconsistent_meshes_are_accepted_with_a_warning() -> None:
    box = cube()
    open_box = nominal_from_arrays(box.vertices, box.faces[:-2])
    assert not open_box.closed and "open" in open_box.warnings[0] and "winding" in open_box.warnings[0]
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    mixed = nominal_from_arrays(box.vertices, faces)
    assert mixed.closed and not mixed.consistent and "inconsistently oriented" in mixed.warnings[0]


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("empty.stl", b"", "not an STL"),
        ("nothing.stl", b"solid x\nendsolid x\n", "no triangles"),
        ("bad.ply", b"not a ply", "not a PLY"),
        (
            "flat.stl",
            b"solid x\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 2 0 0\n",
            "degenerate",
        ),
        ("part.iges", b"IGES", "must be .stl, .ply, .obj"),
        # a STEP file is read through the optional cadquery-ocp: refused as unreadable, or for want of it
        ("part.step", b"ISO-10303-21;", r"not a readable STEP file|STEP files need OpenCASCADE"),
    ],
)
def test_unusable_files_are_refused(tmp_path: Path, name: str, content: bytes, message: str) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message):
        read_nominal(path)


def test_faces_must_refer_to_existing_vertices() -> None:
    box = cube()
    with pytest.raises(ValueError, match="does not exist"):
        nominal_from_arrays(box.vertices, box.faces + 1)
    with pytest.raises(ValueError, match="not finite"):
        nominal_from_arrays(np.where(box.vertices == 1.0, np.nan, box.vertices), box.faces)
