"""The projector's undistortion tabulated for one coded axis (pinhole rigs whose projector is
distorted and whose codec codes both projector axes, triangulated by the plane method).

The plane of the coded axis ``u`` needs only ``x_p(u, v)``, the undistorted normalized abscissa
of the decoded ``(u, v)`` (``y_p(u, v)`` for axis ``v``). It is the affine ``K^-1 (u, v)`` plus a
small correction ``dx(u, v)``, tabulated like the epipolar table
(:class:`~metrology.core.geometry.epipolar_table.EpipolarTable`) with the rows ``v = const`` as
its lines: exact at the nodes (Newton to 1e-9 projector units, the derivative along ``u`` from
the inverse of the distortion's Jacobian), a cubic Hermite polynomial along the coded axis
(node spacing up to 16 units) and linear across it (spacing 1, 0.5 or 0.25 units), the coarsest
table whose estimated error is below :data:`GRID_TOL`. A frame reads, per pixel, one cell of
seven float32 coefficients and evaluates a cubic (a few megabytes of cells, read along the
projector's rows as the camera's rows advance; a bilinear grid needed half-unit cells on
strongly distorted projectors, 133 MB read at random). For the axis ``v`` exchange the roles of
``u`` and ``v``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.distortion import Distortion, undistort_pixels
from metrology.core.geometry.epipolar_table import EpipolarTable
from metrology.core.geometry.pinhole_numpy import flat, tile_kernels

GRID_TOL = 2e-5
"""Largest estimated interpolation error (projector units) accepted for the projector's
undistortion table (both axes decoded)."""
GRID_MAX_ITER = 30
"""Newton iterations of the table's exact undistortion."""


@dataclass(frozen=True)
class UndistortionGrid:
    """The correction ``dx(u, v)`` (``axis="u"``) or ``dy(u, v)`` (``"v"``) of the projector's
    undistortion, tabulated (see the module docstring).

    ``table`` is an :class:`~metrology.core.geometry.epipolar_table.EpipolarTable` of the
    correction (normalized units) whose coded coordinate is ``axis`` and whose line intercepts
    are the other projector coordinate (projector units); ``intrinsics`` ``(fx, s, cx, fy, cy)``
    give the affine part ``y_lin = (v - cy) / fy``, ``x_lin = (u - cx - s y_lin) / fx``.
    """

    axis: str
    table: EpipolarTable
    intrinsics: tuple[float, float, float, float, float]

    @property
    def error(self) -> float:
        """The estimated worst interpolation error, projector units."""
        return self.table.error

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table as arrays (for the local cache); :meth:`from_arrays` inverts it."""
        meta = np.asarray([1.0 if self.axis == "u" else 0.0, *self.intrinsics], np.float64)
        return {"grid_meta": meta, **self.table.to_arrays()}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> UndistortionGrid:
        axis_u, fx, s, cx, fy, cy = (float(x) for x in arrays["grid_meta"])
        return cls("u" if axis_u else "v", EpipolarTable.from_arrays(arrays), (fx, s, cx, fy, cy))

    @classmethod
    def build(
        cls, K: np.ndarray, dist: Distortion, width: float, height: float, axis: str = "u"
    ) -> UndistortionGrid | None:
        """The coarsest table meeting :data:`GRID_TOL` of the coded ``axis``, or None (a point of
        the projector's image, grown by one unit, that does not undistort)."""
        fx, s, cx, fy, cy = (float(K[0, 0]), float(K[0, 1]), float(K[0, 2]), float(K[1, 1]), float(K[1, 2]))
        axis_u = axis == "u"
        failed = [False]

        def solve(w: np.ndarray, c: np.ndarray, _: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            uu, vv = (w, c) if axis_u else (c, w)
            res = undistort_pixels(K, dist, uu, vv, tol_px=1e-9, max_iter=GRID_MAX_ITER)
            failed[0] |= res.n_failed > 0
            # d(x, y)/d(u, v) = (K2 J)^-1, K2 = [[fx, s], [0, fy]], J the distortion's Jacobian
            _, _, (jxx, jxy, jyx, jyy) = dist.distort_with_jacobian(res.x, res.y)
            a11, a12, a21, a22 = fx * jxx + s * jyx, fx * jxy + s * jyy, fy * jyx, fy * jyy
            det = a11 * a22 - a12 * a21
            y_lin = (vv - cy) / fy
            if axis_u:  # dx = x_p - x_lin, d(dx)/du = dx_p/du - 1/fx
                return res.x - (uu - cx - s * y_lin) / fx, a22 / det - 1.0 / fx
            return res.y - y_lin, a11 / det - 1.0 / fy

        size_w, size_c = (width, height) if axis_u else (height, width)
        table = EpipolarTable.build(
            solve,
            np.zeros_like,
            (-1.5, size_w + 0.5),
            (-1.0, size_c + 1.0),
            fx if axis_u else fy,
            1.0,
            GRID_TOL,
        )
        if table is None or failed[0]:
            return None
        return cls(axis, table, (fx, s, cx, fy, cy))

    def kernel_args(
        self,
    ) -> tuple[np.ndarray, float, float, int, float, float, int, bool, float, float, float, float, float]:
        """The table as :func:`~metrology.core.geometry.pinhole_kernels.grid_tile` reads it:
        ``(planes, g0, 1 / h, n_cols, c_lo, 1 / step_c, n_lines, axis_u, fx, s, cx, fy, cy)``."""
        t = self.table
        return (*t.kernel_args(), t.c_lo, 1.0 / t.step_c, t.n_lines, self.axis == "u", *self.intrinsics)

    def normalized(
        self, u: np.ndarray, v: np.ndarray, derivative: bool = False, frame_px: int | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The undistorted normalized coordinate of the coded axis, ``x_p`` (``axis="u"``) or
        ``y_p`` (``"v"``), at ``(u, v)`` (projector units, one shape) and, with ``derivative``,
        its derivative along the coded axis; float32, the shape of ``u``. NaN for NaN input and
        for coded coordinates beyond half a unit outside the projector; the other coordinate is
        clamped to the table (one unit outside). One pass of ``grid_tile`` (float64 inside),
        compiled or numpy's as :func:`~metrology.core.geometry.pinhole_numpy.tile_kernels`
        chooses for frames of ``frame_px`` pixels (default: ``u.size``)."""
        if np.shape(u) != np.shape(v):
            raise ValueError(f"u and v must have one shape, got {np.shape(u)} and {np.shape(v)}")
        kernels = tile_kernels(np.size(u) if frame_px is None else frame_px)
        coded, other = (u, v) if self.axis == "u" else (v, u)
        q = np.empty(np.shape(u), np.float32)
        dq = np.empty(q.shape if derivative else 0, np.float32)
        kernels.grid_tile(flat(coded), flat(other), *self.kernel_args(), q.reshape(-1), dq.reshape(-1), derivative)
        return q, (dq if derivative else None)
