"""The projector's undistortion along epipolar lines, tabulated (pinhole rigs whose projector is
distorted and whose codec codes one projector axis).

With one axis decoded, say ``u``, a camera pixel's projector point lies on the pixel's epipolar
line ``y_p = c0 + c1 x_p`` (undistorted normalized projector coordinates), and ``x_p`` solves
``fx D_x(x_p, c0 + c1 x_p) + s D_y + cx = u``. Every epipolar line passes through the epipole
(the camera centre ``T`` seen by the projector), so ``l . T = 0`` ties the slope to the intercept::

    c1 = (T_o - c0 T_z) / T_a        (T_a, T_o: T's component of the coded axis, of the other)

and ``x_p = Q(u, c0)`` is a smooth function of two variables. :class:`EpipolarTable` samples it
exactly (Newton to 1e-9 projector units) at ``u_k = lo + k h_w`` and ``c0_j = c_lo + j h_c``
and interpolates it as a cubic Hermite polynomial in ``u`` (values and exact slopes at the
nodes: error ~ h_w^4 |Q''''| / 384) and linearly in ``c0`` (error ~ h_c^2 |Q_cc| / 8). Since
``c0`` of a camera pixel is fixed, its row of cells and its weight between the two rows are
computed once per pixel; a frame costs, per pixel, the cell's index, one gather of seven (or six)
float32 coefficients from as many contiguous planes and a cubic in the position ``tau`` inside the cell::

    Q = sum_m tau^m (A_m + a_c B_m),   A: the cubic of row j, B: row j+1 minus row j

evaluated by Horner's rule on the blended coefficients, in one pass per tile, compiled
(:mod:`metrology.core.geometry.pinhole_kernels`) or its numpy twin
(:mod:`metrology.core.geometry.pinhole_numpy`); float32 coefficients, float64 arithmetic. ``B_3``
(the change of the cubic term from one line to the next, ~1e-6 projector units on strongly
distorted projectors) is left out and its largest value added to the table's error.

For the coded axis ``v`` exchange the roles of ``x`` and ``y``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from metrology.core.geometry.pinhole_numpy import flat, tile_kernels

LINE_TOL = 5e-5
"""Largest estimated interpolation error accepted, projector units. The float32 evaluation
itself rounds ``q`` by up to ~1e-4 projector units on a 2000-unit projector (half a float32 ulp
of a normalized coordinate of 0.4, times ``fx``), as the float32 input ``u`` is already rounded
by up to 6e-5 units: a finer table would not be more accurate."""
LINE_STEPS_W: tuple[float, ...] = (16.0, 8.0, 4.0, 2.0)
"""Node spacings along the coded axis tried, projector units, coarsest first (powers of two)."""
LINE_STEPS_C: tuple[float, ...] = (1.0, 0.5, 0.25)
"""Node spacings across the lines tried, in projector units of the other axis, coarsest first."""
LINE_MARGIN = 8.0
"""Lines are tabulated where they cross the projector's image grown by this many units on each
side; camera pixels whose line misses it cannot be lit and get NaN."""

Solver = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``(w, c0, c1) -> (q, dq/dw)``: the coded normalized coordinate on each line (NaN where the
solve fails) and its derivative along the coded axis, float64 arrays of ``w``'s shape."""


