"""Point maps stored compactly: the points of the measured pixels only, exact to the bit.

A point map is ``(H, W, 3)`` float32, millimetres, NaN where not measured (the conventions of
:mod:`metrology.core.geometry.base`). Most of a real capture is not measured (83 % of the pixels
of a real pinhole capture are NaN), so the application stores point maps as an uncompressed
``.npz`` (docs/file-formats.md, "Stored point maps") of three members:

- ``shape``: ``(2,)`` int64, ``(H, W)``;
- ``valid_bits``: uint8, ``numpy.packbits`` of the ``(H, W)`` mask of stored pixels in row-major
  order (``ceil(H * W / 8)`` bytes), or empty when every pixel is stored;
- ``points``: ``(N, 3)`` float32 mm, the stored pixels' points in row-major order.

A pixel is left out only when its three coordinates are all the NaN that numpy writes
(``float32`` bits ``0x7FC00000``, :data:`NOT_MEASURED_BITS`), the value read back there; every
other pixel (finite, partly NaN, another NaN's bits) is stored as it is, so reading returns the
written array bit for bit. Size: ``12 N + ceil(H W / 8)`` bytes (no mask when ``N = H W``) and 776 bytes of headers,
``12 f + 0.125`` bytes per pixel for a measured fraction ``f`` (the float32 depth map is 4).

Point clouds as PLY
-------------------
:func:`ply_point_cloud` writes a binary little-endian PLY point cloud (no faces): per vertex
float64 ``x y z`` (mm), then, each only when given, float64 ``nx ny nz``, float32 ``sigma_mm`` (the
point's standard uncertainty, mm), float32 ``deviation_mm`` (its signed deviation from a nominal,
mm, positive outside the material) and float32 ``intensity``. Without the optional arrays the
file is the plain ``x y z`` cloud. :func:`read_ply` reads any PLY's vertex properties (ASCII or
binary, either byte order) and its triangles, for these files and others.
"""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
import numpy.typing as npt

from metrology.core.io.atomic import atomic_path

NOT_MEASURED_BITS = np.uint32(0x7FC00000)
"""The float32 bits of ``numpy.nan``: a pixel whose three coordinates have these bits is not stored."""

MEMBERS = ("shape", "valid_bits", "points")
"""The ``.npz`` members of a stored point map, in the order they are written."""


def _as_point_map(points_mm: npt.ArrayLike) -> np.ndarray:
    points = np.asarray(points_mm)
    if points.ndim != 3 or points.shape[2] != 3 or 0 in points.shape:
        raise ValueError(f"points must be a non-empty (H, W, 3) array, got shape {points.shape}")
    if points.dtype != np.float32:
        raise ValueError(f"points must be float32, got dtype {points.dtype}")
    return np.ascontiguousarray(points)


