"""Parsing and validating the values of calibrated rig files (OpenCV conventions).

The pinhole model (and any later model built of calibrated cameras and projectors) reads its
rig file through these helpers, so every model refuses a bad value with the same sentence:
each error names the key (``camera K``, ``T[2]``...) and the value it got.

- numbers are finite reals (not booleans);
- ``K`` is ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with ``fx, fy > 0``;
- ``dist`` holds 4, 5, 8, 12 or 14 OpenCV coefficients (:mod:`metrology.core.distortion`), or
  none, each within +-:data:`MAX_DISTORTION_COEFFICIENT`;
- a translation ``T`` holds three numbers within +-:data:`MAX_TRANSLATION_MM` mm;
- a camera image side is at most :data:`MAX_IMAGE_SIDE_PX` pixels;
- a rotation ``R`` satisfies ``|R^T R - I| < 1e-6`` and ``det R = +1``;
- a JSON object has only the allowed keys and every required one.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.base import GeometryError

Matrix3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
"""A 3x3 matrix as three rows of three floats (hashable, JSON-shaped)."""

ROTATION_TOL = 1e-6
"""Largest ``|R^T R - I|`` entry accepted for a rotation."""


MAX_DISTORTION_COEFFICIENT = 1e4
"""Largest magnitude of an OpenCV distortion coefficient (real lenses stay far below; larger values
overflow the undistortion's polynomial)."""

MAX_TRANSLATION_MM = 1e5
"""Largest magnitude of a translation component, mm (100 m); also the largest length of a rig
(the crossed-axes model's ``L_mm``, ``d_mm``, ``fw_mm``)."""

MAX_IMAGE_SIDE_PX = 65536
"""Largest camera image side, pixels (a frame of 65536 x 65536 16-bit pixels is 8 GiB)."""


class RigFileError(GeometryError):
    """A rig file is malformed (the message names the key and the value)."""


def number(value: Any, name: str) -> float:
    """``value`` as a finite float; :class:`RigFileError` naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RigFileError(f"{name} must be a number, got {value!r}")
    f = float(value)
    if not math.isfinite(f):
        raise RigFileError(f"{name} must be finite, got {value!r}")
    return f


def bounded(value: Any, name: str, limit: float, unit: str = "") -> float:
    """``value`` as a finite float within ``+-limit``; :class:`RigFileError` naming ``name`` otherwise."""
    f = number(value, name)
    if abs(f) > limit:
        suffix = f" {unit}" if unit else ""
        raise RigFileError(f"{name} must be within +-{limit:g}{suffix}, got {value!r}")
    return f


def matrix3(value: Any, name: str) -> Matrix3:
    """``value`` as three rows of three finite numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise RigFileError(f"{name} must be a 3x3 matrix (three rows of three numbers), got {value!r}")
    rows: list[tuple[float, float, float]] = []
    for i, row in enumerate(value):
        if not isinstance(row, (list, tuple)) or len(row) != 3:
            raise RigFileError(f"{name} row {i} must hold three numbers, got {row!r}")
        a, b, c = (number(x, f"{name}[{i}][{j}]") for j, x in enumerate(row))
        rows.append((a, b, c))
    return (rows[0], rows[1], rows[2])


def vector3(value: Any, name: str, unit: str = "mm") -> tuple[float, float, float]:
    """``value`` as a list of three finite numbers (a translation in ``unit``)."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise RigFileError(f"{name} must be a list of three numbers ({unit}), got {value!r}")
    return (number(value[0], f"{name}[0]"), number(value[1], f"{name}[1]"), number(value[2], f"{name}[2]"))


def translation(value: Any, name: str) -> tuple[float, float, float]:
    """``value`` as a translation: three finite numbers within +-:data:`MAX_TRANSLATION_MM` mm."""
    x, y, z = vector3(value, name)
    for i, component in enumerate((x, y, z)):
        bounded(component, f"{name}[{i}]", MAX_TRANSLATION_MM, "mm")
    return (x, y, z)


def checked_keys(data: Any, allowed: tuple[str, ...], required: tuple[str, ...], where: str) -> Mapping[str, Any]:
    """``data`` when it is a JSON object with only ``allowed`` keys and every ``required`` one."""
    if not isinstance(data, Mapping):
        raise RigFileError(f"{where} must be a JSON object, got {type(data).__name__}")
    unknown = [key for key in data if key not in allowed]
    if unknown:
        raise RigFileError(f"{where} has unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")
    missing = [key for key in required if key not in data]
    if missing:
        raise RigFileError(f"{where} is missing key {missing[0]!r}")
    return data


def intrinsics(value: Any, name: str) -> Matrix3:
    """An OpenCV camera matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with ``fx, fy > 0``."""
    k = matrix3(value, name)
    if k[0][0] <= 0 or k[1][1] <= 0:
        raise RigFileError(f"{name} must have fx > 0 and fy > 0, got fx={k[0][0]!r}, fy={k[1][1]!r}")
    if k[1][0] != 0 or k[2][0] != 0 or k[2][1] != 0 or k[2][2] != 1:
        raise RigFileError(f"{name} must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {list(k)}")
    return k


def distortion_coefficients(value: Any, name: str) -> tuple[float, ...]:
    """OpenCV distortion coefficients: 4, 5, 8, 12 or 14 numbers within +-:data:`MAX_DISTORTION_COEFFICIENT`,
    or none (``None`` or ``[]``)."""
    if value is None:
        return ()
    if not isinstance(value, (list, tuple)):
        raise RigFileError(f"{name} must be a list of 4, 5, 8, 12 or 14 numbers, got {value!r}")
    coeffs = tuple(bounded(x, f"{name}[{i}]", MAX_DISTORTION_COEFFICIENT) for i, x in enumerate(value))
    from metrology.core.distortion import DIST_COUNTS  # here: a rig without distortion does without the module

    if coeffs and len(coeffs) not in DIST_COUNTS:
        raise RigFileError(f"{name} must hold 4, 5, 8, 12 or 14 coefficients (or none), got {len(coeffs)}")
    return coeffs


def positive_int(value: Any, name: str) -> int:
    """A positive integer (an integral float is accepted)."""
    f = number(value, name)
    if not f.is_integer() or f <= 0:
        raise RigFileError(f"{name} must be a positive integer, got {value!r}")
    return int(f)


def image_side(value: Any, name: str) -> int:
    """A camera image side: a positive integer of at most :data:`MAX_IMAGE_SIDE_PX` pixels."""
    side = positive_int(value, name)
    if side > MAX_IMAGE_SIDE_PX:
        raise RigFileError(f"{name} must be at most {MAX_IMAGE_SIDE_PX} pixels, got {value!r}")
    return side


def positive(value: Any, name: str) -> float:
    """A positive finite number."""
    f = number(value, name)
    if f <= 0:
        raise RigFileError(f"{name} must be positive, got {value!r}")
    return f


def check_rotation(R: npt.ArrayLike, name: str = "R") -> None:
    """Raise :class:`RigFileError` naming ``name`` unless ``|R^T R - I| < 1e-6`` and ``det R = +1``."""
    r = np.asarray(R, dtype=np.float64)
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if not err < ROTATION_TOL:
        raise RigFileError(f"{name} is not a rotation: max |R^T R - I| = {err:.3g} (must be < {ROTATION_TOL:g})")
    det = float(np.linalg.det(r))
    if det < 0:
        raise RigFileError(f"{name} is not a rotation: det R = {det:.6g} (a reflection; must be +1)")


def check_projector_size(projector_size: tuple[float, float], width: float, height: float) -> None:
    """:class:`GeometryError` naming both sizes unless the codec's projector ``projector_size``
    (width, height) is the rig's ``width x height`` (within 1e-9 projector units)."""
    w, h = projector_size
    if abs(w - width) > 1e-9 or abs(h - height) > 1e-9:
        raise GeometryError(f"the codec's projector is {w:g}x{h:g} but the rig's projector is {width:g}x{height:g}")


def check_coded_axis(axis: str, triangulate: str, coded_axes: Collection[str], use: str) -> None:
    """:class:`GeometryError` unless ``axis`` (the one the rig ``use``\\ s, chosen by the option
    ``triangulate``) is among the codec's ``coded_axes``."""
    if axis not in coded_axes:
        raise GeometryError(
            f"the codec does not code the projector's {axis} axis, which the {use} "
            f"(triangulate {triangulate}); it codes {', '.join(sorted(coded_axes)) or 'no axis'}"
        )
