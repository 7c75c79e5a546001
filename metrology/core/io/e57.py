"""Point clouds as ASTM E2807 (E57) files, through ``pye57`` (libE57Format).

:func:`write_e57` writes one scan (one ``data3D`` entry) of the measured points:

- ``cartesianX/Y/Z`` in **metres** (E57's unit), float32 as ``pye57`` writes them, stored relative
  to the points' centroid so that float32 keeps about 0.01 um within 100 mm of it; the centroid
  goes into the scan's pose, so a reader that applies the pose (every E57 reader: the pose maps the
  scan's coordinates to the file's) gets the points where they are;
- the scan's **pose**: ``x_file = R x_scan + t`` (``R`` a rotation, ``t`` in mm; identity by
  default: the file's frame is the rig's model frame), written as E57's unit quaternion and
  translation in metres;
- ``intensity`` (optional, e.g. the fringe **modulation** of each point), float32;
- ``rowIndex`` / ``columnIndex``: each point's camera pixel when the points are given as an
  ``(H, W, 3)`` map (NaN pixels are left out), or its position in the ``(N, 3)`` list.

:func:`read_e57` reads every scan back, in the file's frame, in millimetres.

``pye57`` is an optional dependency (``pip install gcps-lab[e57]``, part of ``[dev]``); both
functions raise :class:`ImportError` with that advice where it is absent.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.io.atomic import atomic_path

FloatArray = npt.NDArray[np.float64]

MM_PER_M = 1000.0


def _pye57() -> Any:
    try:
        import pye57
    except ImportError as exc:  # pragma: no cover - the dev install has it
        raise ImportError("E57 files need pye57: pip install 'gcps-lab[e57]'") from exc
    return pye57


def _quaternion(rotation: FloatArray) -> FloatArray:
    """``(w, x, y, z)`` unit quaternion of a rotation matrix, ``w >= 0``."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    q = np.array([w, x, y, z], dtype=np.float64)
    return q if w >= 0 else -q


def _pose(rotation: npt.ArrayLike | None, translation_mm: npt.ArrayLike | None) -> tuple[FloatArray, FloatArray]:
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    t = np.zeros(3) if translation_mm is None else np.asarray(translation_mm, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
        raise ValueError("rotation must be a 3 x 3 rotation matrix (orthonormal, determinant +1)")
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ValueError(f"translation_mm must be 3 finite numbers, got {translation_mm!r}")
    return r, t


def write_e57(
    path: str | os.PathLike[str],
    points_mm: npt.ArrayLike,
    *,
    intensity: npt.ArrayLike | None = None,
    rotation: npt.ArrayLike | None = None,
    translation_mm: npt.ArrayLike | None = None,
    name: str = "GCPS Lab scan",
) -> Path:
    """Write one scan as an E57 file, atomically (module docstring).

    Parameters
    ----------
    path : path
        Destination (``.e57``).
    points_mm : (H, W, 3) or (N, 3) array_like of float
        Points in the scan's frame (the rig's model frame), mm; a point with a NaN coordinate is left out.
    intensity : (H, W) or (N,) array_like of float, optional
        Each point's intensity (the modulation, for instance).
    rotation, translation_mm : optional
        The scan's pose ``x_file = rotation @ x_scan + translation_mm`` (mm). Default identity.
    name : str
        The scan's name in the file.

    Raises
    ------
    ValueError
        No finite point, shapes that do not match, or a pose that is not a rotation and a translation.
    """
    pye57 = _pye57()
    points = np.asarray(points_mm, dtype=np.float64)
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise ValueError(f"points_mm must be (H, W, 3) or (N, 3), got shape {points.shape}")
    grid = points.shape[:-1]
    rows, columns = np.indices(grid if points.ndim == 3 else (grid[0], 1)).reshape(2, -1)
    flat = points.reshape(-1, 3)
    keep = np.isfinite(flat).all(axis=1)
    if not keep.any():
        raise ValueError("no finite point to write")
    values = None
    if intensity is not None:
        values = np.asarray(intensity, dtype=np.float64)
        if values.shape != grid:
            raise ValueError(f"intensity must have shape {grid}, got {values.shape}")
        values = values.reshape(-1)[keep]
        if not np.isfinite(values).all():
            raise ValueError("intensity must be finite at every finite point")
    r, t = _pose(rotation, translation_mm)
    kept = flat[keep]
    centre = kept.mean(axis=0)
    local_m = (kept - centre) / MM_PER_M
    data: dict[str, np.ndarray] = {
        "cartesianX": local_m[:, 0],
        "cartesianY": local_m[:, 1],
        "cartesianZ": local_m[:, 2],
        "rowIndex": rows[keep].astype(np.int32),
        "columnIndex": columns[keep].astype(np.int32),
    }
    if values is not None:
        data["intensity"] = values
    # x_file = R (local + centre) + t: the pose of the centred coordinates is (R, R centre + t)
    path = Path(path)
    with atomic_path(path) as tmp:
        e57 = pye57.E57(str(tmp), mode="w")
        try:
            e57.write_scan_raw(data, name=name, rotation=_quaternion(r), translation=(r @ centre + t) / MM_PER_M)
        finally:
            e57.close()
    return path


@dataclass(frozen=True, eq=False)
class E57Scan:
    """One scan read from an E57 file.

    Attributes
    ----------
    name : str
    points_mm : (N, 3) float64
        The points in the file's frame (the scan's pose applied), mm.
    intensity : (N,) float64 or None
    row, column : (N,) int64 or None
        Each point's grid position, when the file has them.
    rotation : (3, 3) float64
    translation_mm : (3,) float64
        The scan's pose as stored (``x_file = rotation @ x_stored + translation``; a file written by
        :func:`write_e57` stores coordinates relative to the points' centroid).
    """

    name: str
    points_mm: FloatArray
    intensity: FloatArray | None
    row: npt.NDArray[np.int64] | None
    column: npt.NDArray[np.int64] | None
    rotation: FloatArray
    translation_mm: FloatArray


def read_e57(path: str | os.PathLike[str]) -> list[E57Scan]:
    """Every scan of an E57 file (:class:`E57Scan`), points in mm in the file's frame.

    Raises
    ------
    ValueError
        When the file cannot be read as E57 (the library's message).
    """
    pye57 = _pye57()
    try:
        e57 = pye57.E57(str(path), mode="r")
    except Exception as exc:  # libE57Format raises its own exception types
        raise ValueError(f"not a readable E57 file: {exc}") from exc
    scans = []
    try:
        for index in range(e57.scan_count):
            header = e57.get_header(index)
            raw = e57.read_scan_raw(index)
            stored = np.column_stack([raw[c] for c in ("cartesianX", "cartesianY", "cartesianZ")]).astype(np.float64)
            rotation = np.asarray(header.rotation_matrix, dtype=np.float64)
            translation_mm = np.asarray(header.translation, dtype=np.float64) * MM_PER_M
            scans.append(
                E57Scan(
                    name=str(header["name"].value()),
                    points_mm=stored * MM_PER_M @ rotation.T + translation_mm,
                    intensity=np.asarray(raw["intensity"], dtype=np.float64) if "intensity" in raw else None,
                    row=np.asarray(raw["rowIndex"], dtype=np.int64) if "rowIndex" in raw else None,
                    column=np.asarray(raw["columnIndex"], dtype=np.int64) if "columnIndex" in raw else None,
                    rotation=rotation,
                    translation_mm=translation_mm,
                )
            )
    finally:
        e57.close()
    return scans
