"""Triangulation: light codes to abscissae on R (Eq. 14) and heights (Eqs. 16-17).

All functions are vectorised over arrays of any shape and keep the input's
floating dtype (float32 stays float32: the fast path). NaN propagates, so an
invalid code gives a NaN height.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from metrology.core.rig import Rig

FloatArray = npt.NDArray[np.floating]


def _as_float(values: npt.ArrayLike) -> FloatArray:
    array = np.asarray(values)
    if array.dtype.kind != "f":
        array = array.astype(np.float64)
    return array


def abscissa_from_codes_eq14(rig: Rig, codes: npt.ArrayLike) -> FloatArray:
    """Eq. 14 literally: ``x = L tan(gamma + atan(C1 l cos(g-a) / (1 + C1 l sin(g-a))))``.

    The reference implementation, kept to test the Mobius form against.

    Parameters
    ----------
    rig : Rig
    codes : array_like of float, any shape
        Light codes, code units (0 on ray PS, nlp on ray PT).

    Returns
    -------
    x_mm : ndarray, same shape, float64 unless ``codes`` is float32
        Abscissa on R where the light ray of each code lands, mm from Q.
    """
    l = _as_float(codes)
    g, a = rig.gamma_rad, rig.alpha_rad
    u = rig.C1 * l * math.cos(g - a) / (1 + rig.C1 * l * math.sin(g - a))
    return (rig.L_mm * np.tan(g + np.arctan(u))).astype(l.dtype, copy=False)


def abscissa_from_codes(rig: Rig, codes: npt.ArrayLike) -> FloatArray:
    """Eq. 14 as a Mobius map: ``x = L (t + p l) / (1 + q l)``, no trigonometry.

    Parameters
    ----------
    rig : Rig
    codes : array_like of float, any shape
        Light codes, code units; NaN where invalid.

    Returns
    -------
    x_mm : ndarray, same shape and float dtype as ``codes`` (float64 for ints)
        Abscissa on R, mm from Q. ``x(0) = d - FW/2`` and ``x(nlp) = d + FW/2``.

    Examples
    --------
    >>> from metrology.core.rig import PAPER_RIG as rig
    >>> [round(float(x), 9) for x in abscissa_from_codes(rig, [0.0, rig.nlp])]
    [102.0, 602.0]
    """
    l = _as_float(codes)
    m = rig.mobius
    dt = l.dtype.type
    return dt(m.L_mm) * (dt(m.t) + dt(m.p) * l) / (dt(1.0) + dt(m.q) * l)


def codes_from_abscissa(rig: Rig, x_mm: npt.ArrayLike) -> FloatArray:
    """Inverse of Eq. 14: the light code whose ray lands at abscissa ``x_mm`` on R.

    Parameters
    ----------
    rig : Rig
    x_mm : array_like of float, any shape
        Abscissa on R, mm from Q.

    Returns
    -------
    codes : ndarray, same shape
        Light codes, code units (may fall outside [0, nlp] off the coded field).
    """
    x = _as_float(x_mm)
    m = rig.mobius
    s = x / m.L_mm
    return (s - m.t) / (m.p - m.q * s)


def height_from_abscissae(rig: Rig, x_ref_mm: npt.ArrayLike, x_obj_mm: npt.ArrayLike) -> FloatArray:
    """Eqs. 5 and 17: ``z = L D / (d + D)`` with ``D = x_obj - x_ref``.

    Parameters
    ----------
    x_ref_mm, x_obj_mm : array_like of float, broadcastable
        Abscissae of the reference and object codes, mm.

    Returns
    -------
    z_mm : ndarray
        Height above R, mm.
    """
    return height_from_displacement(rig, _as_float(x_obj_mm) - _as_float(x_ref_mm))


def height_from_displacement(rig: Rig, displacement_mm: npt.ArrayLike) -> FloatArray:
    """Eqs. 5 and 17: ``z = L D / (d + D)`` from the displacement ``D = x_obj - x_ref`` on R, mm."""
    d_r = _as_float(displacement_mm)
    dt = d_r.dtype.type
    return dt(rig.L_mm) * d_r / (dt(rig.d_mm) + d_r)


def reference_slope_mm(rig: Rig, ref_codes: npt.ArrayLike, out: np.ndarray | None = None) -> FloatArray:
    """``L (p - t q) / (1 + q r)`` of reference codes ``r``, mm per code (Eq. 14 as a Mobius map).

    Times ``(l - r) / (1 + q l)`` it is the displacement ``x(l) - x(r)`` on R: the
    difference of two Mobius values, ``L (p - t q)(l - r) / ((1 + q l)(1 + q r))``,
    without subtracting two abscissae of ~500 mm (in float32 that alone costs 0.4 um
    of height). Written into ``out`` when given (same shape, float dtype).
    """
    r = _as_float(ref_codes)
    dt = (out if out is not None else r).dtype.type
    m = rig.mobius
    den = np.multiply(r, dt(m.q), out=out)
    den += dt(1)
    return np.divide(dt(m.L_mm * (m.p - m.t * m.q)), den, out=den)


def displacement_from_codes(rig: Rig, ref_codes: npt.ArrayLike, obj_codes: npt.ArrayLike) -> FloatArray:
    """Eq. 16: the displacement ``D_R = x(OBJ) - x(REF)`` on R of each pixel, mm, from its codes
    (see :func:`reference_slope_mm`); NaN where either code is NaN."""
    r, l = _as_float(ref_codes), _as_float(obj_codes)
    dt = np.result_type(r, l).type
    return reference_slope_mm(rig, r) * (l - r) / (dt(1) + dt(rig.mobius.q) * l)


def height_from_codes(rig: Rig, ref_codes: npt.ArrayLike, obj_codes: npt.ArrayLike) -> FloatArray:
    """Eqs. 16-17: heights from the reference (REF) and object (OBJ) code maps.

    Parameters
    ----------
    rig : Rig
    ref_codes, obj_codes : array_like of float, shape (H, W) (or broadcastable)
        Light codes in code units, NaN where invalid.

    Returns
    -------
    z_mm : ndarray, shape (H, W), float32 when both inputs are float32
        Height above R, mm; NaN where either code is NaN.
    """
    return height_from_displacement(rig, displacement_from_codes(rig, ref_codes, obj_codes))


def points_from_heights(rig: Rig, z_mm: npt.ArrayLike) -> FloatArray:
    """3D coordinates of every pixel (DESIGN.md 1.1): ``(X_H, Y_H, z)``.

    ``X_H = d + (1 - z/L)(x_A - d)`` and ``Y_H = (1 - z/L) Y_A`` place each
    measured point on its camera ray CA.

    Parameters
    ----------
    rig : Rig
    z_mm : array_like, shape (height_px, width_px)
        Height map, mm, NaN where not measured.

    Returns
    -------
    xyz_mm : ndarray, shape (height_px, width_px, 3), float64
        X, Y, Z of each pixel's point, mm; NaN rows where ``z`` is NaN.
    """
    z = np.asarray(z_mm, dtype=np.float64)
    if z.shape != rig.shape:
        raise ValueError(f"z_mm must have the rig's shape {rig.shape}, got {z.shape}")
    scale = 1.0 - z / rig.L_mm
    x_a = rig.column_x_mm()[None, :]
    y_a = rig.row_y_mm()[:, None]
    xyz = np.empty((*z.shape, 3), dtype=np.float64)
    xyz[..., 0] = rig.d_mm + scale * (x_a - rig.d_mm)
    xyz[..., 1] = scale * y_a
    xyz[..., 2] = z
    return xyz
