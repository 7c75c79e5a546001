"""The projector's undistortion sampled on a grid, for bicubic look-ups (pinhole rigs whose
projector is distorted and whose codec codes both projector axes).

``(x_p, y_p) = K^-1 (u, v) + (dx, dy)(u, v)``: the corrections are solved exactly (Newton, 1e-9
projector units) on a grid of spacing :data:`GRID_STEPS`, with their exact first derivatives (the
inverse of the distortion's Jacobian) and their cross derivative (central differences of those),
and interpolated by bicubic Hermite patches: in a cell, with ``a, b`` the position along ``u``
and ``v`` (0..1)::

    dx(a, b) = sum_ij C_ij a^i b^j,   C = H G H^T,
    G = [[f00, f01, fb00, fb01], [f10, f11, fb10, fb11], [fa00, fa01, fab00, fab01], [fa10, fa11, fab10, fab11]]

(``f_ab`` the corner ``(a, b)``'s value, ``fa = h df/du``, ``fb = h df/dv``, ``fab = h^2 d2f/dudv``;
``H`` the cubic Hermite basis of :func:`~metrology.core.geometry.epipolar_table._hermite`). The
coarsest grid whose interpolation error, measured against exact solves at every cell's centre
and edge midpoints, is below :data:`GRID_TOL` is kept: on strongly distorted projectors a few
tens of thousands of 64-byte cells, which stay in the processor's caches (a bilinear grid needed
half-unit cells there: 133 MB read at random).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metrology.core.distortion import Distortion, undistort_pixels

GRID_TOL = 2e-5
"""Largest interpolation error (projector units, measured at the cells' centres and edge
midpoints) accepted for the projector's undistortion grid (both axes decoded)."""
GRID_STEPS: tuple[float, ...] = (16.0, 8.0, 4.0, 2.0, 1.0)
"""Grid spacings tried, projector units, coarsest first (powers of two: the position inside a
cell is exact); without one that meets :data:`GRID_TOL` both-axes pixels are undistorted by
Newton at every frame."""
GRID_MAX_ITER = 30
"""Newton iterations of the grid's exact undistortion."""
HERMITE = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-3.0, 3.0, -2.0, -1.0], [2.0, -2.0, 1.0, 1.0]])
"""``H``: ``p(t) = [1, t, t^2, t^3] H [f_0, f_1, h f'_0, h f'_1]``, the cubic Hermite basis."""


