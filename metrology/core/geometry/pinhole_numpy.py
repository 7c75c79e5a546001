"""The pinhole model's distorted-projector tile kernels in vectorised numpy, twins of the compiled
ones (:mod:`metrology.core.geometry.pinhole_kernels`), and :func:`tile_kernels`, which chooses.

Each function takes the arguments of its compiled twin and writes the same outputs:

- :func:`table_tile`: the epipolar table at each pixel's coded coordinate, ``q`` and ``dq/dw``;
- :func:`grid_tile`: the projector's undistortion table at ``(u, v)``, ``q`` and ``dq/dw``;
- :func:`plane_tile`: ``t = (q T_z - T_i) / (Rd_i - q Rd_z)`` (NaN unless ``t > 0``), the sigma
  ``|dt/dq dq/dw| |d| sigma_in`` and the points ``t (x_n, y_n, 1)``.

The arithmetic is the compiled kernels', operation for operation, in float64 on the float32
inputs, rounded to float32 on output. The two differ only by float64 rounding (the compiled code
may fuse a multiply and an add): their float32 outputs are equal but where a float64 result lies
within a few 1e-16 of a float32 rounding boundary, a float32 ulp apart there (tests:
``tests/core/test_pinhole_numpy.py``). Every array is one-dimensional (a tile's rows, flattened).

A ``gcps measure`` process triangulates one frame: importing numba and loading the compiled
kernels from its cache (0.5-1 s of CPU) cost far more than they save on it (about 20 ms of CPU
per 1280x1024 frame), so a process that has not imported numba takes these, by the rule of the
decoders (:func:`metrology.core.kernel_choice.use_compiled`): Celery workers, which load numba
as they start, and warm benchmarks take the compiled ones.
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from metrology.core.kernel_choice import use_compiled


def tile_kernels(pixels: int) -> ModuleType:
    """The module whose ``table_tile``, ``grid_tile`` and ``plane_tile`` triangulate frames of
    ``pixels`` pixels (their arrays as :func:`flat` makes them): :mod:`metrology.core.geometry.pinhole_kernels` where
    :func:`~metrology.core.kernel_choice.use_compiled` says so, else this one."""
    if use_compiled(pixels):
        from metrology.core.geometry import pinhole_kernels

        return pinhole_kernels
    import sys

    return sys.modules[__name__]


def flat(a: np.ndarray, dtype: type[np.generic] = np.float32) -> np.ndarray:
    """``a`` as a contiguous one-dimensional array of ``dtype`` (a view when it already is one)."""
    return np.ascontiguousarray(a, dtype=dtype).reshape(-1)


def _table_at(
    w: np.ndarray, base: np.ndarray, frac: np.ndarray, planes: np.ndarray, g0: float, inv_h: float, n_cols: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(q, dq/dw)`` (float64 ``(n,)``) of the epipolar table at coded coordinates ``w`` (float64)
    of pixels whose row of cells starts at flat index ``base`` (integer) with weight ``frac``
    (float64) to the next row: ``g = (w - g0) / h`` clipped to the row, cell ``floor(g)``, ``tau =
    g - cell``, ``q = ((A_3 tau + c_2) tau + c_1) tau + A_0 + frac B_0``, ``c_m = A_m + frac B_m``
    (``c_2 = A_2`` with six planes), ``dq/dw = ((3 A_3 tau + 2 c_2) tau + c_1) / h``. NaN for NaN
    ``frac``; for NaN ``w`` the first cell of the row (the caller writes NaN there: the compiled
    :func:`~metrology.core.geometry.pinhole_kernels._table_at` returns it)."""
    g = w - g0
    g *= inv_h
    np.fmax(g, 0.0, out=g)  # NaN too goes to 0: a NaN index would read anywhere
    np.minimum(g, n_cols - 1e-3, out=g)
    idx = g.astype(np.intp)  # floor(g): g >= 0
    tau = g
    tau -= idx
    idx += base
    np.minimum(idx, planes.shape[1] - 1, out=idx)

    def plane(k: int) -> np.ndarray:
        return planes[k].take(idx).astype(np.float64)

    c1 = plane(5)
    c1 *= frac
    c1 += plane(1)
    c2 = plane(2)
    if planes.shape[0] == 7:
        b2 = plane(6)
        b2 *= frac
        c2 += b2
    a3 = plane(3)
    q = a3 * tau
    q += c2
    q *= tau
    q += c1
    q *= tau
    q += plane(0)
    b0 = plane(4)
    b0 *= frac
    q += b0
    dq = a3
    dq *= 3.0
    dq *= tau
    c2 *= 2.0
    dq += c2
    dq *= tau
    dq += c1
    dq *= inv_h
    return q, dq


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
) -> None:
    """``q_out``, ``dq_out`` (float32 ``(n,)``) = :func:`_table_at` of ``coded`` (``(n,)`` float32),
    ``base`` (int32), ``frac`` (float32), NaN where ``coded`` is NaN; ``dq_out`` written only with
    ``want_dq``."""
    q, dq = _table_at(coded.astype(np.float64), base, frac.astype(np.float64), planes, g0, inv_h, n_cols)
    _write_q(q, dq, np.isnan(coded), q_out, dq_out, want_dq)


