"""Compiled kernels of the stereo model's 2-D match (numba, ``nogil``: the tiles of
:func:`metrology.core.tiling.run_tiled` run them on the pool's threads in parallel), the equations of
:class:`metrology.core.geometry.stereo_match.PreparedStereo2D`:

- :func:`cell_buckets`: camera 1's cells of four decoded pixels indexed by the projector-space
  buckets their corners span;
- :func:`match_2d_tile`: each camera-0 pixel's decoded pair ``(u, v)`` found in the one cell of camera
  1 whose bilinear map holds it (:func:`invert_bilinear`), with the cell's slopes at the match;
- :func:`undistort_tile`: camera 1's matched pixels to undistorted normalized coordinates and the
  lens's Jacobian there (OpenCV's untilted model, Newton per point, as
  :func:`metrology.core.distortion.undistort_pixels`);
- :func:`midpoint_tile`: the rays' midpoint as the disparity ``d = k / t_m`` and, on request, its
  slopes ``dd/d(x_1, y_1)`` per camera-1 pixel;
- :func:`disparity_sigma_tile`: the disparity's sigma from each camera's and axis's decoder noise, and
  its covariance with camera 0's coordinate (the fusion's shared term).

Arithmetic float64 inside, float32 maps in and out. Compiled on first use and cached on disk
(``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from metrology.core.distortion import untilted_jacobian

_jacobian = njit(nogil=True, cache=True, inline="always")(untilted_jacobian)
"""The lens's Jacobian, :func:`metrology.core.distortion.untilted_jacobian` compiled (one formula)."""

CELL_BOX_MARGIN = 1e-6
"""Margin of the bounding-box test of :func:`match_2d_tile`, projector units: wider than the 1e-9 (of
the cell's span) by which :func:`invert_bilinear` accepts a solution outside its cell."""

NEWTON_STEPS = 8
"""Most Newton steps of :func:`invert_bilinear`."""
NEWTON_TOL = 1e-9
"""Newton's last step in :func:`invert_bilinear`, in units of the cell: once a step is smaller, the
iterate's error is of its square (quadratic convergence), far below float32's 6e-5 px of the match's
position near column 1000 (the output); later steps only move its last float64 bits."""


