"""Reading triangle meshes and point clouds for inspection: STL (binary and ASCII), PLY (binary
little/big endian and ASCII) and OBJ, to plain numpy arrays.

- :func:`read_stl` parses both STL forms itself: a file whose size is ``84 + 50 n`` with ``n`` the
  little-endian uint32 at byte 80 is binary, anything starting with ``solid`` otherwise is ASCII.
  It returns the corner coordinates of each facet (``(F, 3, 3)`` float64); the facet normals
  stored in the file are ignored (the winding decides the orientation).
- :func:`read_ply_vertices` reads the ``vertex`` element of a PLY file (``x y z`` and any other
  scalar properties, e.g. ``sigma_mm``); other elements (faces) are skipped. In a binary file
  an element with list properties may only come after ``vertex``.
- :func:`read_mesh_arrays` reads a mesh of any of the three formats: STL as above, PLY and OBJ
  through Open3D (``enable_post_processing=False``: no vertex merging, no normal changes).
- :func:`triangle_mesh_ply_bytes` writes a triangle mesh as a binary PLY with double vertices (how
  the application stores a STEP nominal's tessellation), read back exactly by :func:`read_mesh_arrays`.

Every reader raises ``ValueError`` with a one-line message on a malformed or empty file.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

MESH_SUFFIXES = (".stl", ".ply", ".obj")
"""File extensions a nominal mesh may have (case-insensitive)."""

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_FLOAT = rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_STL_VERTEX = re.compile(rb"vertex\s+(" + _FLOAT + rb")\s+(" + _FLOAT + rb")\s+(" + _FLOAT + rb")")


def read_stl(data: bytes) -> np.ndarray:
    """``(F, 3, 3)`` float64: the three corners (x, y, z) of each facet of an STL file's bytes,
    binary or ASCII (module docstring). ValueError on anything else."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
            facets = np.frombuffer(data, record, count, 84)
            return facets["corners"].astype(np.float64)
    if not data.lstrip()[:5].lower() == b"solid":
        raise ValueError("not an STL file: neither binary (84 + 50 n bytes) nor ASCII (starting with 'solid')")
    values = np.array(_STL_VERTEX.findall(data), dtype=np.float64)
    if values.size == 0:
        return np.zeros((0, 3, 3))
    if values.shape[0] % 3:
        raise ValueError(f"ASCII STL: {values.shape[0]} vertex lines, not a multiple of 3")
    if values.shape[0] != data.count(b"vertex"):
        raise ValueError("ASCII STL: a vertex line could not be read as three numbers")
    return values.reshape(-1, 3, 3)


