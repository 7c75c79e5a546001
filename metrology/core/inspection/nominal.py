"""The nominal model of an inspection: a validated triangle mesh in millimetres.

:func:`read_nominal` reads binary or ASCII STL, PLY or OBJ (:mod:`metrology.core.io.meshes`), and STEP
where OpenCASCADE is installed (:mod:`metrology.core.io.step`, tessellated with a recorded
tolerance), and :func:`nominal_from_arrays` validates any vertex/face arrays:

- units: millimetres, as the file's numbers are (STL, PLY and OBJ carry no unit);
- vertices with bit-identical coordinates are merged (an STL stores each facet's corners
  separately), so that edges shared by two facets are known;
- degenerate faces (two equal corners after merging, or an area below ``1e-12`` of the squared
  bounding diagonal) are dropped and counted;
- refused (``ValueError``) when nothing is left, or a coordinate is not finite;
- orientation: a mesh is *closed* when every edge belongs to exactly two faces, and
  *consistently oriented* when those two faces run along it in opposite directions. A closed,
  consistent mesh of signed volume ``V = sum(det[a, b, c]) / 6 > 0`` has its faces oriented
  outward (right-hand rule); with ``V < 0`` every face is flipped (with a warning). An open or
  inconsistent mesh is accepted with a warning: the sign of a deviation then follows each face's
  own winding (counter-clockwise seen from outside, the right-hand normal pointing outward).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metrology.core.io.meshes import read_mesh_arrays

UNITS = "mm"
DEGENERATE_AREA = 1e-12
"""A face whose area is below this fraction of the squared bounding-box diagonal is degenerate."""


@dataclass(frozen=True, eq=False)
class NominalModel:
    """A validated triangle mesh, mm (module docstring).

    Attributes
    ----------
    vertices : (V, 3) float64
        Vertex coordinates, mm, identical ones merged.
    faces : (F, 3) int32
        Vertex indices of each face, counter-clockwise seen from outside where the orientation is known.
    sha256 : str
        Hex digest of the file read (of the arrays' bytes when built from arrays).
    name : str
        File name (or the caller's label).
    degenerate_faces : int
        Faces dropped as degenerate.
    closed : bool
        Every edge belongs to exactly two faces.
    consistent : bool
        Every edge shared by two faces is run in opposite directions by them.
    signed_volume_mm3 : float
        ``sum(det[a, b, c]) / 6`` over the faces as kept (> 0 for a closed outward mesh).
    flipped : bool
        The file's faces were all inward and have been flipped.
    warnings : tuple of str
        How the sign is decided when the orientation is not established.
    tessellation : dict or None
        How a STEP solid became triangles (method and tolerances, :func:`metrology.core.io.step.read_step`);
        None for a mesh file.
    """

    vertices: np.ndarray
    faces: np.ndarray
    sha256: str
    name: str = ""
    degenerate_faces: int = 0
    closed: bool = False
    consistent: bool = False
    signed_volume_mm3: float = 0.0
    flipped: bool = False
    warnings: tuple[str, ...] = field(default=())
    tessellation: dict[str, Any] | None = None

    @property
    def units(self) -> str:
        return UNITS

    @property
    def triangle_count(self) -> int:
        return int(self.faces.shape[0])

    @property
    def bounds_mm(self) -> tuple[list[float], list[float]]:
        """The axis-aligned bounding box: ``(minimum [x, y, z], maximum [x, y, z])``, mm."""
        return self.vertices.min(axis=0).tolist(), self.vertices.max(axis=0).tolist()

    @property
    def size_mm(self) -> list[float]:
        """The bounding box's extent along x, y, z, mm."""
        low, high = self.bounds_mm
        return [h - lo for lo, h in zip(low, high, strict=True)]

    @property
    def oriented(self) -> bool:
        """The outward orientation is established (closed and consistent)."""
        return self.closed and self.consistent

    def face_normals(self) -> np.ndarray:
        """``(F, 3)`` float64 unit normals ``(b - a) x (c - a) / |...|`` (right-hand rule)."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        cross = np.cross(b - a, c - a)
        return cross / np.linalg.norm(cross, axis=1, keepdims=True)

    def area_mm2(self) -> float:
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    def summary(self) -> dict[str, Any]:
        """JSON form for reports: name, sha256, units, size, counts, orientation, warnings."""
        low, high = self.bounds_mm
        return {
            "name": self.name,
            "sha256": self.sha256,
            "units": UNITS,
            "triangles": self.triangle_count,
            "vertices": int(self.vertices.shape[0]),
            "bounds_mm": {"min": low, "max": high},
            "size_mm": self.size_mm,
            "degenerate_faces_dropped": self.degenerate_faces,
            "closed": self.closed,
            "consistently_oriented": self.consistent,
            "signed_volume_mm3": self.signed_volume_mm3,
            "flipped": self.flipped,
            "warnings": list(self.warnings),
            **({"tessellation": dict(self.tessellation)} if self.tessellation is not None else {}),
        }


def read_nominal(path: str | os.PathLike[str]) -> NominalModel:
    """The validated nominal model of a mesh file (STL, PLY, OBJ) or a STEP file (``.step``/``.stp``,
    with ``cadquery-ocp``), mm; ValueError with a one-line message when the file is unreadable or
    holds no usable triangle, or is STEP without OpenCASCADE."""
    from dataclasses import replace

    from metrology.core.io.step import STEP_SUFFIXES, read_step

    file = Path(path)
    tessellation = None
    if file.suffix.lower() in STEP_SUFFIXES:
        try:
            vertices, faces, tessellation = read_step(file)
        except ImportError as exc:
            raise ValueError(str(exc)) from None
    else:
        vertices, faces = read_mesh_arrays(file)
    digest = hashlib.sha256(file.read_bytes()).hexdigest()
    nominal = nominal_from_arrays(vertices, faces, sha256=digest, name=file.name)
    return nominal if tessellation is None else replace(nominal, tessellation=tessellation)


def nominal_from_arrays(
    vertices: np.ndarray, faces: np.ndarray, *, sha256: str | None = None, name: str = ""
) -> NominalModel:
    """Validate ``vertices`` ``(V, 3)`` mm and ``faces`` ``(F, 3)`` indices (module docstring)."""
    points = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    label = name or "mesh"
    if triangles.shape[0] == 0 or points.shape[0] == 0:
        raise ValueError(f"{label}: the mesh has no triangles")
    if not np.isfinite(points).all():
        raise ValueError(f"{label}: a vertex coordinate is not finite")
    if triangles.min() < 0 or triangles.max() >= points.shape[0]:
        raise ValueError(f"{label}: a face refers to a vertex that does not exist")
    if sha256 is None:
        sha256 = hashlib.sha256(points.tobytes() + triangles.tobytes()).hexdigest()
    used = np.unique(triangles)
    unique, inverse = np.unique(points[used], axis=0, return_inverse=True)
    remap = np.zeros(points.shape[0], np.int64)
    remap[used] = inverse.reshape(-1)
    triangles = remap[triangles]
    diagonal = float(np.linalg.norm(unique.max(axis=0) - unique.min(axis=0)))
    a, b, c = (unique[triangles[:, k]] for k in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    repeated = (
        (triangles[:, 0] == triangles[:, 1])
        | (triangles[:, 1] == triangles[:, 2])
        | (triangles[:, 0] == triangles[:, 2])
    )
    degenerate = repeated | (area2 <= 2 * DEGENERATE_AREA * diagonal**2)
    triangles = triangles[~degenerate]
    if triangles.shape[0] == 0:
        raise ValueError(f"{label}: every triangle is degenerate")
    closed, consistent = edge_topology(triangles)
    volume = signed_volume(unique, triangles)
    warnings: list[str] = []
    flipped = False
    if closed and consistent and volume < 0:
        triangles = triangles[:, ::-1]
        volume = -volume
        flipped = True
        warnings.append("the faces were oriented inward (negative signed volume): all were flipped")
    elif not (closed and consistent):
        what = "open" if not closed else "inconsistently oriented"
        warnings.append(
            f"the mesh is {what}: the sign of a deviation follows each face's winding "
            "(positive on the side of the right-hand normal (b - a) x (c - a))"
        )
    return NominalModel(
        vertices=unique,
        faces=np.ascontiguousarray(triangles, dtype=np.int32),
        sha256=sha256,
        name=name,
        degenerate_faces=int(degenerate.sum()),
        closed=closed,
        consistent=consistent,
        signed_volume_mm3=volume,
        flipped=flipped,
        warnings=tuple(warnings),
    )


def edge_topology(faces: np.ndarray) -> tuple[bool, bool]:
    """``(closed, consistent)`` of ``(F, 3)`` faces: closed when every undirected edge belongs to
    exactly two faces; consistent when no directed edge ``(a, b)`` occurs twice (two faces sharing
    an edge run it in opposite directions)."""
    start = faces.reshape(-1).astype(np.int64)
    end = faces[:, [1, 2, 0]].reshape(-1).astype(np.int64)
    n = int(max(start.max(), end.max())) + 1
    directed = start * n + end
    undirected = np.minimum(start, end) * n + np.maximum(start, end)
    _, counts = np.unique(undirected, return_counts=True)
    consistent = np.unique(directed).size == directed.size
    return bool((counts == 2).all()), bool(consistent)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """``sum(det[a - o, b - o, c - o]) / 6``, mm^3, about the vertices' centroid ``o``."""
    centred = vertices - vertices.mean(axis=0)
    a, b, c = (centred[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
