"""Height maps: float32 ``.npy`` and float32 TIFF, millimetres, NaN where not measured."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.io.atomic import _write_bytes_atomic, atomic_binary_file


def _as_height_map(z_mm: npt.ArrayLike) -> np.ndarray:
    z = np.asarray(z_mm)
    if z.ndim != 2 or 0 in z.shape:
        raise ValueError(f"z_mm must be a non-empty (H, W) array, got shape {z.shape}")
    if z.dtype.kind not in "fiu":
        raise ValueError(f"z_mm must be numeric, got dtype {z.dtype}")
    return np.ascontiguousarray(z, dtype=np.float32)


def write_height_npy(z_mm: npt.ArrayLike, path: str | os.PathLike[str]) -> None:
    """Write a height map as a float32 ``.npy`` file, atomically (docs/file-formats.md).

    Parameters
    ----------
    z_mm : (H, W) array_like of float
        Heights above R, mm, NaN where not measured; stored as float32.
    path : path
        Destination file (conventionally ending in ``.npy``; used verbatim).
    """
    z = _as_height_map(z_mm)
    # np.save straight into the temporary file (the bytes an in-memory np.save would hold, without
    # its two frame-sized copies)
    with atomic_binary_file(path) as fh:
        np.save(fh, z, allow_pickle=False)


def read_height_npy(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a height map written by :func:`write_height_npy`: ``(H, W)`` float32, mm, NaN where invalid."""
    z = np.load(Path(path), allow_pickle=False)
    if not isinstance(z, np.ndarray) or z.ndim != 2 or z.dtype.kind != "f":
        raise ValueError(f"{Path(path).name} is not a (H, W) float height map")
    return z.astype(np.float32, copy=False)


def write_height_tiff(z_mm: npt.ArrayLike, path: str | os.PathLike[str]) -> None:
    """Write a height map as a single-channel float32 TIFF (NaN kept), atomically.

    Parameters
    ----------
    z_mm : (H, W) array_like of float
        Heights above R, mm, NaN where not measured; stored as float32.
    path : path
        Destination file; the format is TIFF whatever the extension.
    """
    z = _as_height_map(z_mm)
    ok, buf = cv2.imencode(".tiff", z)
    if not ok:
        raise OSError("OpenCV could not encode the height map as TIFF")
    _write_bytes_atomic(path, buf.tobytes())