@dataclass(frozen=True)
class EpipolarTable:
    """The tabulated ``Q(w, c0)`` (see the module docstring).

    Attributes
    ----------
    planes : (7 or 6, n_rows * n_cols) float32
        Per cell (the flat index of the second axis) ``A_0..A_3, B_0..B_2`` (``B_2`` left out
        where the error allows it, see :meth:`_from_nodes`), one contiguous plane
        per coefficient (a gather from a plane writes a contiguous array); column 0 and the
        last column of each row are NaN guards (coded coordinates outside ``[lo, hi]`` give
        NaN), so flat index 0 is a guard.
    lo, step_w : float
        The first node and the spacing along the coded axis, projector units.
    n_cols : int
        Cells per row, guards included.
    c_lo, step_c : float
        The first line's intercept and the spacing of the intercepts (normalized units).
    n_lines : int
        Rows of nodes (``n_lines - 1`` rows of cells).
    error : float
        The estimated interpolation error, projector units.
    """

    planes: np.ndarray
    lo: float
    step_w: float
    n_cols: int
    c_lo: float
    step_c: float
    n_lines: int
    error: float

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table as arrays (for the local cache); :meth:`from_arrays` inverts it."""
        meta = [self.lo, self.step_w, self.n_cols, self.c_lo, self.step_c, self.n_lines, self.error]
        return {"line_planes": self.planes, "line_meta": np.asarray(meta, np.float64)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> EpipolarTable:
        lo, step_w, n_cols, c_lo, step_c, n_lines, error = (float(x) for x in arrays["line_meta"])
        return cls(arrays["line_planes"], lo, step_w, int(n_cols), c_lo, step_c, int(n_lines), error)

    @classmethod
    def build(
        cls,
        solve: Solver,
        slope: Callable[[np.ndarray], np.ndarray],
        domain: tuple[float, float],
        c_range: tuple[float, float],
        scale_w: float,
        scale_c: float,
        tol: float = LINE_TOL,
    ) -> EpipolarTable | None:
        """The coarsest table meeting ``tol`` (default :data:`LINE_TOL`), or None.

        ``solve`` as :data:`Solver`; ``slope(c0)`` the lines' ``c1``; ``domain = (lo, hi)`` the
        coded coordinates covered (projector units); ``c_range`` the intercepts covered;
        ``scale_w`` (``fx`` or ``fy``) turns normalized units of the coded axis into projector
        units, ``scale_c`` those of the other axis."""
        lo, hi = domain
        for step_c_px in LINE_STEPS_C:
            n_lines = max(2, math.ceil((c_range[1] - c_range[0]) * scale_c / step_c_px) + 1)
            step_c = (c_range[1] - c_range[0]) / (n_lines - 1)
            c0 = c_range[0] + step_c * np.arange(n_lines)
            for step_w in LINE_STEPS_W:  # powers of two: the position in a cell is exact in float32
                n_w = max(2, math.ceil((hi - lo) / step_w) + 1)
                w = lo + step_w * np.arange(n_w)
                ww, cc = np.meshgrid(w, c0)
                q, dq = solve(ww, cc, slope(cc))
                # Hermite midpoints of every eighth line against exact solves there
                sub = slice(0, n_lines, 8)
                mid_w = 0.5 * (w[:-1] + w[1:])
                mw, mc = np.meshgrid(mid_w, c0[sub])
                exact, _ = solve(mw, mc, slope(mc))
                herm = _hermite(q[sub], dq[sub] * step_w)
                mid = herm[..., 0] + 0.5 * herm[..., 1] + 0.25 * herm[..., 2] + 0.125 * herm[..., 3]
                err_w = _nanmax(np.abs(mid - exact)) * scale_w
                if err_w > tol / 2:
                    continue
                err_c = _nanmax(np.abs(q[2:] - 2 * q[1:-1] + q[:-2])) / 8 * scale_w if n_lines > 2 else 0.0
                if err_w + err_c > tol:
                    break  # a finer step across the lines
                table = cls._from_nodes(q, dq, lo, step_w, c_range[0], step_c, err_w + err_c, scale_w, tol)
                if table.error <= tol:
                    return table
                break  # the B_3 left out is too large: a finer step across the lines
        return None

    @classmethod
    def _from_nodes(
        cls,
        q: np.ndarray,
        dq: np.ndarray,
        lo: float,
        step_w: float,
        c_lo: float,
        step_c: float,
        error: float,
        scale_w: float,
        tol: float = LINE_TOL,
    ) -> EpipolarTable:
        """The table of node values ``q`` and slopes ``dq`` (``(n_lines, n_w)``, normalized
        units); ``error`` (projector units) grows by the ``B_3`` left out, and by ``B_2`` when
        that too fits within ``tol`` (mildly distorted projectors: six planes)."""
        n_lines, n_w = q.shape
        herm = _hermite(q, dq * step_w)  # (n_lines, n_w - 1, 4)
        a, b = herm[:-1], herm[1:] - herm[:-1]
        error += _nanmax(np.abs(b[..., 3])) * scale_w
        b2 = _nanmax(np.abs(b[..., 2])) * scale_w
        n_b = 2 if error + b2 <= tol else 3  # B_2 too is left out where the budget allows
        error += b2 if n_b == 2 else 0.0
        planes = np.full((4 + n_b, n_lines - 1, n_w + 1), np.nan, np.float32)
        planes[:4, :, 1:-1] = np.moveaxis(a, -1, 0)
        planes[4:, :, 1:-1] = np.moveaxis(b[..., :n_b], -1, 0)
        return cls(planes.reshape(4 + n_b, -1), lo, step_w, n_w + 1, c_lo, step_c, n_lines, error)

    def pixel_rows(self, c0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per camera pixel of line intercept ``c0`` (any shape): the flat index of its row's
        first cell (int32; 0, a guard, where the line is not tabulated) and its weight ``a_c``
        between row ``j`` and ``j + 1`` (float32; NaN where not tabulated)."""
        with np.errstate(invalid="ignore"):
            g = (np.asarray(c0, np.float64) - self.c_lo) / self.step_c
            inside = (g >= 0) & (g <= self.n_lines - 1)
            j = np.minimum(np.where(inside, g, 0.0).astype(np.int64), self.n_lines - 2)
        frac = np.where(inside, g - j, np.nan).astype(np.float32)
        base = np.where(inside, j * self.n_cols, 0).astype(np.int32)
        return base, frac

    def kernel_args(self) -> tuple[np.ndarray, float, float, int]:
        """``(planes, g0, 1 / h, n_cols)``: the table as the compiled kernels of
        :mod:`metrology.core.geometry.pinhole_kernels` read it (``g0 = lo - h``, column 0 the guard)."""
        return self.planes, self.lo - self.step_w, 1.0 / self.step_w, self.n_cols

    def evaluate(
        self,
        coded: np.ndarray,
        base: np.ndarray,
        frac: np.ndarray,
        derivative: bool = False,
        frame_px: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``q`` (float32, the shape of ``coded``) at coded coordinates ``coded`` of pixels with
        :meth:`pixel_rows` ``(base, frac)``, and with ``derivative`` ``dq/dw`` (per projector
        unit); NaN outside the table. One pass of ``table_tile`` (float64 inside), compiled or
        numpy's as :func:`~metrology.core.geometry.pinhole_numpy.tile_kernels` chooses for frames
        of ``frame_px`` pixels (default: ``coded.size``); both give the same numbers."""
        if not np.shape(coded) == np.shape(base) == np.shape(frac):
            raise ValueError("coded, base and frac must have one shape")
        kernels = tile_kernels(np.size(coded) if frame_px is None else frame_px)
        q = np.empty(np.shape(coded), np.float32)
        dq = np.empty(q.shape if derivative else 0, np.float32)
        kernels.table_tile(
            flat(coded),
            flat(base, np.int32),
            flat(frac),
            *self.kernel_args(),
            q.reshape(-1),
            dq.reshape(-1),
            derivative,
        )
        return q, (dq if derivative else None)


def _hermite(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Cubic Hermite coefficients ``(..., n - 1, 4)`` in ``tau`` of the cells between nodes of
    values ``q`` and scaled slopes ``d = h dq/dw`` along the last axis:
    ``p(tau) = q0 + d0 tau + (3 (q1 - q0) - 2 d0 - d1) tau^2 + (2 (q0 - q1) + d0 + d1) tau^3``."""
    q0, q1, d0, d1 = q[..., :-1], q[..., 1:], d[..., :-1], d[..., 1:]
    return np.stack([q0, d0, 3 * (q1 - q0) - 2 * d0 - d1, 2 * (q0 - q1) + d0 + d1], axis=-1)


def _nanmax(a: np.ndarray) -> float:
    finite = a[np.isfinite(a)]
    return float(finite.max()) if finite.size else math.inf
