"""OpenCV's lens distortion model, forward and inverse (iterated to convergence).

Normalized coordinates ``(x, y) = (X / Z, Y / Z)`` of a point in a device's frame are
distorted by the model of ``cv2.projectPoints`` with 4, 5, 8, 12 or 14 coefficients
``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]`` (missing ones are zero)::

    r2 = x^2 + y^2
    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    x' = x radial + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2
    y' = y radial + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2
    (xd, yd) = (w0 / w2, w1 / w2),  w = M(tx, ty) (x', y', 1)^T      (tilted sensor)

and the pixel is ``u = fx xd + s yd + cx``, ``v = fy yd + cy`` with ``K = [[fx, s, cx],
[0, fy, cy], [0, 0, 1]]`` (pixel centres at integer coordinates, as in OpenCV).

The inverse (pixel to undistorted normalized coordinates) is solved by Newton's method with
the analytic Jacobian, with step halving when a step does not reduce the residual, until the
reprojection residual is below a tolerance in pixels (default 1e-6 px) or an iteration cap is
reached; points that do not converge are reported (and set to NaN), unlike OpenCV's
``cv2.undistortPoints`` whose default five fixed-point iterations are not enough for strong
distortion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

DIST_COUNTS: tuple[int, ...] = (4, 5, 8, 12, 14)
"""Numbers of coefficients OpenCV's distortion model accepts."""

UNDISTORT_TOL_PX = 1e-6
"""Default convergence tolerance of the inverse: reprojection residual in pixels."""

UNDISTORT_MAX_ITER = 50
"""Default iteration cap of the inverse."""


def check_dist(dist: npt.ArrayLike | None, name: str = "dist") -> FloatArray:
    """Validate distortion coefficients; return them as a ``(14,)`` float64 array (zeros padded).

    ``None`` or an empty sequence means no distortion.

    Raises
    ------
    ValueError
        If the count is not 0, 4, 5, 8, 12 or 14 or a value is not finite (naming ``name``).
    """
    if dist is None:
        return np.zeros(14)
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size == 0:
        return np.zeros(14)
    if d.size not in DIST_COUNTS:
        raise ValueError(f"{name} must hold 4, 5, 8, 12 or 14 coefficients (or none), got {d.size}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name} must hold finite numbers, got {d.tolist()}")
    out = np.zeros(14)
    out[: d.size] = d
    return out


def tilt_matrix(tau_x: float, tau_y: float) -> FloatArray:
    """OpenCV's ``computeTiltProjectionMatrix``: ``(3, 3)`` float64 matrix of the tilted sensor."""
    cx, sx, cy, sy = math.cos(tau_x), math.sin(tau_x), math.cos(tau_y), math.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array([[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]], [0.0, 0.0, 1.0]])
    return np.asarray(proj_z @ rot_xy)


