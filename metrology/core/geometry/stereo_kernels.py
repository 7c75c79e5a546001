"""Compiled kernels of the stereo model's hot loops (numba, ``nogil``: the tiles of
:func:`metrology.core.tiling.run_tiled` run them on the pool's threads in parallel).

Each kernel does in one pass over a tile what took a dozen numpy passes and their temporaries:

- :func:`sample_tile`: bilinear sampling at fixed positions with the parabolic terms (the
  rectification of a decoded map, the disparity sampled back on camera 0's grid), and where a
  neighbour is missing, from the three that are there (:func:`_sample_triangle`);
- :func:`match_pixels`: camera-0 pixels matched directly at their own positions (where the
  resampling chain lacks a neighbour);
- :func:`match_tile`: the matching of rectified rows (running extrema, a merge walk instead of a
  ``searchsorted``), the sub-pixel position and the normalized disparity;
- :func:`depth_tile`: the disparity to points along camera 0's rays.

The equations are those of :mod:`metrology.core.geometry.stereo_match`'s module docstring; the
arithmetic is float64 inside, float32 in and out. Compiled on first use and cached on disk
(``cache=True``: a new process loads the machine code instead of compiling it again).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SAMPLE_STRICT = 0
"""Sampling mode of :func:`sample_tile`: NaN where any of the four neighbours is NaN."""
SAMPLE_TRIANGLE = 1
"""Sampling mode of :func:`sample_tile`: with one of the four neighbours NaN, the plane through the
other three (inside the cell of decoded pixels)."""


@njit(nogil=True, cache=True)
def _sample_triangle(flat: np.ndarray, i: int, w: int, fx: float, fy: float) -> float:  # pragma: no cover
    """The value at ``(fx, fy)`` of the cell whose top-left neighbour is ``flat[i]`` when one of its
    four neighbours is NaN: the plane through the other three (exact for an affine map), e.g.
    ``a + fx (b - a) + fy (c - a)`` without ``d``; NaN when two or more are NaN or the position is."""
    a = np.float64(flat[i])
    b = np.float64(flat[i + 1])
    c = np.float64(flat[i + w])
    d = np.float64(flat[i + w + 1])
    ma, mb, mc, md = math.isnan(a), math.isnan(b), math.isnan(c), math.isnan(d)
    if int(ma) + int(mb) + int(mc) + int(md) != 1:
        return np.nan
    if md:
        return a + fx * (b - a) + fy * (c - a)
    if mc:
        return a + fx * (b - a) + fy * (d - b)
    if mb:
        return a + fy * (c - a) + fx * (d - c)
    return d + (1.0 - fx) * (c - d) + (1.0 - fy) * (b - d)


@njit(nogil=True, cache=True)
def _second_difference(flat: np.ndarray, i: int, step: int, before: bool, after: bool) -> float:  # pragma: no cover
    """The second difference of ``flat`` across the segment ``i .. i + step`` (``step`` 1: along a
    row, ``w``: down a column) at the segment's middle: the mean of those at its two ends,
    ``(u[i - step] - u[i] - u[i + step] + u[i + 2 step]) / 2``, when both outer samples exist
    (``before``, ``after``: inside the image) and are not NaN; else the one-sided
    ``u[i - step] - 2 u[i] + u[i + step]`` or ``u[i] - 2 u[i + step] + u[i + 2 step]``; NaN when
    neither outer sample is known. Each is exact for a quadratic map."""
    a = np.float64(flat[i])
    b = np.float64(flat[i + step])
    left = np.float64(flat[i - step]) if before else np.nan
    right = np.float64(flat[i + 2 * step]) if after else np.nan
    if not math.isnan(left) and not math.isnan(right):
        return 0.5 * (left - a - b + right)
    if not math.isnan(left):
        return left - 2.0 * a + b
    if not math.isnan(right):
        return a - 2.0 * b + right
    return np.nan


@njit(nogil=True, cache=True)
def sample_tile(
    image: np.ndarray,
    index: np.ndarray,
    inner: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    out: np.ndarray,
    curvature: bool,
    fallback: int,
    where: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``out[r, c]`` = the ``(h, w)`` float32 ``image`` sampled bilinearly at the positions of
    ``index`` (flat index of the top-left neighbour, ``(n, m)`` int32; ``inner`` (``(n, m)`` uint8)
    1 where it is at least one pixel in from the image's left and top edges and two from its right
    and bottom ones, where both symmetric stencils below fit), ``wx``, ``wy`` (``(n, m)``
    float32 weights of the right and lower neighbours; NaN outside the image): ``top = a + wx (b -
    a)``, ``bottom = c + wx (d - c)``, ``top + wy (bottom - top)``; NaN where a neighbour is NaN.

    With ``curvature`` the parabolic terms ``-(wx (1 - wx) c_xx + wy (1 - wy) c_yy) / 2`` are added
    (exact for a quadratic map), each where it is known, independently of the other:
    ``c_xx = (u[j-1] - u[j] - u[j+1] + u[j+2]) / 2`` along the top-left neighbour's row (the mean of
    the second differences at ``j`` and ``j + 1``), the one-sided second difference at ``j`` or
    ``j + 1`` where ``u[j+2]`` or ``u[j-1]`` is missing (NaN, or outside the image), the bottom
    neighbours' row where the top row has neither (:func:`_second_difference`); ``c_yy`` likewise
    down the left neighbours' column, then the right ones'. Bilinear interpolation alone errs by up
    to ``|c_xx + c_yy| / 8``: at the edge of the decoded field of a steep, curved surface this is the
    error of the whole chain (docs/stereo.md, "The VDI/VDE probing error of a noise-free sphere").

    Where a neighbour is NaN the sample is NaN with ``fallback`` :data:`SAMPLE_STRICT`; with
    :data:`SAMPLE_TRIANGLE` and one neighbour NaN, the plane through the other three
    (:func:`_sample_triangle`).

    ``where`` ((n, m) float32) samples only where it is not NaN (NaN elsewhere: the disparity sampled
    back where camera 0 decoded); an empty ``(0, 0)`` array samples everywhere."""
    w = image.shape[1]
    h = image.shape[0]
    flat = image.ravel()
    n, m = index.shape
    everywhere = where.shape[0] == 0
    for r in range(n):
        for c in range(m):
            if not everywhere and math.isnan(where[r, c]):
                out[r, c] = np.nan
                continue
            i = index[r, c]
            fx = np.float64(wx[r, c])
            fy = np.float64(wy[r, c])
            a = np.float64(flat[i])
            b = np.float64(flat[i + 1])
            cc = np.float64(flat[i + w])
            d = np.float64(flat[i + w + 1])
            top = a + fx * (b - a)
            bottom = cc + fx * (d - cc)
            value = top + fy * (bottom - top)
            if math.isnan(value):
                if fallback == SAMPLE_TRIANGLE and not math.isnan(fx + fy):
                    value = np.float64(_sample_triangle(flat, i, w, fx, fy))
            elif curvature:
                cxx = np.nan
                cyy = np.nan
                if inner[r, c]:  # the common case: both symmetric stencils inside the image
                    cxx = 0.5 * (np.float64(flat[i - 1]) - a - b + np.float64(flat[i + 2]))
                    cyy = 0.5 * (np.float64(flat[i - w]) - a - cc + np.float64(flat[i + 2 * w]))
                if math.isnan(cxx) or math.isnan(cyy):  # an edge or a missing sample: one-sided, other line
                    ix = i % w
                    iy = i // w
                    left, right = ix >= 1, ix + 2 <= w - 1
                    up, down = iy >= 1, iy + 2 <= h - 1
                    if math.isnan(cxx):
                        cxx = _second_difference(flat, i, 1, left, right)
                        if math.isnan(cxx):
                            cxx = _second_difference(flat, i + w, 1, left, right)
                    if math.isnan(cyy):
                        cyy = _second_difference(flat, i, w, up, down)
                        if math.isnan(cyy):
                            cyy = _second_difference(flat, i + 1, w, up, down)
                if not math.isnan(cxx) and not math.isnan(cyy):
                    value -= 0.5 * (fx * (1.0 - fx) * cxx + fy * (1.0 - fy) * cyy)
                elif not math.isnan(cxx):
                    value -= 0.5 * fx * (1.0 - fx) * cxx
                elif not math.isnan(cyy):
                    value -= 0.5 * fy * (1.0 - fy) * cyy
            out[r, c] = value