@dataclass(frozen=True)
class UndistortionGrid:
    """The projector's undistortion sampled on a grid, for bicubic look-ups.

    ``(x_p, y_p) = K^-1 (u, v) + (dx, dy)(u, v)``: the corrections ``dx, dy`` (float32
    ``(n_v, n_u)``) at ``u = -1 + step i``, ``v = -1 + step k``, exact (Newton, 1e-9 units).
    ``error`` is the worst interpolation error measured (projector units). ``cx16``, ``cy16`` hold,
    per cell (``(n_v - 1) (n_u - 1), 16`` float32, one 64-byte row), the bicubic coefficients of
    the correction, ``C_ij`` at ``4 i + j`` with ``i`` the power of the coded axis' position
    (``a`` for ``dx``, ``b`` for ``dy``: ``cy16`` holds ``C^T``) and ``j`` that of the other's.
    """

    step: float
    dx: np.ndarray
    dy: np.ndarray
    error: float
    intrinsics: tuple[float, float, float, float, float] = (1.0, 0.0, 0.0, 1.0, 0.0)
    cx16: np.ndarray = field(repr=False, default_factory=lambda: np.empty((0, 16), np.float32))
    cy16: np.ndarray = field(repr=False, default_factory=lambda: np.empty((0, 16), np.float32))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The grid as arrays (for the local cache); :meth:`from_arrays` inverts it."""
        meta = np.asarray([self.step, self.error, *self.intrinsics], np.float64)
        return {"meta": meta, "dx": self.dx, "dy": self.dy, "cx16": self.cx16, "cy16": self.cy16}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> UndistortionGrid:
        step, error, fx, s, cx, fy, cy = (float(x) for x in arrays["meta"])
        return cls(
            step=step,
            dx=arrays["dx"],
            dy=arrays["dy"],
            error=error,
            intrinsics=(fx, s, cx, fy, cy),
            cx16=arrays["cx16"],
            cy16=arrays["cy16"],
        )

    @classmethod
    def build(cls, K: np.ndarray, dist: Distortion, width: float, height: float) -> UndistortionGrid | None:
        """The coarsest grid of :data:`GRID_STEPS` meeting :data:`GRID_TOL`, or None.

        The exact corrections are solved on a grid of half the step: its even nodes are the
        grid's, its odd ones (edge midpoints and cell centres) check the interpolation."""
        fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
        for step in GRID_STEPS:
            n_u, n_v = math.ceil((width + 1) / step) + 2, math.ceil((height + 1) / step) + 2
            uu, vv = np.meshgrid(-1.0 + 0.5 * step * np.arange(2 * n_u - 1), -1.0 + 0.5 * step * np.arange(2 * n_v - 1))
            res = undistort_pixels(K, dist, uu, vv, tol_px=1e-9, max_iter=GRID_MAX_ITER)
            if res.n_failed:
                continue  # a finer grid reaches less far beyond the projector's image
            y_lin = (vv - cy) / fy
            x_lin = (uu - cx - s * y_lin) / fx
            dx, dy = res.x - x_lin, res.y - y_lin
            nodes = (slice(None, None, 2), slice(None, None, 2))
            # d(x, y)/d(u, v) = (K2 J)^-1 at the nodes, K2 = [[fx, s], [0, fy]], J the distortion's Jacobian
            _, _, (jxx, jxy, jyx, jyy) = dist.distort_with_jacobian(res.x[nodes], res.y[nodes])
            a11, a12, a21, a22 = fx * jxx + s * jyx, fx * jxy + s * jyy, fy * jyx, fy * jyy
            det = a11 * a22 - a12 * a21
            xu, xv, yu, yv = a22 / det, -a12 / det, -a21 / det, a11 / det
            coefs, err = [], 0.0
            for f, fu, fv, scale in (
                (dx, xu - 1.0 / fx, xv + s / (fx * fy), fx),
                (dy, yu, yv - 1.0 / fy, fy),
            ):
                c = _bicubic_cells(f[nodes], fu, fv, step)
                err = max(err, _check(c, f) * scale)
                coefs.append(c)
            if err <= GRID_TOL:
                cx16 = coefs[0].reshape(-1, 16)
                cy16 = np.swapaxes(coefs[1], -1, -2).reshape(-1, 16)  # the coded axis' power first
                return cls(
                    step=step,
                    dx=dx[nodes].astype(np.float32),
                    dy=dy[nodes].astype(np.float32),
                    error=err,
                    intrinsics=(float(fx), float(s), float(cx), float(fy), float(cy)),
                    cx16=np.ascontiguousarray(cx16, np.float32),
                    cy16=np.ascontiguousarray(cy16, np.float32),
                )
        return None

    def kernel_args(self, axis: str) -> tuple[np.ndarray, bool, float, int, int, float, float, float, float, float]:
        """``(coef, axis_u, 1 / step, n_cols, n_rows, fx, s, cx, fy, cy)``: the grid as the compiled
        kernels of :mod:`metrology.core.geometry.pinhole_kernels` read it (``cx16`` for axis u,
        ``cy16`` for v; the intrinsics give the affine part)."""
        coef = self.cx16 if axis == "u" else self.cy16
        return (coef, axis == "u", 1.0 / self.step, self.dx.shape[1] - 1, self.dx.shape[0] - 1, *self.intrinsics)

    def normalized(
        self, axis: str, u: np.ndarray, v: np.ndarray, derivative: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Bicubic undistorted normalized coordinate ``x_p`` (``axis="u"``) or ``y_p`` (``"v"``) at
        ``(u, v)`` and, with ``derivative``, its derivative along ``u`` (``x_p``) or ``v`` (``y_p``);
        float32, same shape. Coordinates beyond the grid (one unit outside the projector) are
        clamped to its border; NaN coordinates give NaN. One compiled pass
        (:func:`~metrology.core.geometry.pinhole_kernels.grid_tile`, float64 inside)."""
        from metrology.core.geometry import pinhole_kernels as kernels

        if np.shape(u) != np.shape(v):
            raise ValueError(f"u and v must have one shape, got {np.shape(u)} and {np.shape(v)}")
        q = np.empty(np.shape(u), np.float32)
        dq = np.empty(q.shape if derivative else 0, np.float32)
        kernels.grid_tile(
            kernels.flat(u), kernels.flat(v), *self.kernel_args(axis), q.reshape(-1), dq.reshape(-1), derivative
        )
        return q, (dq if derivative else None)

    def lookup(
        self, table: np.ndarray, u: np.ndarray, v: np.ndarray, derivative: bool = True
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The correction ``dx`` (``table`` is ``self.dx``) or ``dy`` at ``(u, v)``: :meth:`normalized`
        minus the affine ``K^-1 (u, v)``; with ``derivative`` its derivative along ``u`` (``dx``) or
        ``v`` (``dy``); float32 (the affine part from the grid's ``intrinsics``)."""
        axis = "u" if table is self.dx else "v"
        value, deriv = self.normalized(axis, u, v, derivative)
        fx, skew, cx, fy, cy = self.intrinsics
        y_lin = (np.asarray(v, np.float64) - cy) / fy
        lin = y_lin if axis == "v" else (np.asarray(u, np.float64) - cx - skew * y_lin) / fx
        value = (value - lin).astype(np.float32)
        if deriv is not None:
            deriv = (deriv - np.float32(1.0 / (fx if axis == "u" else fy))).astype(np.float32)
        return value, deriv


def _bicubic_cells(f: np.ndarray, fu: np.ndarray, fv: np.ndarray, step: float) -> np.ndarray:
    """``C`` (``(n_v - 1, n_u - 1, 4, 4)`` float64, ``C[..., i, j]`` the coefficient of ``a^i b^j``)
    of the bicubic Hermite patches through the node values ``f`` and derivatives ``fu = df/du``,
    ``fv = df/dv`` (``(n_v, n_u)``, per projector unit); the cross derivative is the mean of the
    central differences of ``fu`` along ``v`` and of ``fv`` along ``u``."""
    fuv = 0.5 * (np.gradient(fu, step, axis=0) + np.gradient(fv, step, axis=1))
    fa, fb, fab = fu * step, fv * step, fuv * step * step

    def corners(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return t[:-1, :-1], t[1:, :-1], t[:-1, 1:], t[1:, 1:]  # (a, b) = (0, 0), (0, 1), (1, 0), (1, 1)

    f00, f01, f10, f11 = corners(f)
    b00, b01, b10, b11 = corners(fb)
    a00, a01, a10, a11 = corners(fa)
    x00, x01, x10, x11 = corners(fab)
    G = np.stack(
        [
            np.stack([f00, f01, b00, b01], -1),
            np.stack([f10, f11, b10, b11], -1),
            np.stack([a00, a01, x00, x01], -1),
            np.stack([a10, a11, x10, x11], -1),
        ],
        -2,
    )
    return np.einsum("ik,...kl,jl->...ij", HERMITE, G, HERMITE)


def _check(c: np.ndarray, exact: np.ndarray) -> float:
    """The worst ``|p - exact|`` (normalized units) of the patches ``c`` (``(n_v - 1, n_u - 1, 4,
    4)``) at the cells' edge midpoints and centres, ``exact`` the corrections on the half-step grid
    (``(2 n_v - 1, 2 n_u - 1)``)."""
    worst = 0.0
    for a, b, rows, cols in (
        (0.5, 0.0, slice(0, -1, 2), slice(1, None, 2)),
        (0.0, 0.5, slice(1, None, 2), slice(0, -1, 2)),
        (0.5, 0.5, slice(1, None, 2), slice(1, None, 2)),
    ):
        pa, pb = a ** np.arange(4), b ** np.arange(4)
        p = np.einsum("i,...ij,j->...", pa, c, pb)
        worst = max(worst, float(np.abs(p - exact[rows, cols]).max()))
    return worst