@dataclass(frozen=True)
class Distortion:
    """One device's distortion coefficients, validated (see the module docstring).

    Parameters
    ----------
    coeffs : (14,) float64 array
        ``k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tx ty``, zeros where absent.
    """

    coeffs: FloatArray

    @classmethod
    def from_coeffs(cls, dist: npt.ArrayLike | None, name: str = "dist") -> Distortion:
        """From 0, 4, 5, 8, 12 or 14 OpenCV coefficients (``ValueError`` naming ``name`` otherwise)."""
        return cls(check_dist(dist, name))

    @property
    def is_identity(self) -> bool:
        """True when every coefficient is zero (no distortion)."""
        return not np.any(self.coeffs)

    @property
    def _tilted(self) -> bool:
        return bool(self.coeffs[12] != 0.0 or self.coeffs[13] != 0.0)

    def distort(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Distort normalized coordinates: arrays of any (common) shape, float64 out."""
        xd, yd, _ = self._evaluate(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), False)
        return xd, yd

    def distort_with_jacobian(
        self, x: npt.ArrayLike, y: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray, tuple[FloatArray, FloatArray, FloatArray, FloatArray]]:
        """Distort and return the Jacobian ``(dxd/dx, dxd/dy, dyd/dx, dyd/dy)`` too."""
        xd, yd, jac = self._evaluate(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), True)
        assert jac is not None
        return xd, yd, jac

    def _evaluate(
        self, x: FloatArray, y: FloatArray, with_jacobian: bool
    ) -> tuple[FloatArray, FloatArray, tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None]:
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = (float(c) for c in self.coeffs)
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        rational = k4 != 0.0 or k5 != 0.0 or k6 != 0.0
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)) if rational else None
        radial = num / den if den is not None else num
        xp = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) + r2 * (s1 + s2 * r2)
        yp = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy + r2 * (s3 + s4 * r2)
        jac = None
        if with_jacobian:
            dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            if den is not None:
                dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
                drad = (dnum * den - num * dden) / (den * den)
            else:
                drad = dnum
            jac = untilted_jacobian(x, y, r2, radial, drad, p1, p2, s1, s2, s3, s4)
        if not self._tilted:
            return xp, yp, jac
        m = tilt_matrix(tx, ty)
        w0 = m[0, 0] * xp + m[0, 1] * yp + m[0, 2]
        w1 = m[1, 0] * xp + m[1, 1] * yp + m[1, 2]
        w2 = m[2, 0] * xp + m[2, 1] * yp + m[2, 2]
        xd, yd = w0 / w2, w1 / w2
        if jac is not None:
            # d(w0/w2)/dx' = (m00 - xd m20) / w2, etc.; chain rule with the Jacobian above.
            a00 = (m[0, 0] - xd * m[2, 0]) / w2
            a01 = (m[0, 1] - xd * m[2, 1]) / w2
            a10 = (m[1, 0] - yd * m[2, 0]) / w2
            a11 = (m[1, 1] - yd * m[2, 1]) / w2
            jxx, jxy, jyx, jyy = jac
            jac = (a00 * jxx + a01 * jyx, a00 * jxy + a01 * jyy, a10 * jxx + a11 * jyx, a10 * jxy + a11 * jyy)
        return xd, yd, jac


def untilted_jacobian(
    x: Any, y: Any, r2: Any, radial: Any, drad: Any, p1: float, p2: float, s1: float, s2: float, s3: float, s4: float
) -> tuple[Any, Any, Any, Any]:
    """The untilted model's Jacobian ``(dx'/dx, dx'/dy, dy'/dx, dy'/dy)`` at ``(x, y)`` (``r2 = x^2 +
    y^2``, ``radial`` the radial factor and ``drad`` its derivative in ``r2``): floats or arrays alike,
    so that the compiled 2-D stereo match (:mod:`metrology.core.geometry.match_2d_kernels`) compiles
    this very function."""
    sx = 2.0 * (s1 + 2.0 * s2 * r2)
    sy = 2.0 * (s3 + 2.0 * s4 * r2)
    x2, y2, xy = x * x, y * y, x * y
    jxx = radial + 2.0 * x2 * drad + 2.0 * p1 * y + 6.0 * p2 * x + sx * x
    jxy = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y + sx * y
    jyx = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y + sy * x
    jyy = radial + 2.0 * y2 * drad + 6.0 * p1 * y + 2.0 * p2 * x + sy * y
    return jxx, jxy, jyx, jyy


def _check_K(K: npt.ArrayLike, name: str = "K") -> FloatArray:
    k = np.asarray(K, dtype=np.float64)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise ValueError(f"{name} must be a finite 3x3 matrix, got shape {k.shape}")
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ValueError(f"{name} must have fx > 0 and fy > 0, got fx={k[0, 0]!r}, fy={k[1, 1]!r}")
    if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1:
        raise ValueError(f"{name} must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}")
    return k


def project_normalized(
    K: npt.ArrayLike, dist: Distortion, x: npt.ArrayLike, y: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Pixel coordinates ``(u, v)`` (float64, any shape) of normalized coordinates ``(x, y)``."""
    k = _check_K(K)
    xd, yd = dist.distort(x, y)
    return k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]