@njit(nogil=True, cache=True)
def clean_row(u: np.ndarray, lo: float, hi: float, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[:w]`` = the float32 row ``u`` (w,) as float64, NaN where not decoded (outside ``[lo,
    hi]``) and at an *isolated out-of-order value*: one whose two neighbours are decoded and in order
    (``u[j-1] < u[j+1]``) while it does not lie strictly between them (a spike or a dip of one pixel).
    Such a value is not matched and does not take part in the running extrema, so it cannot refuse
    the rest of its row."""
    w = u.shape[0]
    for j in range(w):
        v = np.float64(u[j])
        out[j] = v if (v >= lo and v <= hi) else np.nan
    for j in range(1, w - 1):
        v = np.float64(u[j])
        before = np.float64(u[j - 1])
        after = np.float64(u[j + 1])
        if not (before >= lo and before <= hi and after >= lo and after <= hi):
            continue
        if before < after and not (before < v and v < after):
            out[j] = np.nan


@njit(nogil=True, cache=True)
def suffix_min(row: np.ndarray, w: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[c]`` = the minimum of the (not NaN) values of ``row[c:w]``, ``inf`` where all are NaN."""
    low = np.inf
    for c in range(w - 1, -1, -1):
        v = row[c]
        if v < low:
            low = v
        out[c] = low


@njit(nogil=True, cache=True, error_model="numpy", inline="always")  # inlined: run_positions' loop overlaps it
def _run_position(
    before: float, a: float, b: float, after: float, q: float
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`run_position`'s arithmetic, without a branch (inlined: its callers take numpy's error model,
    a division by zero of a discarded case giving inf or NaN instead of raising)."""
    lin = (q - a) / (b - a)
    step = b - a
    d0 = before - 2.0 * a + b
    d1 = a - 2.0 * b + after
    has_before = before < a and abs(d0) < step
    has_after = after > b and abs(d1) < step
    both = has_before and has_after
    # the arithmetic runs whatever the case and the case selects the result at the end: no branch,
    # so a loop over many segments (run_positions) overlaps them instead of waiting on each division
    c3 = (d1 - d0) / 6.0 if both else 0.0
    c2 = (0.5 * d0 + c3) if both else (0.5 * d0 if has_before else 0.5 * d1)
    ok = has_before or has_after
    s = lin
    for _ in range(3):
        slope = (b - a) + (2.0 * s - 1.0) * (c2 + c3 * s) + s * (s - 1.0) * c3
        ok = ok and slope > 0
        s -= (a + s * (b - a) + s * (s - 1.0) * (c2 + c3 * s) - q) / slope
    slope = (b - a) + (2.0 * s - 1.0) * (c2 + c3 * s) + s * (s - 1.0) * c3
    ok = ok and s >= 0.0 and s < 1.0 and slope > 0
    return (s, slope) if ok else (lin, step)


@njit(nogil=True, cache=True, error_model="numpy")
def run_position(
    before: float, a: float, b: float, after: float, q: float
) -> tuple[float, float]:  # pragma: no cover - compiled
    """Where a monotone run of samples takes ``q`` between two of them, ``a = u(0) <= q < b = u(1)``:
    ``(s, u'(s))``, ``s`` in ``[0, 1)`` px from ``a``'s sample, the slope in units per px.

    Linear interpolation, ``s = (q - a) / (b - a)``, misplaces ``s`` by ``s (1 - s) u'' / (2 u')``
    px (``u'' / (8 u')`` mid-segment). Inside a monotone run (``before = u(-1) < a``, ``after = u(2)
    > b``) the cubic through the four samples,

        ``P(s) = a + s (b - a) + s (s - 1) (c_2 + c_3 s)``,
        ``c_3 = (D_1 - D_0) / 6``, ``c_2 = D_0 / 2 + c_3``,

    ``D_0 = before - 2 a + b`` and ``D_1 = a - 2 b + after`` the second differences at 0 and 1, is
    solved for ``P(s) = q`` by Newton from the linear ``s`` (three steps; the error is then of the
    order of the fourth derivative); with one outer sample only, the parabola through three
    (``c_3 = 0``, ``c_2 = D_0 / 2`` or ``D_1 / 2``); at a run's ends (no outer sample in order),
    linear with the secant ``b - a``. Where the polynomial is not increasing or its root leaves
    ``[0, 1]`` the linear result is kept, so ``s`` stays in its segment and varies continuously with
    ``q`` (no pixel locking). An outer sample whose second difference is not below the segment's
    step (``|D| >= b - a``: no smooth function sampled finely, e.g. a jump at a fringe's edge) is
    not used."""
    return _run_position(before, a, b, after, q)


@njit(nogil=True, cache=True, error_model="numpy")
def run_positions(
    before: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    after: np.ndarray,
    q: np.ndarray,
    n: int,
    s_out: np.ndarray,
    slope_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`run_position` of the first ``n`` segments of the float64 arrays ``before, a, b, after,
    q`` into ``s_out``, ``slope_out``: a loop without branches, whose iterations the processor
    overlaps (each alone waits on a chain of four divisions)."""
    for k in range(n):
        s_out[k], slope_out[k] = _run_position(before[k], a[k], b[k], after[k], q[k])


@njit(nogil=True, cache=True, inline="always")
def _segment_position(
    row1: np.ndarray, min1: np.ndarray, w1: int, p: int, q: float
) -> tuple[float, float]:  # pragma: no cover
    """Camera 1's column ``p + s`` and slope where its cleaned row ``row1`` (suffix minimum ``min1``,
    ``w1`` columns) takes ``q`` in the segment ``[p, p + 1]``: ``u1(p) <= q < u1(p + 1)``, unique (no
    decoded value right of ``p + 1`` at most ``q``), ``s`` from :func:`run_position`; NaN, NaN
    otherwise."""
    if p < 0 or p > w1 - 2:
        return np.nan, np.nan
    a = np.float64(row1[p])
    b = np.float64(row1[p + 1])
    beyond = np.float64(min1[p + 2]) if p + 2 < w1 else np.inf
    if not (a <= q and q < b and beyond > q):
        return np.nan, np.nan
    before = np.float64(row1[p - 1]) if p >= 1 else np.nan
    after = np.float64(row1[p + 2]) if p + 2 < w1 else np.nan
    s, slope = run_position(before, a, b, after, q)
    return p + s, slope


MATCH_SCRATCH_ROWS = 13
"""Rows of :func:`match_tile`'s float64 scratch: four row buffers and nine of the segments found."""


@njit(nogil=True, cache=True, error_model="numpy")
def match_tile(
    u0: np.ndarray,
    u1: np.ndarray,
    lo: float,
    hi: float,
    x0n: np.ndarray,
    inv_f: float,
    offset: float,
    x1_out: np.ndarray,
    slope_out: np.ndarray,
    d_out: np.ndarray,
    scratch: np.ndarray,
    rows0_out: np.ndarray,
    rows1_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Match rows of rectified maps whose coordinate grows along the rows.

    ``u0`` (n, W0), ``u1`` (n, W1) float32, decoded where in ``[lo, hi]`` (rows cleaned by
    :func:`clean_row`). For each camera-0 pixel of value ``q`` that is a *record* (above every
    decoded value left of it in its row, below every one right of it: the left-right consistency),
    the segment ``[x, x + 1]`` of camera 1's row with ``u1(x) <= q < u1(x + 1)``, found by a merge
    walk on camera 1's running maximum (the records grow along the row), kept when no decoded value
    of camera 1 right of ``x + 1`` is at most ``q`` (unique): ``x1 = x + s``, ``s`` where the run's
    local polynomial through its samples takes ``q`` (:func:`run_position`: the cubic through
    ``u1(x - 1) .. u1(x + 2)`` inside a monotone run, linear at its ends) (``x1_out``), the
    polynomial's slope there (``slope_out``, projector units per px) and the normalized disparity
    ``x1 inv_f - offset - x0n[j]`` (``d_out``), all (n, W0) float32, NaN where not matched.
    ``scratch``: (:data:`MATCH_SCRATCH_ROWS`, max(W0, W1)) float64.

    What :func:`match_pixels` needs of each row is kept (float32, exact: decoded values or
    infinities): ``rows0_out`` (n, 2, W0) camera 0's running maximum of its cleaned row (of the
    decoded values up to each column, ``-inf`` before the first) and suffix minimum;
    ``rows1_out`` (n, 2, W1) camera 1's cleaned row and its suffix minimum.

    A row's walk collects its segments first and solves them afterwards in one loop
    (:func:`run_positions`): solved one by one between the walk's steps, they took two thirds of the
    kernel's time."""
    n, w0 = u0.shape
    w1 = u1.shape[1]
    inf = np.inf
    row0, row1, rmin0, rmin1 = scratch[0], scratch[1], scratch[2], scratch[3]
    # the segments of a row: camera-0 column, camera-1 column p, u1(p - 1 .. p + 2), q; s and slope
    at0, at1, before, a, b, after, value = (
        scratch[4],
        scratch[5],
        scratch[6],
        scratch[7],
        scratch[8],
        scratch[9],
        scratch[10],
    )
    s, slope = scratch[11], scratch[12]
    for r in range(n):
        clean_row(u0[r], lo, hi, row0)
        clean_row(u1[r], lo, hi, row1)
        suffix_min(row1, w1, rmin1)
        suffix_min(row0, w0, rmin0)
        max0 = rows0_out[r, 0]
        rows0_out[r, 1] = rmin0[:w0]
        rows1_out[r, 0] = row1[:w1]
        rows1_out[r, 1] = rmin1[:w1]
        x1_out[r] = np.nan
        slope_out[r] = np.nan
        d_out[r] = np.nan
        left = -inf  # the maximum decoded camera-0 value left of j
        p = -1  # the last column of camera 1 whose running maximum is at most q
        key = -inf  # camera 1's running maximum up to p (lo for undecoded values)
        found = 0
        for j in range(w0):
            q = row0[j]
            if math.isnan(q):
                max0[j] = left
                continue
            record = q > left and (j + 1 >= w0 or q < rmin0[j + 1])
            left = max(left, q)
            max0[j] = left
            if not record:
                continue
            while p + 1 < w1:
                nxt = row1[p + 1]
                candidate = max(key, lo if math.isnan(nxt) else nxt)
                if candidate > q:
                    break
                key = candidate
                p += 1
            # _segment_position's rules, the position left for run_positions
            if p < 0 or p > w1 - 2:
                continue
            beyond = rmin1[p + 2] if p + 2 < w1 else inf
            if not (row1[p] <= q and q < row1[p + 1] and beyond > q):
                continue
            at0[found] = j
            at1[found] = p
            before[found] = row1[p - 1] if p >= 1 else np.nan
            a[found] = row1[p]
            b[found] = row1[p + 1]
            after[found] = row1[p + 2] if p + 2 < w1 else np.nan
            value[found] = q
            found += 1
        run_positions(before, a, b, after, value, found, s, slope)
        for k in range(found):
            j = int(at0[k])
            x1 = at1[k] + s[k]
            x1_out[r, j] = x1
            slope_out[r, j] = slope[k]
            d_out[r, j] = x1 * inv_f - offset - x0n[j]


@njit(nogil=True, cache=True)
def row_steps(u: np.ndarray, stride: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """Of the steps ``u[r, j + 1] - u[r, j]`` (float32, as ``np.diff``) of every ``stride``-th row of the
    ``(n, m)`` float32 ``u``: how many are negative and how many finite."""
    falling = 0
    finite = 0
    n, m = u.shape
    for r in range(0, n, stride):
        for j in range(m - 1):
            step = u[r, j + 1] - u[r, j]
            if math.isfinite(step):
                finite += 1
                falling += step < 0
    return falling, finite


@njit(nogil=True, cache=True)
def depth_tile(
    d: np.ndarray,
    k: np.ndarray,
    xn: np.ndarray,
    yn: np.ndarray,
    points: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Points on camera 0's rays from the normalized disparity ``d`` (n, m) float32: camera-0 depth
    ``t = k / d`` (``k`` (n, m) float32 mm), the point ``t (x_n, y_n, 1)`` into ``points`` (n, m, 3)
    float32 mm; NaN where ``t`` is not positive or ``d`` is NaN."""
    n, m = d.shape
    for r in range(n):
        for c in range(m):
            t = np.float64(k[r, c]) / np.float64(d[r, c]) if d[r, c] != 0 else np.nan
            if not t > 0:
                t = np.nan
            points[r, c, 0] = t * xn[r, c]
            points[r, c, 1] = t * yn[r, c]
            points[r, c, 2] = t


@njit(nogil=True, cache=True)
def camera1_depth(
    xp: float, d: float, x_r: float, y_r: float, w: float, plane: np.ndarray
) -> float:  # pragma: no cover - compiled
    """Camera 1 - projector depth on camera 0's ray (mm; :mod:`~metrology.core.geometry.stereo_fusion`):
    camera 1's ray ``Y(Z) = (Z (x_r + d) - b, Z y_r, Z)`` (camera 0's rectified frame) meets the light
    plane ``m . Y + n . T_p = 0``, ``m = g_i - x_p g_z``, ``n . T_p = T_i - x_p T_z``, at ``Z = (b m_x - n .
    T_p) / (m . (x_r + d, y_r, 1))``; the point's foot on ``a = (x_r, y_r, 1)`` is ``(Y . a) / (a . a)``,
    over ``w`` camera 0's depth. ``plane``: ``(b, g_i[0..2], g_z[0..2], T_i, T_z)`` float64. NaN unless
    positive."""
    b = plane[0]
    m0 = plane[1] - xp * plane[4]
    m1 = plane[2] - xp * plane[5]
    m2 = plane[3] - xp * plane[6]
    nT = plane[7] - xp * plane[8]
    x1 = x_r + d
    den = m0 * x1 + m1 * y_r + m2
    if den == 0.0 or math.isnan(den):
        return np.nan
    Z = (b * m0 - nT) / den
    t = ((Z * x1 - b) * x_r + Z * y_r * y_r + Z) / (x_r * x_r + y_r * y_r + 1.0) / w
    return t if t > 0 else np.nan


@njit(nogil=True, cache=True)
def camera1_depth_tile(
    xp: np.ndarray, d: np.ndarray, x_r: np.ndarray, y_r: np.ndarray, w: np.ndarray, plane: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """:func:`camera1_depth` of every pixel of the ``(n, m)`` float64 arrays into ``out``."""
    n, m = xp.shape
    for r in range(n):
        for c in range(m):
            out[r, c] = camera1_depth(xp[r, c], d[r, c], x_r[r, c], y_r[r, c], w[r, c], plane)


@njit(nogil=True, cache=True)
def _projector_coordinate(p: np.ndarray, r: int, c: int, projector: np.ndarray) -> float:  # pragma: no cover
    """The undistorted normalized projector coordinate ``(R_p P + T_p)_i / (R_p P + T_p)_z`` of the
    float32 point ``p[r, c]``; ``projector``: ``(R_p[i], T_i, R_p[2], T_z)`` (8 float64)."""
    x, y, z = np.float64(p[r, c, 0]), np.float64(p[r, c, 1]), np.float64(p[r, c, 2])
    coded = projector[0] * x + projector[1] * y + projector[2] * z + projector[3]
    depth = projector[4] * x + projector[5] * y + projector[6] * z + projector[7]
    return coded / depth


@njit(nogil=True, cache=True)
def fuse_tile(
    d: np.ndarray,
    p0: np.ndarray,
    p0h: np.ndarray,
    sigma0: np.ndarray,
    sigma_d: np.ndarray,
    shared: np.ndarray,
    k: np.ndarray,
    x_r: np.ndarray,
    y_r: np.ndarray,
    w: np.ndarray,
    plane: np.ndarray,
    projector: np.ndarray,
    steps: np.ndarray,
    t_out: np.ndarray,
    sigma_out: np.ndarray,
    pairs_out: np.ndarray,
    t01_out: np.ndarray,
    t1p_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The fusion of :mod:`~metrology.core.geometry.stereo_fusion` (its docstring's equations) for a
    tile of camera 0's pixels, ``(n, m)`` each: ``d`` the normalized disparity, ``p0``/``p0h`` the camera
    0 - projector points (float32 ``(n, m, 3)``) at ``q`` and ``q + h``, ``sigma0``, ``sigma_d``, ``shared``
    (``c / (s f)``), ``k``, camera 0's rectified ``x_r, y_r, w``; ``plane`` as :func:`camera1_depth`,
    ``projector`` as :func:`_projector_coordinate`, ``steps`` ``(h, h_d)``. Writes the fused depth and
    sigma (mm), the pairs bits (1, 2, 4), ``t_01`` and ``t_1p`` (NaN where not measured)."""
    n, m = d.shape
    h, hd = steps[0], steps[1]
    for r in range(n):
        for c in range(m):
            dd = np.float64(d[r, c])
            t01 = k[r, c] / dd if dd != 0 else np.nan
            if not t01 > 0:
                t01 = np.nan
            t0p = float(p0[r, c, 2])
            if not t0p > 0:
                t0p = np.nan
            xp = _projector_coordinate(p0, r, c, projector)
            xph = _projector_coordinate(p0h, r, c, projector)
            a0p = (np.float64(p0h[r, c, 2]) - t0p) / h
            xr, yr, ww = x_r[r, c], y_r[r, c], w[r, c]
            t1p = camera1_depth(xp, dd, xr, yr, ww, plane)
            a1p = (camera1_depth(xph, dd, xr, yr, ww, plane) - t1p) / h
            b1p = (camera1_depth(xp, dd + hd, xr, yr, ww, plane) - t1p) / hd
            has1p = not (math.isnan(t1p) or math.isnan(a1p) or math.isnan(b1p))
            s0 = np.float64(sigma0[r, c])
            sd = np.float64(sigma_d[r, c])
            t01_out[r, c] = t01
            t1p_out[r, c] = t1p if has1p else np.nan
            fused = np.nan
            sigma_f = np.nan
            if not (math.isnan(t01) or math.isnan(t0p)):
                b01 = -t01 / dd
                vq = s0 * s0
                vd = sd * sd
                cqd = np.float64(shared[r, c]) * vq
                gq = 1.0 / a0p
                gd = 1.0 / b01
                det = vq * vd - cqd * cqd
                iq = (vd * gq - cqd * gd) / det
                idd = (vq * gd - cqd * gq) / det
                info = gq * iq + gd * idd
                zq = iq / info
                zd = idd / info
                a1 = a1p if has1p else 0.0
                b1 = b1p if has1p else 0.0
                jqq = a0p * a0p + a1 * a1
                jqd = a1 * b1
                jdd = b01 * b01 + b1 * b1
                jdet = jqq * jdd - jqd * jqd
                yq = (jdd * zq - jqd * zd) / jdet
                yd = (jqq * zd - jqd * zq) / jdet
                w01 = b01 * yd
                w0p = a0p * yq
                w1p = a1 * yq + b1 * yd
                fused = (w01 * t01 + w0p * t0p + (w1p * t1p if has1p else 0.0)) / (w01 + w0p + w1p)
                sigma_f = 1.0 / math.sqrt(info) if info > 0 else np.nan
            if not (math.isnan(fused) or math.isnan(sigma_f)):
                t_out[r, c] = fused
                sigma_out[r, c] = sigma_f
                pairs_out[r, c] = 7 if has1p else 3
            elif math.isnan(t01) and not math.isnan(t0p):
                t_out[r, c] = t0p
                sigma_out[r, c] = abs(a0p) * s0
                pairs_out[r, c] = 2
            elif not math.isnan(t01):
                t_out[r, c] = t01
                sigma_out[r, c] = abs(t01 / dd) * sd
                pairs_out[r, c] = 1
            else:
                t_out[r, c] = np.nan
                sigma_out[r, c] = np.nan
                pairs_out[r, c] = 0


@njit(nogil=True, cache=True)
def direct_candidates(
    u0: np.ndarray,
    out: np.ndarray,
    corner: np.ndarray,
    width: int,
    u0r: np.ndarray,
    disparity: np.ndarray,
    index_out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The camera-0 pixels to match directly (:meth:`PreparedStereo._match_direct
    <metrology.core.geometry.stereo_match.PreparedStereo._match_direct>`), in one pass: sets ``out``
    (the disparity sampled back, (H W,) float32) NaN where camera 0's ``u0`` ((H W,) float32) is NaN,
    and writes to ``index_out`` ((H W,) intp) the flat indices of the decoded pixels left NaN in
    ``out`` whose four rectified samples (top-left flat index ``corner`` (H W,) int32 in the
    rectified grid of ``width`` columns) include one camera 0 did not decode (``u0r`` NaN) or one
    camera 1 matched (``disparity`` finite; both flat rectified maps, float32), in increasing
    order. Returns how many."""
    found = 0
    for k in range(u0.shape[0]):
        if math.isnan(u0[k]):
            out[k] = np.nan
            continue
        if not math.isnan(out[k]):
            continue
        c = np.intp(corner[k])
        lacking = False
        for at in (c, c + 1, c + width, c + width + 1):
            lacking = lacking or math.isnan(u0r[at]) or math.isfinite(disparity[at])
        if lacking:
            index_out[found] = k
            found += 1
    return found


@njit(nogil=True, cache=True)
def _prefix_max(row: np.ndarray, w: int, lo: float, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[c]`` = the maximum of ``row[:c + 1]`` counting a NaN as ``lo`` (the key of
    :func:`match_tile`'s merge walk)."""
    high = -np.inf
    for c in range(w):
        v = row[c]
        high = max(high, lo if math.isnan(v) else v)
        out[c] = high


@njit(nogil=True, cache=True)
def _match_in_row(
    q: float,
    x0: float,
    max0: np.ndarray,
    min0: np.ndarray,
    row1: np.ndarray,
    key1: np.ndarray,
    min1: np.ndarray,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """Camera 1's column ``x1`` and slope where one rectified row (cleaned ``row1``, its merge keys
    ``key1`` and suffix minimum ``min1``) takes ``q``, for a camera-0 value at rectified column
    ``x0`` of the same row (its cleaned values' running maximum ``max0`` and suffix minimum ``min0``):
    :func:`match_tile`'s rules (a record of camera 0's row: above every decoded value left of
    ``x0``, below every one right of it; the segment ``u1(x) <= q < u1(x + 1)`` unique in camera 1's
    row; :func:`run_position`). NaN, NaN where not matched."""
    w0 = max0.shape[0]
    w1 = row1.shape[0]
    left = math.ceil(x0) - 1  # the last column strictly left of x0
    right = math.floor(x0) + 1  # the first column strictly right of it
    if left >= 0 and not q > max0[min(left, w0 - 1)]:
        return np.nan, np.nan
    if right <= w0 - 1 and not q < min0[max(right, 0)]:
        return np.nan, np.nan
    # p: the last column whose merge key is at most q (keys do not decrease)
    low, high = 0, w1
    while low < high:
        mid = (low + high) // 2
        if key1[mid] <= q:
            low = mid + 1
        else:
            high = mid
    return _segment_position(row1, min1, w1, low - 1, q)


@njit(nogil=True, cache=True)
def match_pixels(
    rows0: np.ndarray,
    rows1: np.ndarray,
    lo: float,
    hi: float,
    q: np.ndarray,
    x0: np.ndarray,
    y0: np.ndarray,
    x0n: np.ndarray,
    inv_f: float,
    offset: float,
    x1_out: np.ndarray,
    slope_out: np.ndarray,
    d_out: np.ndarray,
    rows_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Match camera-0 pixels directly, without resampling camera 0: each pixel's own decoded value
    ``q`` ((n,) float64, the coordinate growing along the rows) at its rectified position ``(x0,
    y0)`` ((n,) float64 rectified px, sorted by ``floor(y0)``) is matched in the two rectified rows
    ``r = floor(y0)`` and ``r + 1`` of camera 1's rectified map (camera 0's for the left-right
    consistency) by :func:`_match_in_row`, from what :func:`match_tile` kept of each row (``rows0``
    (rows, 2, W0), ``rows1`` (rows, 2, W1) float32: its ``rows0_out``, ``rows1_out``), and camera
    1's column at the pixel's own epipolar line ``y0`` is interpolated between the rows, ``x1 = (1 -
    w) x1_r + w x1_(r+1)``, ``w = y0 - r`` (the line of equal ``q`` in camera 1's rectified image:
    exact for a plane lit by a pinhole projector); so is the slope. ``x1_out``, ``slope_out`` and the
    normalized disparity ``d = x1 inv_f - offset - x0n`` ((n,) float32), and the columns on rows
    ``r`` and ``r + 1`` (``rows_out``, (n, 2) float64); NaN
    where either row does not match or ``y0`` is outside the grid's rows."""
    n = q.shape[0]
    rows = rows0.shape[0]
    w1 = rows1.shape[2]
    key1 = np.empty(w1)
    found = np.full((2, n), np.nan)  # x1 on rows r and r + 1
    slopes = np.full((2, n), np.nan)
    first = 0  # the pixels [first, i) have r = rho - 1, [i, j) r = rho: each row is prepared once
    i = 0
    top = min(max(math.floor(y0[0]), 0), rows - 2) if n else 0
    bottom = min(max(math.floor(y0[n - 1]), 0), rows - 2) + 2 if n else 0
    for rho in range(top, bottom):
        j = i
        while j < n and min(max(math.floor(y0[j]), 0), rows - 2) == rho:
            j += 1
        if j > first:
            max0, min0 = rows0[rho, 0], rows0[rho, 1]
            row1, min1 = rows1[rho, 0], rows1[rho, 1]
            _prefix_max(row1, w1, lo, key1)
            for k in range(first, j):
                second = 1 if k < i else 0
                if q[k] >= lo and q[k] <= hi and (second == 0 or not math.isnan(found[0, k])):
                    found[second, k], slopes[second, k] = _match_in_row(q[k], x0[k], max0, min0, row1, key1, min1)
        first, i = i, j
    for i in range(n):
        r = min(max(math.floor(y0[i]), 0), rows - 2)
        w = y0[i] - r
        x = (1.0 - w) * found[0, i] + w * found[1, i] if w >= 0.0 and w <= 1.0 else np.nan
        x1_out[i] = x
        slope_out[i] = (1.0 - w) * slopes[0, i] + w * slopes[1, i]
        d_out[i] = x * inv_f - offset - x0n[i]
        rows_out[i, 0] = found[0, i]
        rows_out[i, 1] = found[1, i]
