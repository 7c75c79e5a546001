"""Test parts for inspection: meshes with known geometry, STL/PLY/STEP writers, random poses."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from metrology.core.inspection import alignment
from metrology.core.inspection.nominal import NominalModel, nominal_from_arrays


def mesh_arrays(mesh: object) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)  # type: ignore[attr-defined]


def asymmetric_part() -> NominalModel:
    """A 60 x 40 x 20 mm block carrying a cylinder, a small block and a cone (no symmetry)."""
    import open3d

    geometry = open3d.geometry.TriangleMesh
    block = geometry.create_box(60, 40, 20)
    post = geometry.create_cylinder(8, 30, resolution=64, split=4).translate((15, 12, 35))
    lug = geometry.create_box(10, 6, 8).translate((42, 28, 20))
    cone = geometry.create_cone(5, 12, resolution=32).translate((45, 8, 20))
    return nominal_from_arrays(*mesh_arrays(block + post + lug + cone), name="asymmetric")


def cylinder_part(resolution: int = 256) -> NominalModel:
    """A closed cylinder, radius 20 mm, height 50 mm, axis z through the origin."""
    import open3d

    mesh = open3d.geometry.TriangleMesh.create_cylinder(20, 50, resolution=resolution, split=2)
    return nominal_from_arrays(*mesh_arrays(mesh), name="cylinder")


def cube(size: float = 1.0) -> NominalModel:
    """The closed cube [0, size]^3, faces outward."""
    import open3d

    return nominal_from_arrays(*mesh_arrays(open3d.geometry.TriangleMesh.create_box(size, size, size)), name="cube")


def random_pose(rng: np.random.Generator, angle_rad: float = np.pi, shift_mm: float = 50.0) -> np.ndarray:
    """A ``(4, 4)`` rigid transform: a rotation of up to ``angle_rad`` about a random axis and a shift
    of up to ``shift_mm`` along each axis."""
    axis = rng.normal(size=3)
    axis *= angle_rad * rng.random() / np.linalg.norm(axis)
    return alignment.rigid_transform(alignment.rotation_matrix(axis), rng.uniform(-shift_mm, shift_mm, 3))


def pose_error(found: np.ndarray, truth: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """``(rotation error deg, largest displacement mm over points)`` of ``found`` against ``truth``."""
    error = found @ np.linalg.inv(truth)
    rotation = error[:3, :3]
    sine = 0.5 * np.linalg.norm(
        [rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]]
    )
    angle = np.arctan2(sine, (np.trace(rotation) - 1.0) / 2.0)  # precise near 0, unlike arccos
    moved = np.abs(alignment.apply(error, points) - points).max()
    return float(np.degrees(angle)), float(moved)


def write_binary_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    corners = vertices[faces].astype(np.float32)
    record = np.zeros(
        faces.shape[0], np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    )
    record["corners"] = corners
    path.write_bytes(b"\0" * 80 + np.uint32(faces.shape[0]).tobytes() + record.tobytes())
    return path


def write_ascii_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    lines = ["solid part"]
    for tri in vertices[faces]:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    lines.append("endsolid part")
    path.write_text("\n".join(lines) + "\n")
    return path


def write_ply_points(path: Path, points: np.ndarray, sigma: np.ndarray | None = None, *, ascii: bool = False) -> Path:
    from metrology.core.io.meshes import ply_points_bytes

    if not ascii:
        columns = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
        if sigma is not None:
            columns["sigma_mm"] = sigma
        path.write_bytes(ply_points_bytes(columns))
        return path
    names = ["x", "y", "z"] + ([] if sigma is None else ["sigma_mm"])
    table = points if sigma is None else np.column_stack([points, sigma])
    header = ["ply", "format ascii 1.0", f"element vertex {len(points)}"]
    header += [f"property double {n}" for n in names] + [
        "element face 0",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    body = "\n".join(" ".join(repr(float(v)) for v in row) for row in table)
    path.write_text("\n".join(header) + "\n" + body + "\n")
    return path


def write_step(shape: Any, path: Path) -> Path:
    """Write an OpenCASCADE shape (``TopoDS_Shape``, needs ``cadquery-ocp``) as a STEP file at ``path``."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    writer.Transfer(shape, STEPControl_AsIs)
    if writer.Write(str(path)) != IFSelect_RetDone:
        raise OSError(f"{path}: OpenCASCADE could not write the STEP file")
    return path


def polygon_faces_shape(vertices: np.ndarray, polygons: Sequence[Sequence[int]]) -> Any:
    """A compound of planar faces (needs ``cadquery-ocp``), one per polygon of vertex indices into
    ``vertices`` ``(V, 3)`` mm, each bounded by the closed polygon in its order (counter-clockwise seen
    from the side its normal points to)."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.gp import gp_Pnt
    from OCP.TopoDS import TopoDS_Compound

    builder = BRep_Builder()
    compound = TopoDS_Compound()
    builder.MakeCompound(compound)
    for polygon in polygons:
        wire = BRepBuilderAPI_MakePolygon()
        for index in polygon:
            wire.Add(gp_Pnt(*(float(x) for x in vertices[index])))
        wire.Close()
        builder.Add(compound, BRepBuilderAPI_MakeFace(wire.Wire(), True).Face())
    return compound
