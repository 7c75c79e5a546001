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
"""

from __future__ import annotations

import io
import zipfile
from typing import IO

import numpy as np
import numpy.typing as npt

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