@dataclass(frozen=True)
class Undistorted:
    """Result of :func:`undistort_pixels`.

    Attributes
    ----------
    x, y : float64 arrays, the input's shape
        Undistorted normalized coordinates; NaN where not converged (or the input was NaN).
    converged : bool array, the input's shape
        Where the reprojection residual fell below the tolerance.
    failed : bool array, the input's shape
        Finite input points that did not converge (NaN inputs are neither).
    iterations : int
        Newton iterations run (the cap when some point did not converge).
    """

    x: FloatArray
    y: FloatArray
    converged: npt.NDArray[np.bool_]
    failed: npt.NDArray[np.bool_]
    iterations: int

    @property
    def n_failed(self) -> int:
        """Number of finite input points that did not converge."""
        return int(np.count_nonzero(self.failed))


def undistort_pixels(
    K: npt.ArrayLike,
    dist: Distortion,
    u: npt.ArrayLike,
    v: npt.ArrayLike,
    tol_px: float = UNDISTORT_TOL_PX,
    max_iter: int = UNDISTORT_MAX_ITER,
    start: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> Undistorted:
    """Invert :func:`project_normalized`: pixels to undistorted normalized coordinates.

    Solves ``K D(x, y) = (u, v)`` by Newton's method with the analytic Jacobian of ``D``,
    starting from ``start`` if given, else from ``K^-1 (u, v)``, and halving a step while it
    does not reduce the residual (at most 8 times). A point has converged when its reprojection residual
    ``hypot(fx rx + s ry, fy ry)`` is at most ``tol_px`` pixels.

    Parameters
    ----------
    K : (3, 3) array_like
    dist : Distortion
    u, v : array_like, any (common) shape
        Pixel coordinates (pixel centres at integers); NaN allowed (stays NaN, not "failed").
    tol_px : float
        Convergence tolerance, pixels (> 0).
    max_iter : int
        Iteration cap (>= 1).
    start : (x0, y0), optional
        Undistorted normalized coordinates to start from (the shape of ``u``), e.g. interpolated
        from a coarse grid of solutions: one Newton step where they are close. The result meets
        ``tol_px`` whatever the start (points whose iteration from it does not converge restart
        from ``K^-1 (u, v)``; untilted models), but a start far from the solution may reach
        another preimage where the model folds over: give a close one.

    Returns
    -------
    Undistorted
        Points that do not converge are NaN with ``converged`` False.
    """
    if not (tol_px > 0):
        raise ValueError(f"tol_px must be > 0, got {tol_px!r}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter!r}")
    k = _check_K(K)
    u_arr, v_arr = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    fx, s, cx, fy, cy = k[0, 0], k[0, 1], k[0, 2], k[1, 1], k[1, 2]
    # Target in distorted normalized coordinates; residuals scale back to pixels.
    yd_t = (v_arr - cy) / fy
    xd_t = (u_arr - cx - s * yd_t) / fx
    finite = np.isfinite(xd_t) & np.isfinite(yd_t)
    if start is None:
        x, y = xd_t.copy(), yd_t.copy()
    else:
        x = np.array(np.broadcast_to(np.asarray(start[0], dtype=np.float64), u_arr.shape))
        y = np.array(np.broadcast_to(np.asarray(start[1], dtype=np.float64), u_arr.shape))
        x[~finite], y[~finite] = np.nan, np.nan
    if dist.is_identity:
        x, y = xd_t, yd_t
        return Undistorted(x=x, y=y, converged=finite, failed=np.zeros_like(finite), iterations=0)
    with np.errstate(all="ignore"):  # diverging points overflow; they are reported, not warned about
        if not dist._tilted:
            ok = np.zeros(x.shape, bool)
            iterations = _fast_newton(
                dist, fx, s, fy, x, y, xd_t, yd_t, tol_px, min(max_iter, FAST_MAX_ITER), ok, start is not None
            )
            slow = finite & ~ok
            if not slow.any():
                return Undistorted(x=x, y=y, converged=finite, failed=np.zeros_like(finite), iterations=iterations)
            # the few points the plain iteration does not bring home restart on the damped Newton
            x[slow], y[slow] = xd_t[slow], yd_t[slow]
            rest = _newton(dist, fx, s, fy, x[slow], y[slow], xd_t[slow], yd_t[slow], finite[slow], tol_px, max_iter)
            x[slow], y[slow] = rest.x, rest.y
            conv = finite & ~slow
            conv[slow] = rest.converged
            return Undistorted(
                x=x, y=y, converged=conv, failed=finite & ~conv, iterations=max(iterations, rest.iterations)
            )
        return _newton(dist, fx, s, fy, x, y, xd_t, yd_t, finite, tol_px, max_iter)


FAST_MAX_ITER = 8
"""Iterations of the undamped kernel (:func:`_fast_newton`) before the damped one takes over."""

FAST_TILE = 1 << 13
"""Points per block of the undamped kernel: its ~12 float64 temporaries stay in the L2 cache."""


def _fast_newton(
    dist: Distortion,
    fx: float,
    s: float,
    fy: float,
    x: FloatArray,
    y: FloatArray,
    xd_t: FloatArray,
    yd_t: FloatArray,
    tol_px: float,
    max_iter: int,
    ok: npt.NDArray[np.bool_],
    started: bool = False,
) -> int:
    """Undamped Newton steps on ``D(x, y) = (xd_t, yd_t)`` in place (from ``x, y``: with
    ``started`` as given, else ``x_d / g(r_d^2)`` where the model is not rational), block by block of
    :data:`FAST_TILE` points, until every residual ``hypot(fx rx + s ry, fy ry)`` of a block is
    at most ``tol_px`` (checked before each step) or ``max_iter`` steps. Untilted models only
    (terms with zero coefficients skipped); the caller verifies the result and sends the points
    that did not converge (or are not finite) to :func:`_newton`. ``ok`` (the shape of ``x``)
    is set where the residual at the returned point is at most ``tol_px``. Returns the most
    steps taken.

    Per step, with ``r2 = x^2 + y^2``, ``g = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + ...)``
    and ``g' = dg/d(r2)``: ``J = g I + 2 g' (x, y)^T (x, y) + (tangential and prism terms)``,
    ``(x, y) -= J^-1 (D(x, y) - (xd_t, yd_t))``.
    """
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, _, _ = (float(c) for c in dist.coeffs)
    rational = k4 != 0.0 or k5 != 0.0 or k6 != 0.0
    prism = s1 != 0.0 or s2 != 0.0 or s3 != 0.0 or s4 != 0.0
    tol_x = tol_px * tol_px
    fx2, s2x, fy2 = fx * fx, 2.0 * fx * s, s * s + fy * fy
    most = 0
    xf, yf, txf, tyf, okf = x.reshape(-1), y.reshape(-1), xd_t.reshape(-1), yd_t.reshape(-1), ok.reshape(-1)
    for start in range(0, xf.size, FAST_TILE):
        blk = slice(start, start + FAST_TILE)
        bx, by, tx, ty = xf[blk].copy(), yf[blk].copy(), txf[blk], tyf[blk]
        if not rational and not started:  # start from x_d / g(r_d^2): one Newton step fewer for most blocks
            r2 = bx * bx + by * by
            g = r2 * k3
            g += k2
            g *= r2
            g += k1
            g *= r2
            g += 1.0
            bx /= g
            by /= g
        for it in range(max_iter + 1):
            x2, y2, xy = bx * bx, by * by, bx * by
            r2 = x2 + y2
            g = r2 * k3
            g += k2
            g *= r2
            g += k1
            dg = r2 * (3.0 * k3)
            dg += 2.0 * k2
            dg *= r2
            dg += k1
            g *= r2
            g += 1.0
            if rational:
                den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
                dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
                dg = (dg * den - g * dden) / (den * den)
                g /= den
            # residual rx = x g + 2 p1 x y + p2 (r2 + 2 x^2) [+ prism] - tx, ry likewise
            rx = bx * g
            rx += (2.0 * p1) * xy
            rx += p2 * (r2 + 2.0 * x2)
            rx -= tx
            ry = by * g
            ry += (2.0 * p2) * xy
            ry += p1 * (r2 + 2.0 * y2)
            ry -= ty
            if prism:
                rx += r2 * (s1 + s2 * r2)
                ry += r2 * (s3 + s4 * r2)
            # squared pixel residual (fx rx + s ry)^2 + (fy ry)^2
            e2 = rx * rx
            e2 *= fx2
            e2 += (s2x * rx + fy2 * ry) * ry
            converged = e2 <= tol_x
            if it == max_iter or converged.all():
                okf[blk] = converged
                break
            most = max(most, it + 1)
            dg *= 2.0
            jxy = dg * xy
            jxx = dg * x2
            jxx += g
            jyy = dg * y2
            jyy += g
            t = (2.0 * p1) * bx
            t += (2.0 * p2) * by
            jxy += t
            jyx = jxy.copy()
            jxx += (2.0 * p1) * by + (6.0 * p2) * bx
            jyy += (6.0 * p1) * by + (2.0 * p2) * bx
            if prism:
                sx, sy = 2.0 * (s1 + 2.0 * s2 * r2), 2.0 * (s3 + 2.0 * s4 * r2)
                jxx += sx * bx
                jxy += sx * by
                jyx += sy * bx
                jyy += sy * by
            det = jxx * jyy
            det -= jxy * jyx
            # (dx, dy) = J^-1 (rx, ry)
            dx = jyy * rx
            dx -= jxy * ry
            dx /= det
            dy = jxx * ry
            dy -= jyx * rx
            dy /= det
            bx -= dx
            by -= dy
        xf[blk], yf[blk] = bx, by
    return most


def _newton(
    dist: Distortion,
    fx: float,
    s: float,
    fy: float,
    x: FloatArray,
    y: FloatArray,
    xd_t: FloatArray,
    yd_t: FloatArray,
    finite: npt.NDArray[np.bool_],
    tol_px: float,
    max_iter: int,
) -> Undistorted:
    def residual_px(xd: FloatArray, yd: FloatArray, xt: FloatArray, yt: FloatArray) -> FloatArray:
        rx, ry = xd - xt, yd - yt
        return np.asarray(np.hypot(fx * rx + s * ry, fy * ry))

    flat_x, flat_y = x.ravel(), y.ravel()
    txf, tyf = xd_t.ravel(), yd_t.ravel()
    active = np.flatnonzero(finite.ravel())
    converged = np.zeros(flat_x.shape, dtype=bool)
    iterations = 0
    xd, yd = dist.distort(flat_x[active], flat_y[active])
    err = residual_px(xd, yd, txf[active], tyf[active])
    for iterations in range(1, max_iter + 1):
        done = err <= tol_px
        converged[active[done]] = True
        keep = ~done
        active, err = active[keep], err[keep]
        if active.size == 0:
            iterations -= 1
            break
        xa, ya, xt, yt = flat_x[active], flat_y[active], txf[active], tyf[active]
        xd, yd, (jxx, jxy, jyx, jyy) = dist.distort_with_jacobian(xa, ya)
        rx, ry = xd - xt, yd - yt
        det = jxx * jyy - jxy * jyx
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (jyy * rx - jxy * ry) / det
        dy = (jxx * ry - jyx * rx) / det
        step = np.ones_like(xa)
        new_x, new_y = xa - dx, ya - dy
        nxd, nyd = dist.distort(new_x, new_y)
        new_err = residual_px(nxd, nyd, xt, yt)
        for _ in range(8):
            worse = ~(new_err < err)
            if not np.any(worse):
                break
            step[worse] *= 0.5
            new_x[worse] = xa[worse] - step[worse] * dx[worse]
            new_y[worse] = ya[worse] - step[worse] * dy[worse]
            wxd, wyd = dist.distort(new_x[worse], new_y[worse])
            new_err[worse] = residual_px(wxd, wyd, xt[worse], yt[worse])
        flat_x[active], flat_y[active] = new_x, new_y
        err = np.where(np.isfinite(new_err), new_err, np.inf)
    else:
        done = err <= tol_px
        converged[active[done]] = True
    conv = converged.reshape(x.shape)
    x[~conv] = np.nan
    y[~conv] = np.nan
    return Undistorted(x=x, y=y, converged=conv, failed=finite & ~conv, iterations=iterations)
