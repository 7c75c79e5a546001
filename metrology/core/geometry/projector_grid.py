"""The projector's undistortion sampled on a grid, for bilinear look-ups (pinhole rigs whose
projector is distorted and whose codec codes both projector axes).

``(x_p, y_p) = K^-1 (u, v) + (dx, dy)(u, v)``: the corrections are solved exactly (Newton, 1e-9
projector units) on a grid of spacing :data:`GRID_STEPS` and interpolated bilinearly, when the
interpolation error (estimated from the grid's second differences) is below :data:`GRID_TOL`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metrology.core.distortion import Distortion, undistort_pixels

GRID_TOL = 2e-5
"""Largest bilinear-interpolation error (projector units, estimated from the grid's second
differences) accepted for the projector's undistortion grid (both axes decoded)."""
GRID_STEPS: tuple[float, ...] = (1.0, 0.5)
"""Grid spacings tried, projector units, coarsest first; without one that meets
:data:`GRID_TOL` both-axes pixels are undistorted by Newton at every frame."""
GRID_MAX_ITER = 30
"""Newton iterations of the grid's exact undistortion."""


@dataclass(frozen=True)
class UndistortionGrid:
    """The projector's undistortion sampled on a grid, for bilinear look-ups.

    ``(x_p, y_p) = K^-1 (u, v) + (dx, dy)(u, v)``: the corrections ``dx, dy`` (float32
    ``(n_v, n_u)``) at ``u = -1 + step i``, ``v = -1 + step k``, exact (Newton, 1e-9 units).
    ``error`` is the estimated worst bilinear error (projector units). ``cx4``, ``cy4`` hold, per
    cell (``(n_v - 1) (n_u - 1), 4`` float32), the bilinear coefficients of the undistorted
    normalized coordinate itself, ``x_p = c0 + c1 a_u + c2 a_v + c3 a_u a_v`` (``a_u, a_v`` the
    position inside the cell, 0..1): bilinear interpolation reproduces the affine part
    ``K^-1 (u, v)`` exactly, so one gather of 16 bytes and five multiply-adds give ``x_p``.
    """

    step: float
    dx: np.ndarray
    dy: np.ndarray
    error: float
    intrinsics: tuple[float, float, float, float, float] = (1.0, 0.0, 0.0, 1.0, 0.0)
    cx4: np.ndarray = field(repr=False, default_factory=lambda: np.empty((0, 4), np.float32))
    cy4: np.ndarray = field(repr=False, default_factory=lambda: np.empty((0, 4), np.float32))

    @staticmethod
    def _cells(t: np.ndarray) -> np.ndarray:
        """Per-cell bilinear coefficients ``(c0, c1, c2, c3)`` of a float64 grid, float32 ``(cells, 4)``."""
        f00, f01, f10, f11 = t[:-1, :-1], t[:-1, 1:], t[1:, :-1], t[1:, 1:]
        coef = np.stack([f00, f01 - f00, f10 - f00, f11 - f10 - f01 + f00], axis=-1)
        return np.ascontiguousarray(coef.reshape(-1, 4).astype(np.float32))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The grid as arrays (for the local cache); :meth:`from_arrays` inverts it."""
        meta = np.asarray([self.step, self.error, *self.intrinsics], np.float64)
        return {"meta": meta, "dx": self.dx, "dy": self.dy, "cx4": self.cx4, "cy4": self.cy4}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> UndistortionGrid:
        step, error, fx, s, cx, fy, cy = (float(x) for x in arrays["meta"])
        return cls(
            step=step,
            dx=arrays["dx"],
            dy=arrays["dy"],
            error=error,
            intrinsics=(fx, s, cx, fy, cy),
            cx4=arrays["cx4"],
            cy4=arrays["cy4"],
        )

    @classmethod
    def build(cls, K: np.ndarray, dist: Distortion, width: float, height: float) -> UndistortionGrid | None:
        """The coarsest grid of :data:`GRID_STEPS` meeting :data:`GRID_TOL`, or None."""
        fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
        for step in GRID_STEPS:
            gu = -1.0 + step * np.arange(math.ceil((width + 1) / step) + 2)
            gv = -1.0 + step * np.arange(math.ceil((height + 1) / step) + 2)
            uu, vv = np.meshgrid(gu, gv)
            res = undistort_pixels(K, dist, uu, vv, tol_px=1e-9, max_iter=GRID_MAX_ITER)
            if res.n_failed:
                return None
            y_lin = (vv - cy) / fy
            x_lin = (uu - cx - s * y_lin) / fx
            dx, dy = res.x - x_lin, res.y - y_lin
            # bilinear error at a cell centre ~ (|F_uu| + |F_vv|) step^2 / 8 = (|D2_u F| + |D2_v F|) / 8
            err = 0.0
            for f, scale in ((dx, fx), (dy, fy)):
                d2u = np.abs(f[:, 2:] - 2 * f[:, 1:-1] + f[:, :-2]).max()
                d2v = np.abs(f[2:] - 2 * f[1:-1] + f[:-2]).max()
                err = max(err, float(d2u + d2v) / 8 * scale)
            if err <= GRID_TOL:
                return cls(
                    step=step,
                    dx=dx.astype(np.float32),
                    dy=dy.astype(np.float32),
                    error=err,
                    intrinsics=(float(fx), float(s), float(cx), float(fy), float(cy)),
                    cx4=cls._cells(res.x),
                    cy4=cls._cells(res.y),
                )
        return None

    def normalized(
        self, axis: str, u: np.ndarray, v: np.ndarray, derivative: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Bilinear undistorted normalized coordinate ``x_p`` (``axis="u"``) or ``y_p`` (``"v"``) at
        ``(u, v)`` and, with ``derivative``, its derivative along ``u`` (``x_p``) or ``v`` (``y_p``);
        float32, same shape. Coordinates beyond the grid (one unit outside the projector) are
        clamped to its border; NaN coordinates give NaN."""
        coef = self.cx4 if axis == "u" else self.cy4
        n_cols = self.dx.shape[1] - 1
        n_rows = self.dx.shape[0] - 1
        inv = np.float32(1.0 / self.step)
        gu = np.add(u, np.float32(1.0), dtype=np.float32)
        gv = np.add(v, np.float32(1.0), dtype=np.float32)
        if self.step != 1.0:
            gu *= inv
            gv *= inv
        np.clip(gu, np.float32(0.0), np.float32(n_cols - 1e-3), out=gu)  # NaN stays NaN
        np.clip(gv, np.float32(0.0), np.float32(n_rows - 1e-3), out=gv)
        cu, cv = np.floor(gu), np.floor(gv)  # the cell's column and row (gu, gv >= 0)
        with np.errstate(invalid="ignore"):  # NaN: an arbitrary index, clipped by take(); NaN propagates
            iu = cu.astype(np.int32)
            iv = cv.astype(np.int32)
        gu -= cu  # a_u (float32 minus float32: no float64 temporary)
        gv -= cv  # a_v
        iv *= np.int32(n_cols)
        iv += iu
        c = coef.take(iv, axis=0, mode="clip")
        c0, c1, c2, c3 = c[..., 0], c[..., 1], c[..., 2], c[..., 3]
        slope = np.multiply(c3, gv if axis == "u" else gu)
        slope += c1 if axis == "u" else c2  # d/d(a_u) for x_p, d/d(a_v) for y_p
        if axis == "u":
            value = np.multiply(c2, gv)
            deriv = slope * inv if derivative else None
            slope *= gu
        else:
            value = np.multiply(c1, gu)
            deriv = slope * inv if derivative else None
            slope *= gv
        value += slope
        value += c0
        return value, deriv

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