def _ply_header(data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str, str | None]]]], int]:
    """The format, the elements ``(name, count, [(property, type, list count type or None)])``
    and the byte offset of the body of a PLY file."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file (no 'ply' magic or no 'end_header')")
    body = data.find(b"\n", end) + 1
    lines = data[:end].decode("ascii", "replace").splitlines()
    fmt = ""
    elements: list[tuple[str, int, list[tuple[str, str, str | None]]]] = []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list" and len(words) == 5:
                elements[-1][2].append((words[4], _ply_type(words[3]), _ply_type(words[2])))
            elif len(words) == 3:
                elements[-1][2].append((words[2], _ply_type(words[1]), None))
            else:
                raise ValueError(f"PLY header: bad line {line!r}")
        else:
            raise ValueError(f"PLY header: bad line {line!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"PLY header: unknown format {fmt!r}")
    return fmt, elements, body


def _ply_type(name: str) -> str:
    if name not in _PLY_TYPES:
        raise ValueError(f"PLY header: unknown property type {name!r}")
    return _PLY_TYPES[name]


def read_ply_vertices(data: bytes) -> dict[str, np.ndarray]:
    """The scalar properties of the ``vertex`` element of a PLY file's bytes: property name ->
    ``(N,)`` array in the file's vertex order (as stored: float32 stays float32). ValueError when
    the file is malformed, has no ``vertex`` element, or lacks ``x``, ``y`` or ``z``."""
    fmt, elements, offset = _ply_header(data)
    names = [name for name, _, _ in elements]
    if "vertex" not in names:
        raise ValueError("PLY: no 'vertex' element")
    before = elements[: names.index("vertex")]
    _, count, properties = elements[names.index("vertex")]
    if any(kind is not None for _, _, kind in properties):
        raise ValueError("PLY: list properties in the 'vertex' element are not supported")
    if not {"x", "y", "z"} <= {name for name, _, _ in properties}:
        raise ValueError("PLY: the 'vertex' element lacks x, y or z")
    if fmt == "ascii":
        lines = data[offset:].splitlines()
        skip = sum(n for _, n, _ in before)
        rows = lines[skip : skip + count]
        if len(rows) < count:
            raise ValueError(f"PLY: {len(rows)} vertex lines for {count} vertices")
        table = np.loadtxt(rows, dtype=np.float64, ndmin=2) if count else np.zeros((0, len(properties)))
        if table.shape[1] < len(properties):
            raise ValueError("PLY: a vertex line has fewer values than the header's properties")
        return {name: table[:, i].astype(kind) for i, (name, kind, _) in enumerate(properties)}
    order = "<" if fmt == "binary_little_endian" else ">"
    for name, n, props in before:
        if any(kind is not None for _, _, kind in props):
            raise ValueError(f"PLY: element {name!r} with list properties before 'vertex' is not supported")
        offset += n * np.dtype([(p, order + t) for p, t, _ in props]).itemsize
    record = np.dtype([(name, order + kind) for name, kind, _ in properties])
    if len(data) < offset + count * record.itemsize:
        raise ValueError(f"PLY: file too short for {count} vertices")
    records: Any = np.frombuffer(data, record, count, offset)  # a structured array: indexed by field name
    columns = {name: np.asarray(records[name]) for name, _, _ in properties}
    return {name: values.astype(values.dtype.newbyteorder("=")) for name, values in columns.items()}


def read_mesh_arrays(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float64, faces (F, 3) int64)`` of a mesh file (STL, PLY or OBJ, by its
    extension). STL facets come as three vertices each (``faces = arange(3F).reshape(F, 3)``);
    PLY and OBJ as their file indexes them (polygons triangulated by Open3D). ValueError when the
    file is unreadable or not a mesh of that format."""
    file = Path(path)
    suffix = file.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"{file.name}: a mesh must be {', '.join(MESH_SUFFIXES)}")
    if not file.is_file():
        raise ValueError(f"{file}: no such file")
    if suffix == ".stl":
        corners = read_stl(file.read_bytes())
        return corners.reshape(-1, 3), np.arange(corners.shape[0] * 3, dtype=np.int64).reshape(-1, 3)
    if suffix == ".ply":
        with file.open("rb") as handle:
            _ply_header(handle.read(1 << 16))  # a malformed header is refused with its reason
    import open3d

    mesh = open3d.io.read_triangle_mesh(file, enable_post_processing=False, print_progress=False)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.triangles, dtype=np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"{file.name}: a face refers to a vertex that does not exist")
    return vertices, faces


def ply_points_bytes(columns: dict[str, np.ndarray]) -> bytes:
    """A binary little-endian PLY of vertices only: ``columns`` maps property names (``x``, ``y``,
    ``z`` first, then e.g. ``deviation_mm``, ``sigma_mm``) to ``(N,)`` arrays, written as float32."""
    names = list(columns)
    count = len(next(iter(columns.values()))) if columns else 0
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property float {name}" for name in names]
    header.append("end_header")
    table = np.empty(count, np.dtype([(name, "<f4") for name in names]))
    for name in names:
        table[name] = columns[name]
    return ("\n".join(header) + "\n").encode("ascii") + table.tobytes()


def triangle_mesh_ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A binary little-endian PLY triangle mesh: ``vertices`` ``(V, 3)`` mm written as double (read
    back bit for bit by :func:`read_mesh_arrays`), ``faces`` ``(F, 3)`` vertex indices as int32,
    their order (winding) kept."""
    points = np.ascontiguousarray(vertices, dtype="<f8").reshape(-1, 3)
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if triangles.size and (triangles.min() < 0 or triangles.max() >= points.shape[0]):
        raise ValueError("a face refers to a vertex that does not exist")
    header = [
        "ply",
        "format binary_little_endian 1.0",
        f"element vertex {points.shape[0]}",
        "property double x",
        "property double y",
        "property double z",
        f"element face {triangles.shape[0]}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    table = np.empty(triangles.shape[0], np.dtype([("n", "u1"), ("index", "<i4", (3,))]))
    table["n"] = 3
    table["index"] = triangles
    return ("\n".join(header) + "\n").encode("ascii") + points.tobytes() + table.tobytes()