def stored_mask(points_mm: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: the pixels of a ``(H, W, 3)`` float32 point map that are stored (not all
    three coordinates bit-equal to ``numpy.nan``, :data:`NOT_MEASURED_BITS`)."""
    bits = _as_point_map(points_mm).view(np.uint32)
    return np.logical_not((bits == NOT_MEASURED_BITS).all(axis=2))


def write_point_map(handle: IO[bytes], points_mm: npt.ArrayLike) -> None:
    """Write a point map to a binary file object as a stored point map (module docstring).

    Parameters
    ----------
    handle : binary file object
        Written from its current position (seekable or not: the ``.npz`` is built in memory).
    points_mm : (H, W, 3) array of float32
        Points, mm, NaN where not measured.
    """
    points = _as_point_map(points_mm)
    height, width = points.shape[:2]
    mask = stored_mask(points)
    kept = points[mask]  # (N, 3) float32, row-major order
    valid_bits = np.empty(0, np.uint8) if kept.shape[0] == height * width else np.packbits(mask.reshape(-1))
    buffer = io.BytesIO()
    np.savez(buffer, shape=np.array([height, width], np.int64), valid_bits=valid_bits, points=kept)
    handle.write(buffer.getbuffer())


def read_point_map(data: bytes) -> np.ndarray:
    """The ``(H, W, 3)`` float32 point map (mm, NaN where not measured) of a stored point map's bytes,
    bit for bit the array written by :func:`write_point_map`; a dense ``(H, W, 3)`` float ``.npy``
    (the format stored before) is read as it is, as float32.

    Raises
    ------
    ValueError
        When ``data`` is neither (the message names what is wrong).
    """
    if data[:4] == b"PK\x03\x04":
        return _read_npz(data)
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"not a point map: {exc}") from exc
    if not isinstance(array, np.ndarray) or array.ndim != 3 or array.shape[2] != 3 or array.dtype.kind != "f":
        raise ValueError("not a point map: expected a (H, W, 3) float array")
    return array.astype(np.float32, copy=False)


def _read_npz(data: bytes) -> np.ndarray:
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            if sorted(npz.files) != sorted(MEMBERS):
                raise ValueError(f"not a stored point map: members {sorted(npz.files)}, expected {sorted(MEMBERS)}")
            shape = npz["shape"]
            valid_bits = npz["valid_bits"]
            kept = npz["points"]
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"not a stored point map: {exc}") from exc
    if shape.shape != (2,) or shape.dtype.kind != "i" or (shape <= 0).any():
        raise ValueError(f"stored point map: bad shape {shape!r}")
    height, width = int(shape[0]), int(shape[1])
    if kept.dtype != np.float32 or kept.ndim != 2 or kept.shape[1] != 3:
        raise ValueError(f"stored point map: points must be (N, 3) float32, got {kept.shape} {kept.dtype}")
    if valid_bits.size == 0:
        if kept.shape[0] != height * width:
            raise ValueError(f"stored point map: {kept.shape[0]} points for {height * width} pixels")
        return kept.reshape(height, width, 3)
    if valid_bits.dtype != np.uint8 or valid_bits.size != -(-height * width // 8):
        raise ValueError(f"stored point map: valid_bits must be {-(-height * width // 8)} uint8")
    mask = np.unpackbits(valid_bits, count=height * width).view(bool)
    if int(mask.sum()) != kept.shape[0]:
        raise ValueError(f"stored point map: {kept.shape[0]} points for {int(mask.sum())} stored pixels")
    points = np.full((height * width, 3), NOT_MEASURED_BITS, np.uint32).view(np.float32)
    points[mask] = kept
    return points.reshape(height, width, 3)


# --------------------------------------------------------------------------- PLY point clouds
PLY_OPTIONAL_PROPERTIES: tuple[tuple[str, str], ...] = (
    ("sigma_mm", "<f4"),
    ("deviation_mm", "<f4"),
    ("intensity", "<f4"),
)
"""The optional scalar vertex properties of :func:`ply_point_cloud`, in file order, with their dtype."""


def _per_point(name: str, values: npt.ArrayLike | None, n: int, columns: int = 1) -> np.ndarray | None:
    if values is None:
        return None
    array = np.asarray(values, dtype=np.float64)
    shape = (n,) if columns == 1 else (n, columns)
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
    return array


def ply_point_cloud(
    points_mm: npt.ArrayLike,
    *,
    normals: npt.ArrayLike | None = None,
    sigma_mm: npt.ArrayLike | None = None,
    deviation_mm: npt.ArrayLike | None = None,
    intensity: npt.ArrayLike | None = None,
) -> bytes:
    """A binary little-endian PLY point cloud (module docstring).

    Parameters
    ----------
    points_mm : (N, 3) array_like of float
        The points, mm (written as float64; NaN points are written as they are: select first).
    normals : (N, 3) array_like of float, optional
    sigma_mm, deviation_mm, intensity : (N,) array_like of float, optional
        Written as float32 vertex properties of those names.

    Raises
    ------
    ValueError
        On a shape that does not match the points (naming the array).
    """
    points = _per_point("points_mm", points_mm, len(np.asarray(points_mm)), 3)
    assert points is not None
    n = len(points)
    layout: list[tuple[str, str]] = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    columns: dict[str, np.ndarray] = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
    normal = _per_point("normals", normals, n, 3)
    if normal is not None:
        layout += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        columns.update(nx=normal[:, 0], ny=normal[:, 1], nz=normal[:, 2])
    given = {"sigma_mm": sigma_mm, "deviation_mm": deviation_mm, "intensity": intensity}
    for name, dtype in PLY_OPTIONAL_PROPERTIES:
        values = _per_point(name, given[name], n)
        if values is not None:
            layout.append((name, dtype))
            columns[name] = values
    block = np.empty(n, dtype=np.dtype(layout))
    for name, values in columns.items():
        block[name] = values
    types = {"<f8": "double", "<f4": "float"}
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment Created by GCPS Lab (mm)\n"
        f"element vertex {n}\n" + "".join(f"property {types[t]} {name}\n" for name, t in layout) + "end_header\n"
    )
    return header.encode("ascii") + block.tobytes()


def write_ply_point_cloud(
    path: str | os.PathLike[str], points_mm: npt.ArrayLike, **properties: npt.ArrayLike | None
) -> Path:
    """Write :func:`ply_point_cloud` of the points (and ``normals``, ``sigma_mm``, ``deviation_mm``,
    ``intensity``) to ``path``, atomically."""
    data = ply_point_cloud(points_mm, **properties)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


_PLY_TYPES: Mapping[str, str] = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass(frozen=True)
class PlyData:
    """What :func:`read_ply` read: each vertex property by name (``(V,)`` arrays of the file's
    types) and the triangles (``(F, 3)`` int64, empty when the file has none)."""

    vertex: Mapping[str, np.ndarray]
    faces: np.ndarray

    @property
    def points(self) -> np.ndarray:
        """``(V, 3)`` float64 ``x y z``."""
        return np.column_stack([np.asarray(self.vertex[c], dtype=np.float64) for c in "xyz"])


def _ply_header(data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, ...]]]], int]:
    """``(format, [(element, count, [property...])], body offset)``; a property is ``(type, name)``
    or ``("list", count type, item type, name)``."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file (no 'ply' magic or no end_header)")
    body = data.index(b"\n", end) + 1
    fmt = ""
    elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(tuple(words[1:]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"PLY format {fmt!r} is not supported")
    return fmt, elements, body


def _ply_type(name: str, order: str) -> np.dtype:
    if name not in _PLY_TYPES:
        raise ValueError(f"PLY property type {name!r} is not supported")
    return np.dtype(order + _PLY_TYPES[name])


def read_ply(data: bytes) -> PlyData:
    """Read a PLY file's vertices (every scalar property) and triangles (``vertex_indices`` or
    ``vertex_index`` lists of 3; other elements are skipped when they have scalar properties only).

    Raises
    ------
    ValueError
        Not a PLY, an unsupported type or format, faces that are not triangles, or a truncated body.
    """
    fmt, elements, offset = _ply_header(data)
    order = ">" if fmt == "binary_big_endian" else "<"
    vertex: dict[str, np.ndarray] = {}
    faces = np.empty((0, 3), dtype=np.int64)
    text = data[offset:].decode("ascii", errors="replace").split() if fmt == "ascii" else None
    position = 0  # in bytes (binary) or in words (ascii)
    for name, count, properties in elements:
        lists = [p for p in properties if p[0] == "list"]
        if lists and (len(properties) != 1 or name != "face"):
            raise ValueError(f"PLY element {name!r}: only a face element of one list property is supported")
        if lists:
            _, count_type, item_type, _ = lists[0]
            if text is not None:
                rows = np.array(text[position : position + 4 * count], dtype=np.float64).reshape(count, 4)
                position += 4 * count
                counts, indices = rows[:, 0], rows[:, 1:]
            else:
                layout = np.dtype([("n", _ply_type(count_type, order)), ("i", _ply_type(item_type, order), (3,))])
                if offset + position + layout.itemsize * count > len(data):
                    raise ValueError("PLY body is truncated")
                records: np.ndarray = np.frombuffer(data, dtype=layout, count=count, offset=offset + position)
                position += layout.itemsize * count
                counts, indices = records["n"], records["i"]
            if count and (counts != 3).any():
                raise ValueError("PLY faces must all be triangles")
            faces = np.asarray(indices, dtype=np.int64).reshape(count, 3)
            continue
        dtype = np.dtype([(p[1], _ply_type(p[0], order)) for p in properties])
        if text is not None:
            width = len(properties)
            if position + width * count > len(text):
                raise ValueError("PLY body is truncated")
            table = np.array(text[position : position + width * count], dtype=np.float64).reshape(count, width)
            position += width * count
            columns = {p[1]: table[:, i].astype(dtype[p[1]]) for i, p in enumerate(properties)}
        else:
            if offset + position + dtype.itemsize * count > len(data):
                raise ValueError("PLY body is truncated")
            values: np.ndarray = np.frombuffer(data, dtype=dtype, count=count, offset=offset + position)
            position += dtype.itemsize * count
            columns = {p[1]: values[p[1]].astype(dtype[p[1]].newbyteorder("=")) for p in properties}
        if name == "vertex":
            vertex = columns
    if not all(c in vertex for c in "xyz"):
        raise ValueError("PLY file has no vertex x, y, z")
    return PlyData(vertex=vertex, faces=faces)