@njit(nogil=True, cache=True)
def cell_buckets(
    u: np.ndarray, v: np.ndarray, bucket: float, nu: int, nv: int
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Camera 1's cells (the squares of four decoded pixels ``(r, c)..(r + 1, c + 1)`` of the
    ``(h, w)`` float32 maps ``u``, ``v``) by the projector-space buckets (``bucket`` units square,
    ``nu`` x ``nv`` of them from 0) their bounding box overlaps: ``start`` ((nu nv + 1,) int64) and
    ``cells`` ((n, 2) int32, the row and column of each cell's top-left pixel, bucket after bucket;
    CSR layout: no division per cell in the match)."""
    h, w = u.shape
    counts = np.zeros(nu * nv + 1, np.int64)
    start = np.zeros(nu * nv + 1, np.int64)
    fill = np.zeros(nu * nv, np.int64)
    cells = np.empty((0, 2), np.int32)
    for phase in range(2):
        if phase == 1:
            for b in range(nu * nv):
                start[b + 1] = start[b] + counts[b]
            fill[:] = start[:-1]
            cells = np.empty((start[nu * nv], 2), np.int32)
        for r in range(h - 1):
            for c in range(w - 1):
                a0, a1, a2, a3 = u[r, c], u[r, c + 1], u[r + 1, c], u[r + 1, c + 1]
                b0, b1, b2, b3 = v[r, c], v[r, c + 1], v[r + 1, c], v[r + 1, c + 1]
                if math.isnan(a0 + a1 + a2 + a3 + b0 + b1 + b2 + b3):
                    continue
                i0 = max(0, math.floor(min(min(a0, a1), min(a2, a3)) / bucket))
                i1 = min(nu - 1, math.floor(max(max(a0, a1), max(a2, a3)) / bucket))
                j0 = max(0, math.floor(min(min(b0, b1), min(b2, b3)) / bucket))
                j1 = min(nv - 1, math.floor(max(max(b0, b1), max(b2, b3)) / bucket))
                for j in range(j0, j1 + 1):
                    for i in range(i0, i1 + 1):
                        k = j * nu + i
                        if phase == 0:
                            counts[k] += 1
                        else:
                            cells[fill[k], 0] = r
                            cells[fill[k], 1] = c
                            fill[k] += 1
    return start, cells


@njit(nogil=True, cache=True)
def invert_bilinear(
    u00: float,
    u10: float,
    u01: float,
    u11: float,
    v00: float,
    v10: float,
    v01: float,
    v11: float,
    qu: float,
    qv: float,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """``(s, t)`` with the cell's bilinear map ``P(s, t) = (1-s)(1-t) P00 + s(1-t) P10 + (1-s)t P01 +
    st P11 = (qu, qv)`` (Newton from the centre, at most :data:`NEWTON_STEPS` steps, the last one
    smaller than :data:`NEWTON_TOL`), NaN when the
    solution is outside ``[0, 1)^2`` (a tolerance of 1e-9 on the low sides) or the cell folds."""
    s = 0.5
    t = 0.5
    for _ in range(NEWTON_STEPS):
        fu = (1 - s) * (1 - t) * u00 + s * (1 - t) * u10 + (1 - s) * t * u01 + s * t * u11 - qu
        fv = (1 - s) * (1 - t) * v00 + s * (1 - t) * v10 + (1 - s) * t * v01 + s * t * v11 - qv
        us = (1 - t) * (u10 - u00) + t * (u11 - u01)
        ut = (1 - s) * (u01 - u00) + s * (u11 - u10)
        vs = (1 - t) * (v10 - v00) + t * (v11 - v01)
        vt = (1 - s) * (v01 - v00) + s * (v11 - v10)
        det = us * vt - ut * vs
        if det == 0 or math.isnan(det):
            return np.nan, np.nan
        inv = 1.0 / det
        ds = (fu * vt - ut * fv) * inv
        dt = (us * fv - fu * vs) * inv
        s -= ds
        t -= dt
        if abs(ds) + abs(dt) < NEWTON_TOL:
            break
    if s >= -1e-9 and s < 1.0 and t >= -1e-9 and t < 1.0:
        return s, t
    return np.nan, np.nan


@njit(nogil=True, cache=True)
def match_2d_tile(
    u0: np.ndarray,
    v0: np.ndarray,
    u1: np.ndarray,
    v1: np.ndarray,
    start: np.ndarray,
    cells: np.ndarray,
    bucket: float,
    nu: int,
    nv: int,
    cubic: bool,
    x1_out: np.ndarray,
    y1_out: np.ndarray,
    slopes_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """For each camera-0 pixel of decoded ``(u0, v0)`` ((n, W0) float32), camera 1's sub-pixel
    position ``(x1, y1)`` ((n, W0) float32 px) where its decoded maps ``u1``, ``v1`` take the same
    pair: the one cell of :func:`cell_buckets` whose bilinear map holds it (:func:`invert_bilinear`),
    ``x1 = c + s``, ``y1 = r + t``; NaN where no cell or more than one does (not unique). A cell whose
    corners' bounding box (widened by :data:`CELL_BOX_MARGIN`) does not hold the pair takes no Newton
    step (the bilinear map stays inside it). With ``cubic`` the position is then refined on the bicubic
    map of the 4 x 4 pixels around the cell (:func:`refine_cubic`: no pixel-locking bias where the
    maps bend). ``slopes_out`` ((n, W0, 5) float32) gets the map's slopes at the match
    (:func:`cell_slopes`, :func:`refine_cubic`; NaN where none)."""
    n, m = u0.shape
    for r in range(n):
        for c in range(m):
            x1_out[r, c] = np.nan
            y1_out[r, c] = np.nan
            for e in range(5):
                slopes_out[r, c, e] = np.nan
            qu = np.float64(u0[r, c])
            qv = np.float64(v0[r, c])
            if math.isnan(qu) or math.isnan(qv):
                continue
            i = math.floor(qu / bucket)
            j = math.floor(qv / bucket)
            if i < 0 or i >= nu or j < 0 or j >= nv:
                continue
            k = j * nu + i
            found = 0
            fr = -1
            fc = -1
            fs = np.nan
            ft = np.nan
            for e in range(start[k], start[k + 1]):
                rr = cells[e, 0]
                cc = cells[e, 1]
                a0, a1, a2, a3 = u1[rr, cc], u1[rr, cc + 1], u1[rr + 1, cc], u1[rr + 1, cc + 1]
                if (
                    qu < min(min(a0, a1), min(a2, a3)) - CELL_BOX_MARGIN
                    or qu > max(max(a0, a1), max(a2, a3)) + CELL_BOX_MARGIN
                ):
                    continue
                b0, b1, b2, b3 = v1[rr, cc], v1[rr, cc + 1], v1[rr + 1, cc], v1[rr + 1, cc + 1]
                if (
                    qv < min(min(b0, b1), min(b2, b3)) - CELL_BOX_MARGIN
                    or qv > max(max(b0, b1), max(b2, b3)) + CELL_BOX_MARGIN
                ):
                    continue
                s, t = invert_bilinear(
                    np.float64(a0),
                    np.float64(a1),
                    np.float64(a2),
                    np.float64(a3),
                    np.float64(b0),
                    np.float64(b1),
                    np.float64(b2),
                    np.float64(b3),
                    qu,
                    qv,
                )
                if not math.isnan(s):
                    found += 1
                    fr, fc, fs, ft = rr, cc, s, t
            if found == 1:
                if cubic:
                    fs, ft = refine_cubic(u1, v1, fr, fc, fs, ft, qu, qv, slopes_out[r, c])
                else:
                    cell_slopes(u1, v1, fr, fc, fs, ft, slopes_out[r, c])
                x1_out[r, c] = fc + fs
                y1_out[r, c] = fr + ft


@njit(nogil=True, cache=True)
def cell_slopes(
    u: np.ndarray, v: np.ndarray, r: int, c: int, s: float, t: float, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """The bilinear map (:func:`invert_bilinear`) of the cell whose top-left pixel is ``(r, c)`` at
    ``(s, t)``: its derivatives ``du/dx, du/dy, dv/dx, dv/dy`` (projector units per camera px; ``x``
    along the row) and the noise gain of its value, ``sqrt(sum w_i^2) = sqrt(((1-s)^2 + s^2) ((1-t)^2
    + t^2))`` (white noise of unit standard deviation on the four pixels), into ``out`` (5 float32)."""
    u00, u10 = np.float64(u[r, c]), np.float64(u[r, c + 1])
    u01, u11 = np.float64(u[r + 1, c]), np.float64(u[r + 1, c + 1])
    v00, v10 = np.float64(v[r, c]), np.float64(v[r, c + 1])
    v01, v11 = np.float64(v[r + 1, c]), np.float64(v[r + 1, c + 1])
    out[0] = (1 - t) * (u10 - u00) + t * (u11 - u01)
    out[1] = (1 - s) * (u01 - u00) + s * (u11 - u10)
    out[2] = (1 - t) * (v10 - v00) + t * (v11 - v01)
    out[3] = (1 - s) * (v01 - v00) + s * (v11 - v10)
    out[4] = math.sqrt(((1 - s) ** 2 + s * s) * ((1 - t) ** 2 + t * t))


UNDISTORT_STEPS = 8
"""Most Newton steps of :func:`undistort_tile` before a point is handed back as not converged."""


@njit(nogil=True, cache=True)
def undistort_tile(
    x: np.ndarray, y: np.ndarray, camera: np.ndarray, coeffs: np.ndarray, tol_px: float, out: np.ndarray
) -> int:  # pragma: no cover - compiled
    """Pixels ``(x, y)`` ((n, m) float32, pixel centres at integers) of a camera with ``camera`` =
    ``(fx, s, cx, fy, cy)`` and OpenCV's untilted distortion ``coeffs`` (``k1 k2 p1 p2 k3 k4 k5 k6 s1
    s2 s3 s4``, :mod:`metrology.core.distortion`) to undistorted normalized coordinates and the
    distortion's Jacobian there: ``out[..., 0:2] = (x_n, y_n)``, ``out[..., 2:6] = (dxd/dx, dxd/dy,
    dyd/dx, dyd/dy)`` ((n, m, 6) float64). Solves ``D(x_n, y_n) = K^-1 (x, y)`` by Newton's method
    with the analytic Jacobian (as ``distortion._fast_newton``), from ``x_d / g(r_d^2)``, until the
    pixel residual ``hypot(fx r_x + s r_y, fy r_y)`` is at most ``tol_px``. A NaN pixel gives NaN; a point
    not converged in :data:`UNDISTORT_STEPS` steps gives ``out[..., 0] = inf`` for the caller to
    solve by the damped Newton of :func:`~metrology.core.distortion.undistort_pixels`. Returns their
    count."""
    fx, sk, cx, fy, cy = camera[0], camera[1], camera[2], camera[3], camera[4]
    k1, k2, p1, p2, k3, k4, k5, k6 = (
        coeffs[0],
        coeffs[1],
        coeffs[2],
        coeffs[3],
        coeffs[4],
        coeffs[5],
        coeffs[6],
        coeffs[7],
    )
    s1, s2, s3, s4 = coeffs[8], coeffs[9], coeffs[10], coeffs[11]
    rational = k4 != 0.0 or k5 != 0.0 or k6 != 0.0
    tol2 = tol_px * tol_px
    failed = 0
    n, m = x.shape
    for r in range(n):
        for c in range(m):
            px = np.float64(x[r, c])
            py = np.float64(y[r, c])
            if math.isnan(px) or math.isnan(py):
                for e in range(6):
                    out[r, c, e] = np.nan
                continue
            ty = (py - cy) / fy
            tx = (px - cx - sk * ty) / fx
            bx, by = tx, ty
            if not rational:
                r2 = bx * bx + by * by
                g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                bx /= g
                by /= g
            converged = False
            jxx = jxy = jyx = jyy = np.nan
            for _ in range(UNDISTORT_STEPS + 1):
                x2, y2, xy = bx * bx, by * by, bx * by
                r2 = x2 + y2
                g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                dg = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
                if rational:
                    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
                    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
                    dg = (dg * den - g * dden) / (den * den)
                    g /= den
                jxx, jxy, jyx, jyy = _jacobian(bx, by, r2, g, dg, p1, p2, s1, s2, s3, s4)
                rx = bx * g + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) + r2 * (s1 + s2 * r2) - tx
                ry = by * g + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy + r2 * (s3 + s4 * r2) - ty
                ex = fx * rx + sk * ry
                ey = fy * ry
                if ex * ex + ey * ey <= tol2:
                    converged = True
                    break
                det = jxx * jyy - jxy * jyx
                bx -= (jyy * rx - jxy * ry) / det
                by -= (jxx * ry - jyx * rx) / det
            if not converged:
                failed += 1
                out[r, c, 0] = np.inf
                continue
            out[r, c, 0] = bx
            out[r, c, 1] = by
            out[r, c, 2] = jxx
            out[r, c, 3] = jxy
            out[r, c, 4] = jyx
            out[r, c, 5] = jyy
    return failed


@njit(nogil=True, cache=True)
def midpoint_depth(
    xn1: float, yn1: float, ax: float, ay: float, geometry: np.ndarray
) -> float:  # pragma: no cover - compiled
    """``t_m``, camera 0's depth of the rays' midpoint (mm): camera 0's ray ``t (ax, ay, 1)`` and camera
    1's ``C + s b``, ``b = R^T (x_1n, y_1n, 1)``, ``geometry`` = ``(R row-major (9), C (3), ...)``; the
    closest points' parameters ``t = ((a.C)(b.b) - (a.b)(b.C)) / D``, ``s = ((a.b)(a.C) - (a.a)(b.C)) /
    D``, ``D = (a.a)(b.b) - (a.b)^2``, their midpoint's foot on camera 0's ray (NaN unless positive)."""
    c0, c1, c2 = geometry[9], geometry[10], geometry[11]
    bx = geometry[0] * xn1 + geometry[3] * yn1 + geometry[6]
    by = geometry[1] * xn1 + geometry[4] * yn1 + geometry[7]
    bz = geometry[2] * xn1 + geometry[5] * yn1 + geometry[8]
    aa = ax * ax + ay * ay + 1.0
    bb = bx * bx + by * by + bz * bz
    ab = ax * bx + ay * by + bz
    ac = ax * c0 + ay * c1 + c2
    bc = bx * c0 + by * c1 + bz * c2
    det = aa * bb - ab * ab
    t = (ac * bb - ab * bc) / det
    s = (ab * ac - aa * bc) / det
    mx = (t * ax + c0 + s * bx) / 2
    my = (t * ay + c1 + s * by) / 2
    mz = (t + c2 + s * bz) / 2
    tm = (mx * ax + my * ay + mz) / aa
    return tm if tm > 0 else np.nan


@njit(nogil=True, cache=True)
def midpoint_tile(
    und: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    k: np.ndarray,
    geometry: np.ndarray,
    step: float,
    d_out: np.ndarray,
    slopes_out: np.ndarray,
    with_slopes: bool,
) -> None:  # pragma: no cover - compiled
    """The disparity ``d = k / t_m`` (:func:`midpoint_depth`; ``d_out`` (n, m) float64) of camera 1's
    matched rays ``und`` ((n, m, 6) float64 of :func:`undistort_tile`) and camera 0's ``(xn, yn)`` and
    ``k`` ((n, m)); with ``with_slopes`` also ``g = dd/d(x_1, y_1)`` per camera-1 pixel into
    ``slopes_out`` ((n, m, 2) float64): ``g = (dd/dx_1n, dd/dy_1n) . (K' J_dist)^-1``, the first factor
    by forward differences of ``step`` (normalized), ``J_dist`` the lens's Jacobian (``und[..., 2:6]``),
    ``K'`` the upper 2x2 of camera 1's ``K`` (``geometry[12:15]`` = ``fx, s, fy``)."""
    n, m = d_out.shape
    fx, sk, fy = geometry[12], geometry[13], geometry[14]
    for r in range(n):
        for c in range(m):
            x1, y1 = und[r, c, 0], und[r, c, 1]
            ax, ay = np.float64(xn[r, c]), np.float64(yn[r, c])
            kk = np.float64(k[r, c])
            tm = midpoint_depth(x1, y1, ax, ay, geometry)
            d = kk / tm
            d_out[r, c] = d
            if not with_slopes:
                continue
            hx = (kk / midpoint_depth(x1 + step, y1, ax, ay, geometry) - d) / step
            hy = (kk / midpoint_depth(x1, y1 + step, ax, ay, geometry) - d) / step
            a, b, cc, e = und[r, c, 2], und[r, c, 3], und[r, c, 4], und[r, c, 5]
            p00, p01 = fx * a + sk * cc, fx * b + sk * e  # d(pixel)/d(x_1n, y_1n)
            p10, p11 = fy * cc, fy * e
            det = p00 * p11 - p01 * p10
            slopes_out[r, c, 0] = (hx * p11 - hy * p10) / det
            slopes_out[r, c, 1] = (hy * p00 - hx * p01) / det


@njit(nogil=True, cache=True, inline="always")
def _cubic_weights(s: float) -> tuple[float, float, float, float, float, float, float, float]:  # pragma: no cover
    """Lagrange weights of the cubic through the nodes ``-1, 0, 1, 2`` at ``s`` and their derivatives
    (8 floats: ``L_-1, L_0, L_1, L_2, L'_-1, L'_0, L'_1, L'_2``)."""
    a, b, c, d = s + 1.0, s, s - 1.0, s - 2.0
    sixth = 1.0 / 6.0  # constants: a multiplication, not a division, per weight
    return (
        -b * c * d * sixth,
        a * c * d * 0.5,
        -a * b * d * 0.5,
        a * b * c * sixth,
        -(c * d + b * d + b * c) * sixth,
        (c * d + a * d + a * c) * 0.5,
        -(b * d + a * d + a * b) * 0.5,
        (b * c + a * c + a * b) * sixth,
    )


@njit(nogil=True, cache=True, inline="always")
def _row4(row: np.ndarray, c: int, w0: float, w1: float, w2: float, w3: float) -> float:  # pragma: no cover
    """``w0 row[c - 1] + w1 row[c] + w2 row[c + 1] + w3 row[c + 2]`` in float64."""
    return (
        w0 * np.float64(row[c - 1])
        + w1 * np.float64(row[c])
        + w2 * np.float64(row[c + 1])
        + w3 * np.float64(row[c + 2])
    )


CUBIC_STEPS = 4
"""Most Newton steps of :func:`refine_cubic` from the bilinear solution (one, mostly: the bicubic term
moves the solution by about ``s (1 - s) u'' / (2 u')``, a small fraction of a pixel)."""
CUBIC_TOL = 1e-3
"""The last Newton step of :func:`refine_cubic`, camera px (``|ds| + |dt|``): Newton leaves an error of
about ``kappa step^2``, ``kappa = |P''| / |P'|`` the maps' relative curvature (below 0.1 / px where a
rig measures), so at most 1e-7 px after a step of 1e-3: far below float32's 6e-5 px of the output near
column 1000. The slopes and the noise gain are those of the point before that step (relative error
below 1e-3)."""
CUBIC_REACH = 0.5
"""Largest move of :func:`refine_cubic` from the bilinear solution, camera px per axis (the bicubic
term is a small fraction of a pixel; a larger move falls back to the bilinear solution)."""


@njit(nogil=True, cache=True)
def refine_cubic(
    u: np.ndarray,
    v: np.ndarray,
    r: int,
    c: int,
    s: float,
    t: float,
    qu: float,
    qv: float,
    out: np.ndarray,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """The position ``(s, t)`` in the cell of top-left pixel ``(r, c)`` where the bicubic maps of ``u``
    and ``v`` take ``(qu, qv)``: ``P(s, t) = sum_ij L_i(s) L_j(t) P[r + j, c + i]``, ``i, j`` in ``-1..2``,
    ``L`` the Lagrange cubics through the nodes ``-1, 0, 1, 2`` (exact for a cubic map, error O(h^4);
    the bilinear map's is O(h^2): ``s (1 - s) P_xx / 2``), by Newton from the bilinear solution
    ``(s, t)`` (:data:`CUBIC_STEPS`, :data:`CUBIC_TOL`). ``out`` (5 float32) gets the bicubic map's
    ``du/dx, du/dy, dv/dx, dv/dy`` there and the noise gain of its value, ``sqrt(sum_i L_i(s)^2 sum_j
    L_j(t)^2)`` (white noise of unit standard deviation on the 16 pixels). Where a pixel of the 4 x 4
    is not decoded (or outside the image), or Newton does not settle within :data:`CUBIC_REACH`, the
    bilinear solution and its slopes (:func:`cell_slopes`)."""
    h, w = u.shape
    if r < 1 or c < 1 or r + 2 >= h or c + 2 >= w:
        cell_slopes(u, v, r, c, s, t, out)
        return s, t
    s1, t1 = s, t
    for _ in range(CUBIC_STEPS):
        x0, x1, x2, x3, dx0, dx1, dx2, dx3 = _cubic_weights(s1)
        y0, y1, y2, y3, dy0, dy1, dy2, dy3 = _cubic_weights(t1)
        fu = fv = us = ut = vs = vt = 0.0
        for j in range(4):  # along the rows first (separable)
            wy = y0 if j == 0 else (y1 if j == 1 else (y2 if j == 2 else y3))
            dwy = dy0 if j == 0 else (dy1 if j == 1 else (dy2 if j == 2 else dy3))
            ur, vr = u[r - 1 + j], v[r - 1 + j]
            ru = _row4(ur, c, x0, x1, x2, x3)
            rv = _row4(vr, c, x0, x1, x2, x3)
            su = _row4(ur, c, dx0, dx1, dx2, dx3)
            sv = _row4(vr, c, dx0, dx1, dx2, dx3)
            fu += wy * ru
            fv += wy * rv
            ut += dwy * ru
            vt += dwy * rv
            us += wy * su
            vs += wy * sv
        det = us * vt - ut * vs
        if det == 0 or math.isnan(det + fu + fv):  # an undecoded pixel of the 16 makes all NaN
            break
        fu -= qu
        fv -= qv
        inv = 1.0 / det
        ds = (fu * vt - ut * fv) * inv
        dt = (us * fv - fu * vs) * inv
        s1 -= ds
        t1 -= dt
        if abs(ds) + abs(dt) < CUBIC_TOL:
            if abs(s1 - s) > CUBIC_REACH or abs(t1 - t) > CUBIC_REACH:
                break
            out[0] = us
            out[1] = ut
            out[2] = vs
            out[3] = vt
            out[4] = math.sqrt((x0 * x0 + x1 * x1 + x2 * x2 + x3 * x3) * (y0 * y0 + y1 * y1 + y2 * y2 + y3 * y3))
            return s1, t1
    cell_slopes(u, v, r, c, s, t, out)
    return s, t


@njit(nogil=True, cache=True)
def disparity_sigma_tile(
    slopes: np.ndarray,
    g: np.ndarray,
    x1: np.ndarray,
    y1: np.ndarray,
    s0: np.ndarray,
    o0: np.ndarray,
    s1: np.ndarray,
    o1: np.ndarray,
    with_noise: bool,
    axis_u: bool,
    sigma_out: np.ndarray,
    shared_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The 2-D match's disparity sigma (``PreparedStereo2D``'s docstring) for a tile of ``(n, m)``
    camera-0 pixels: ``G = g J^-1`` from the map's slopes at the match (``slopes``, (n, m, 5) float32 of
    :func:`match_2d_tile`: ``J`` and the noise gain ``g_1``) and the midpoint's (``g``, (n, m, 2) float64
    of :func:`midpoint_tile`), then ``sigma_d^2 = G_u^2 (s_0u^2 + g_1^2 s_1u^2) + G_v^2 (s_0v^2 + g_1^2
    s_1v^2)`` into ``sigma_out`` and ``G`` of the matched axis (``axis_u``: ``u``) into ``shared_out``
    ((n, m) float32 each). ``s0``, ``o0``: camera 0's sigma of the matched and the other axis (n, m);
    ``s1``, ``o1``: camera 1's whole maps, read at the match's nearest pixel ``(x1, y1)``; all 1 without
    ``with_noise`` (then 1 x 1 arrays)."""
    n, m = sigma_out.shape
    h1, w1 = s1.shape
    for r in range(n):
        for c in range(m):
            ux, uy = np.float64(slopes[r, c, 0]), np.float64(slopes[r, c, 1])
            vx, vy = np.float64(slopes[r, c, 2]), np.float64(slopes[r, c, 3])
            gain = np.float64(slopes[r, c, 4])
            gx, gy = g[r, c, 0], g[r, c, 1]
            det = ux * vy - uy * vx
            gu = (gx * vy - gy * vx) / det
            gv = (gy * ux - gx * uy) / det
            a0 = a1 = b0 = b1 = 1.0
            if with_noise:
                x, y = x1[r, c], y1[r, c]
                j = min(max(round(x), 0), w1 - 1) if not math.isnan(x) else 0
                i = min(max(round(y), 0), h1 - 1) if not math.isnan(y) else 0
                a0, b0 = np.float64(s0[r, c]), np.float64(o0[r, c])
                a1, b1 = np.float64(s1[i, j]), np.float64(o1[i, j])
            su0, su1, sv0, sv1 = (a0, a1, b0, b1) if axis_u else (b0, b1, a0, a1)
            var = gu * gu * (su0 * su0 + (gain * su1) ** 2) + gv * gv * (sv0 * sv0 + (gain * sv1) ** 2)
            sigma_out[r, c] = math.sqrt(var)
            shared_out[r, c] = gu if axis_u else gv
