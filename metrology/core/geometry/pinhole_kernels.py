"""Compiled kernels of the pinhole model's distorted-projector paths (numba, ``nogil``: the tiles
of :func:`metrology.core.tiling.run_tiled` run them on the pool's threads in parallel).

Each kernel does in one pass over a tile what took two dozen numpy passes, seven gathers and
their temporaries (issue 22 item 2):

- :func:`table_tile`: the epipolar table (:class:`~metrology.core.geometry.epipolar_table.EpipolarTable`)
  at each pixel's coded coordinate: the coded normalized coordinate ``q`` and ``dq/dw``;
- :func:`grid_tile`: the projector's undistortion table
  (:class:`~metrology.core.geometry.projector_grid.UndistortionGrid`) at ``(u, v)``: ``q`` and ``dq/dw``;
- :func:`plane_tile`: the plane of ``q`` met by each pixel's camera ray, ``t = (q T_z - T_i) /
  (Rd_i - q Rd_z)`` (NaN unless ``t > 0``), with ``sigma_in`` the point's standard uncertainty
  ``|dt/dq dq/dw| |d| sigma_in``, and the points ``t (x_n, y_n, 1)``.

The equations are those of the two tables' module docstrings and of
:meth:`metrology.core.geometry.pinhole.PreparedPinhole._plane_of`. Every array is one-dimensional
(a tile's contiguous rows, flattened); the arithmetic is float64 inside, float32 in and out.
Compiled on first use and cached on disk (``cache=True``: a new process loads the machine code
instead of compiling it again). This module imports numba: a process that has not imported it
takes the numpy twins of :mod:`metrology.core.geometry.pinhole_numpy` (same numbers), by the rule
of :func:`metrology.core.kernel_choice.use_compiled`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def _table_at(
    w: float, base: int, frac: float, planes: np.ndarray, g0: float, inv_h: float, n_cols: int
) -> tuple[float, float]:  # pragma: no cover - compiled
    """``(q, dq/dw)`` of the epipolar table at the coded coordinate ``w`` of a pixel whose row of
    cells starts at flat index ``base`` with weight ``frac`` to the next row: ``g = (w - g0) / h``
    (``g0 = lo - h``: column 0 is the guard) clipped to the row, cell ``floor(g)``, ``tau = g -
    cell``; ``Q = ((A_3 tau + c_2) tau + c_1) tau + A_0 + frac B_0`` with ``c_m = A_m + frac B_m``
    (``c_2 = A_2`` when ``planes`` has six planes). NaN for NaN input, outside the table (guard
    cells) and for pixels whose line is not tabulated (``frac`` NaN)."""
    g = (w - g0) * inv_h
    if not g >= 0.0:  # NaN too: a NaN index would read anywhere
        if g != g:
            return np.nan, np.nan
        g = 0.0
    top = n_cols - 1e-3
    if g > top:
        g = top
    cell = math.floor(g)
    tau = g - cell
    idx = base + int(cell)
    last = planes.shape[1] - 1
    if idx > last:
        idx = last
    a0 = np.float64(planes[0, idx])
    a1 = np.float64(planes[1, idx])
    a2 = np.float64(planes[2, idx])
    a3 = np.float64(planes[3, idx])
    c1 = a1 + frac * np.float64(planes[5, idx])
    c2 = a2 + frac * np.float64(planes[6, idx]) if planes.shape[0] == 7 else a2
    q = ((a3 * tau + c2) * tau + c1) * tau + a0 + frac * np.float64(planes[4, idx])
    dq = ((3.0 * a3 * tau + 2.0 * c2) * tau + c1) * inv_h
    return q, dq


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def _plane_at(
    q: float, dq: float, rdi: float, rdz: float, tz: float, ti: float
) -> tuple[float, float]:  # pragma: no cover - compiled
    """``(t, dt/dw)``: the ray parameter on the plane of ``q``, ``t = num / den`` with ``num = q T_z -
    T_i``, ``den = Rd_i - q Rd_z`` (NaN unless ``t > 0``; NaN for a NaN ``q``), and ``dt/dq dq/dw``
    with ``dt/dq = (T_z den + num Rd_z) / den^2``."""
    if q != q:  # skipped: arithmetic on NaN is slow on some processors
        return np.nan, np.nan
    num = q * tz - ti
    den = rdi - q * rdz
    t = num / den
    return (t if t > 0.0 else np.nan), (tz * den + num * rdz) / (den * den) * dq


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def table_tile(
    coded: np.ndarray,
    base: np.ndarray,
    frac: np.ndarray,
    planes: np.ndarray,
    g0: float,
    inv_h: float,
    n_cols: int,
    q_out: np.ndarray,
    dq_out: np.ndarray,
    want_dq: bool,
) -> None:  # pragma: no cover - compiled
    """``q_out[i], dq_out[i]`` = :func:`_table_at` of ``coded[i]`` (``(n,)`` float32), ``base[i]``
    (int32), ``frac[i]`` (float32); ``dq_out`` written only with ``want_dq``."""
    for i in range(coded.shape[0]):
        q, dq = _table_at(np.float64(coded[i]), base[i], np.float64(frac[i]), planes, g0, inv_h, n_cols)
        q_out[i] = q
        if want_dq:
            dq_out[i] = dq


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def grid_tile(
    coded: np.ndarray,
    other: np.ndarray,
    planes: np.ndarray,
    g0: float,
    inv_h: float,
    n_cols: int,
    c_lo: float,
    inv_step_c: float,
    n_lines: int,
    axis_u: bool,
    fx: float,
    skew: float,
    cx: float,
    fy: float,
    cy: float,
    q_out: np.ndarray,
    dq_out: np.ndarray,
    want_dq: bool,
) -> None:  # pragma: no cover - compiled
    """``q_out[i], dq_out[i]``: the undistorted normalized coordinate of the coded axis at the
    decoded ``coded[i]``, ``other[i]`` (``(n,)`` float32, projector units) and its derivative
    along the coded axis, from the projector's undistortion table
    (:class:`~metrology.core.geometry.projector_grid.UndistortionGrid`): the affine part
    (``x_lin = (u - cx - s y_lin) / fx``, ``y_lin = (v - cy) / fy``) plus the tabulated
    correction, :func:`_table_at` between the rows ``j`` and ``j + 1`` of ``g = (other - c_lo) /
    step_c`` (clamped to the table). NaN for NaN input."""
    for i in range(coded.shape[0]):
        w = np.float64(coded[i])
        o = np.float64(other[i])
        g = float((o - c_lo) * inv_step_c)
        if g != g:
            q_out[i] = np.nan
            if want_dq:
                dq_out[i] = np.nan
            continue
        g = min(max(g, 0.0), n_lines - 1.0)
        j = min(math.floor(g), n_lines - 2)
        q, dq = _table_at(w, j * n_cols, g - j, planes, g0, inv_h, n_cols)
        u, v = (w, o) if axis_u else (o, w)
        y_lin = (v - cy) / fy
        q_out[i] = q + ((u - cx - skew * y_lin) / fx if axis_u else y_lin)
        if want_dq:
            dq_out[i] = dq + (1.0 / fx if axis_u else 1.0 / fy)


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def plane_tile(
    q: np.ndarray,
    dq: np.ndarray,
    rdi: np.ndarray,
    rdz: np.ndarray,
    tz: float,
    ti: float,
    norm_d: np.ndarray,
    sigma_in: np.ndarray,
    sigma_out: np.ndarray,
    want_sigma: bool,
    xn: np.ndarray,
    yn: np.ndarray,
    points: np.ndarray,
    want_points: bool,
    t_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``t_out[i]``: the ray parameter of pixel ``i`` on the plane of ``q[i]`` (:func:`_plane_at`);
    with ``want_sigma`` ``sigma_out[i] = |dt/dq dq/dw| |d| sigma_in`` (``dq`` read only then); with
    ``want_points`` its point ``t (x_n, y_n, 1)`` at ``points[3 i: 3 i + 3]``. All per-pixel arrays
    ``(n,)`` float32, ``points`` ``(3 n,)``."""
    for i in range(q.shape[0]):
        t, dt = _plane_at(
            np.float64(q[i]), np.float64(dq[i]) if want_sigma else 0.0, np.float64(rdi[i]), np.float64(rdz[i]), tz, ti
        )
        t_out[i] = t
        if want_sigma:
            sigma_out[i] = abs(dt) * np.float64(norm_d[i]) * np.float64(sigma_in[i])
        if want_points:
            points[3 * i] = t * np.float64(xn[i])
            points[3 * i + 1] = t * np.float64(yn[i])
            points[3 * i + 2] = t


def warm() -> None:
    """Load (or compile) the kernels now, on empty arrays of the types the tiles pass: numba's first
    call costs a few tenths of a second, which the preparation of a distorted rig pays on its
    thread (``gcps measure`` reads the captures meanwhile) instead of the first frame."""
    e, planes = np.empty(0, np.float32), np.empty((7, 1), np.float32)
    table_tile(e, np.empty(0, np.int32), e, planes, 0.0, 1.0, 1, e, e, False)
    grid_tile(e, e, planes, 0.0, 1.0, 1, 0.0, 1.0, 2, True, 1.0, 0.0, 0.0, 1.0, 0.0, e, e, False)
    plane_tile(e, e, e, e, 1.0, 0.0, e, e, e, False, e, e, e, False, e)