def _write_q(
    q: np.ndarray, dq: np.ndarray, missing: np.ndarray, q_out: np.ndarray, dq_out: np.ndarray, want_dq: bool
) -> None:
    """``q`` and (with ``want_dq``) ``dq`` (float64 ``(n,)``) into the float32 outputs, NaN where ``missing``."""
    np.copyto(q_out, q, casting="same_kind")
    np.copyto(q_out, np.nan, where=missing)
    if want_dq:
        np.copyto(dq_out, dq, casting="same_kind")
        np.copyto(dq_out, np.nan, where=missing)


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
) -> None:
    """``q_out``, ``dq_out`` (float32 ``(n,)``): the undistorted normalized coordinate of the coded
    axis at the decoded ``coded``, ``other`` (``(n,)`` float32, projector units) and its
    derivative along the coded axis: ``x_lin = (u - cx - s y_lin) / fx`` (or ``y_lin = (v - cy) /
    fy``) plus :func:`_table_at` between the table's rows ``j`` and ``j + 1`` of ``g = (other -
    c_lo) / step_c`` (clamped to the table); ``dq/dw`` plus ``1 / fx`` (``1 / fy``). NaN for NaN
    input (the compiled :func:`~metrology.core.geometry.pinhole_kernels.grid_tile`)."""
    w = coded.astype(np.float64)
    o = other.astype(np.float64)
    g = o - c_lo
    g *= inv_step_c
    np.fmax(g, 0.0, out=g)  # NaN too goes to 0, written NaN below
    np.minimum(g, n_lines - 1.0, out=g)
    j = np.minimum(g.astype(np.intp), n_lines - 2)  # floor(g): g >= 0
    q, dq = _table_at(w, j * n_cols, g - j, planes, g0, inv_h, n_cols)
    missing = np.isnan(coded) | np.isnan(other)
    u, v = (w, o) if axis_u else (o, w)
    y_lin = (v - cy) / fy
    if axis_u:
        x_lin = u - cx
        x_lin -= skew * y_lin
        x_lin /= fx
        q += x_lin
    else:
        q += y_lin
    if want_dq:
        dq += 1.0 / fx if axis_u else 1.0 / fy
    _write_q(q, dq, missing, q_out, dq_out, want_dq)


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
) -> None:
    """``t_out`` (float32 ``(n,)``): the ray parameter of each pixel on the plane of ``q``, ``t =
    num / den`` with ``num = q T_z - T_i``, ``den = Rd_i - q Rd_z`` (NaN unless ``t > 0``); with
    ``want_sigma`` ``sigma_out = |dt/dq dq/dw| |d| sigma_in``, ``dt/dq = (T_z den + num Rd_z) /
    den^2`` (``dq`` read only then); with ``want_points`` the points ``t (x_n, y_n, 1)`` at
    ``points[3 i: 3 i + 3]``. All per-pixel arrays ``(n,)`` float32, ``points`` ``(3 n,)`` (the
    compiled :func:`~metrology.core.geometry.pinhole_kernels.plane_tile`)."""
    q64 = q.astype(np.float64)
    rdz64 = rdz.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        num = q64 * tz
        num -= ti
        den = rdi.astype(np.float64)
        den -= q64 * rdz64
        t = num / den
        behind = t > 0.0
        np.logical_not(behind, out=behind)  # t <= 0 or NaN
        np.copyto(t, np.nan, where=behind)
        np.copyto(t_out, t, casting="same_kind")
        if want_sigma:
            dt = tz * den
            num *= rdz64
            dt += num
            den *= den
            dt /= den
            dt *= dq
            np.abs(dt, out=dt)
            dt *= norm_d
            dt *= sigma_in
            sigma_out[...] = dt
    if want_points:
        xyz = points.reshape(-1, 3)
        np.multiply(t, xn, out=xyz[:, 0], casting="same_kind")
        np.multiply(t, yn, out=xyz[:, 1], casting="same_kind")
        xyz[:, 2] = t
