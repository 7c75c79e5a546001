"""Result arrays of a measurement job written to storage under the attempt's own prefix.

The measurement handler stores its maps so:
``.npy`` files (the points as a stored point map, ``points.npz``:
:mod:`metrology.core.io.points`) under ``measurements/<id>/<attempt token>/``, referenced by the row only when the
attempt commits (:mod:`metrology.jobs.services`), so a half-written result is never visible.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np
from django.core.files import File
from django.core.files.storage import default_storage

from metrology.jobs.services import JobRun


def save_arrays(run: JobRun, prefix: str, arrays: dict[str, np.ndarray]) -> dict[str, str]:
    """Save each array as ``prefix/<file name>`` (``.npy``); returns file name -> stored name."""
    names: dict[str, str] = {}
    for filename, array in arrays.items():
        buffer = io.BytesIO()
        np.save(buffer, array)
        buffer.seek(0)
        names[filename] = run.save_file(default_storage, f"{prefix}/{filename}", File(buffer, name=filename))
    return names


def save_point_map(run: JobRun, prefix: str, points_mm: np.ndarray) -> str:
    """Save a ``(H, W, 3)`` float32 point map (mm, NaN where not measured) as ``prefix/points.npz``,
    the measured pixels' points and a bit mask (:func:`metrology.core.io.points.write_point_map`,
    12 bytes per measured pixel and 1 bit per pixel); returns the stored name."""
    from metrology.core.io.points import write_point_map

    buffer = io.BytesIO()
    write_point_map(buffer, points_mm)
    buffer.seek(0)
    return run.save_file(default_storage, f"{prefix}/points.npz", File(buffer, name="points.npz"))


def sigma_statistics(sigma_mm: np.ndarray | None) -> dict[str, Any]:
    """``{"sigma_mm_median": ...}`` over the finite per-point sigmas (None when there are none);
    empty when no sigma map was computed."""
    if sigma_mm is None:
        return {}
    finite = sigma_mm[np.isfinite(sigma_mm)]
    return {"sigma_mm_median": float(np.median(finite)) if finite.size else None}


def remove_other_attempts(prefix: str) -> None:
    """Delete files that earlier, killed attempts left under sibling prefixes of ``prefix`` (never
    referenced by a row: an attempt's files are referenced only when it commits)."""
    parent, _, mine = prefix.rpartition("/")
    try:
        folders, _files = default_storage.listdir(parent)
    except (OSError, NotImplementedError):
        return
    for folder in folders:
        if folder == mine:
            continue
        try:
            _sub, files = default_storage.listdir(f"{parent}/{folder}")
            for name in files:
                default_storage.delete(f"{parent}/{folder}/{name}")
            default_storage.delete(f"{parent}/{folder}")
        except OSError:
            continue
