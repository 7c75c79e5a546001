"""Compiled kernels of the virtual rig's hot loops (numba, ``nogil``), each giving the float64
bits of the numpy passes it replaces (but :func:`sine_intensity`, to rounding) (``tests/core/test_render_kernels.py``):

- :func:`plane_hits`: the first hit of camera rays that meet only the scene's reference plane
  (their trace misses every footprint box, where the height is 0): the march of
  :func:`metrology.core.simulate.cast.cast_truth` found in closed form, then the float its 60
  bisections end with (the first float below the plane, found by ulp steps from the crossing);
- :func:`interp_uniform`: ``np.interp`` on a uniform grid ``lo + j * step``, its cell found by
  index arithmetic instead of a binary search, with numpy's arithmetic for the value;
- :func:`lit_intensity`: a codec frame's light, the ambient everywhere plus the projector's where
  lit, in one pass without the temporaries of a gather and a scatter;
- :func:`sine_intensity`: the same for a sinusoidal frame, its cosine from the sequence's cos and sin
  of the step-0 phase (angle addition: one ``cos`` and one ``sin`` per sequence instead of one ``cos``
  per frame; the values agree with the direct cosine to float64 rounding, not bit for bit);
- :func:`slab_interval`: the paper rig's slab test of a ray or shadow segment against a footprint
  box (fourteen passes of numpy before);
- :func:`sample_light`: the paper rig's light per sub-ray, a blurred table interpolated at the
  codes' cells and scaled by the albedo (six passes before);
- :func:`board_pixels`: the procam virtual rig's chessboard seen by each camera sub-ray, its albedo
  and its true projector coordinates (:func:`metrology.core.procam.virtual.board_truth`: some
  thirty passes of numpy over the sub-rays before, the distortion's included).

No ``fastmath``: a fused multiply-add would change the bits. Compiled on first use and cached on
disk (``cache=True``); :func:`warm` loads them (``python -m metrology.core.compiled``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def _march_t(t_near: float, t_far: float, i: int, n_steps: int) -> float:  # pragma: no cover
    """Sample ``i`` of a march: ``t_near + (t_far - t_near) * (i / n_steps)``, as numpy computes it."""
    return t_near + (t_far - t_near) * (float(i) / float(n_steps))


@njit(nogil=True, cache=True)
def plane_hits(
    rows: np.ndarray,
    t_near: np.ndarray,
    t_far: np.ndarray,
    rate: np.ndarray,
    s_origin: float,
    n_steps: int,
    iterations: int,
    hit_t: np.ndarray,
    found: np.ndarray,
) -> None:  # pragma: no cover
    """First hits of the rays ``rows`` on the plane ``s = 0``, written into ``hit_t[rows]`` and
    ``found[rows]`` (flat float64 and bool arrays over all rays).

    The ray's height is ``g(t) = s_origin + t rate`` (``rate = ds/dt < 0``). The march samples
    ``t_i = t_near + (t_far - t_near)(i / n_steps)``, ``i = 0 .. n_steps``; the hit sample is the
    first with ``g(t_i) <= 0`` (``g`` is monotone in ``i`` in floating point too, so it is found from
    the plane's crossing ``t = -s_origin / rate`` and corrected by whole steps). No such sample: not
    found. Hit at ``i = 0``: ``t_0``. Else what ``iterations`` bisections of ``[t_(i-1), t_i]`` on
    ``g(mid) <= 0``, ``mid = 0.5 (a + b)``, end with, ``hit_t = b`` (:func:`_first_below`).
    """
    for k in range(rows.size):
        r = rows[k]
        tn = t_near[r]
        tf = t_far[r]
        slope = rate[r]
        if not math.isfinite(tn):
            found[r] = False
            continue
        guess = (-s_origin / slope - tn) / (tf - tn) * n_steps
        i = n_steps + 1
        if math.isfinite(guess):
            i = min(max(math.ceil(guess), 0), n_steps + 1)
        while i > 0 and s_origin + _march_t(tn, tf, i - 1, n_steps) * slope <= 0:
            i -= 1
        while i <= n_steps and not s_origin + _march_t(tn, tf, i, n_steps) * slope <= 0:
            i += 1
        if i > n_steps:
            found[r] = False
            continue
        found[r] = True
        b = _march_t(tn, tf, i, n_steps)
        if i > 0:
            a = _march_t(tn, tf, i - 1, n_steps)
            if a < b:
                b = _first_below(a, b, s_origin, slope, iterations)
        hit_t[r] = b


@njit(nogil=True, cache=True)
def _first_below(a: float, b: float, s_origin: float, slope: float, iterations: int) -> float:  # pragma: no cover
    """What ``iterations`` bisections of ``[a, b]`` on ``s_origin + t slope <= 0`` end with (``b``).

    The bisection stops moving once ``a`` and ``b`` are adjacent floats (``0.5 (a + b)`` is then one
    of them; before, it lies strictly between), which takes at most ``log2((b - a) / ulp)`` < 60
    halvings here, and ``g(t) = s_origin + t slope`` is monotone in floating point: so it ends at the
    smallest float ``t`` in ``(a, b]`` with ``g(t) <= 0``. That float is found from the crossing
    ``-s_origin / slope`` (off by an ulp or two) by steps of one ulp; where that takes more than 64
    steps, the bisection itself runs."""
    t = -s_origin / slope
    if not a < t < b:
        t = b
    for _ in range(64):
        if t >= b or s_origin + t * slope <= 0:
            break
        t = np.nextafter(t, math.inf)
    else:
        return _bisect_plane(a, b, s_origin, slope, iterations)
    for _ in range(64):
        p = np.nextafter(t, -math.inf)
        if not (p > a and s_origin + p * slope <= 0):
            return t
        t = p
    return _bisect_plane(a, b, s_origin, slope, iterations)


@njit(nogil=True, cache=True)
def _bisect_plane(a: float, b: float, s_origin: float, slope: float, iterations: int) -> float:  # pragma: no cover
    """``iterations`` bisections of ``[a, b]`` on ``s_origin + mid slope <= 0``, ``mid = 0.5 (a + b)``,
    stopped once ``mid`` is ``a`` or ``b`` (the bracket then stays as it is); returns ``b``."""
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        if not a < mid < b:
            break
        if s_origin + mid * slope <= 0:
            b = mid
        else:
            a = mid
    return b


@njit(nogil=True, cache=True)
def interp_uniform(
    x: np.ndarray, lo: float, step: float, table: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover
    """``out = np.interp(x, lo + np.arange(n) * step, table)`` for finite ``x`` (1-D float64 arrays,
    ``n = table.size >= 2``), bit for bit: the cell ``j`` with ``xp[j] <= x < xp[j + 1]`` (first
    guessed as ``floor((x - lo) / step)``, then moved to the grid values as numpy computes them),
    ``table[0]`` left of the grid, ``table[-1]`` from its last value on, ``table[j]`` on a grid
    value, else ``slope (x - xp[j]) + table[j]`` with ``slope = (table[j+1] - table[j]) / (xp[j+1] - xp[j])``.
    """
    n = table.size
    last = lo + float(n - 1) * step
    for k in range(x.size):
        value = x[k]
        if math.isnan(value):
            out[k] = value
            continue
        if value < lo:
            out[k] = table[0]
            continue
        if value >= last:
            out[k] = table[n - 1]
            continue
        j = min(max(int((value - lo) / step), 0), n - 2)
        while j > 0 and value < lo + float(j) * step:
            j -= 1
        while j < n - 2 and value >= lo + float(j + 1) * step:
            j += 1
        left = lo + float(j) * step
        if value == left:
            out[k] = table[j]
            continue
        right = lo + float(j + 1) * step
        slope = (table[j + 1] - table[j]) / (right - left)
        result = slope * (value - left) + table[j]
        if math.isnan(result):
            result = slope * (value - right) + table[j + 1]
            if math.isnan(result) and table[j] == table[j + 1]:
                result = table[j]
        out[k] = result


@njit(nogil=True, cache=True)
def lit_intensity(
    base: np.ndarray, index: np.ndarray, gain: np.ndarray, emitted: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover
    """A frame's light: ``out = base`` with ``out[index[k]] = base[index[k]] + gain[k] * emitted[k]``
    (flat float64; the bits of ``intensity = base.copy(); intensity[index] += gain * emitted``)."""
    out[:] = base
    for k in range(index.size):
        i = index[k]
        out[i] = base[i] + gain[k] * emitted[k]


@njit(nogil=True, cache=True)
def sine_intensity(
    base: np.ndarray,
    index: np.ndarray,
    gain: np.ndarray,
    cos_a: np.ndarray,
    sin_a: np.ndarray,
    offset: float,
    c: float,
    s: float,
    out: np.ndarray,
) -> None:  # pragma: no cover
    """A sinusoidal frame's light: ``out = base`` with ``out[index[k]] = base[index[k]] + gain[k] E_k``,
    ``E_k = offset + (c cos_a[k] - s sin_a[k])`` (flat float64): with ``c = A cos p``, ``s = A sin p``,
    ``E = offset + A cos(a + p)`` by the angle-addition formula (to float64 rounding)."""
    out[:] = base
    for k in range(index.size):
        i = index[k]
        out[i] = base[i] + gain[k] * (offset + (c * cos_a[k] - s * sin_a[k]))


@njit(nogil=True, cache=True)
def _max_nan(a: float, b: float) -> float:  # pragma: no cover
    """``np.maximum(a, b)``: NaN when either is NaN."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a >= b else b


@njit(nogil=True, cache=True)
def _min_nan(a: float, b: float) -> float:  # pragma: no cover
    """``np.minimum(a, b)``: NaN when either is NaN."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a <= b else b


@njit(nogil=True, cache=True)
def slab_interval(
    px: np.ndarray, py: np.ndarray, x0: float, x1: float, y0: float, y1: float, lo: np.ndarray, hi: np.ndarray
) -> None:  # pragma: no cover
    """The interval ``[lo, hi]`` of ``s`` where ``s (px, py)`` lies in the box ``[x0, x1] x [y0, y1]``
    (empty where ``lo > hi``), per element of the 1-D float64 ``px``, ``py``: per axis ``[a / p, b / p]``
    sorted, or every ``s`` (the box's slab holds 0) or none where ``p == 0``; ``lo`` the largest of the
    lower ends and -inf, ``hi`` the smallest of the upper ends and +inf (NaN propagated as numpy's
    ``maximum``/``minimum``)."""
    inside_x = x0 <= 0.0 and x1 >= 0.0
    inside_y = y0 <= 0.0 and y1 >= 0.0
    for k in range(px.size):
        low = -math.inf
        high = math.inf
        for axis in range(2):
            p = px[k] if axis == 0 else py[k]
            a = x0 if axis == 0 else y0
            b = x1 if axis == 0 else y1
            inside = inside_x if axis == 0 else inside_y
            if p != 0.0:
                ta = a / p
                tb = b / p
                first = _min_nan(ta, tb)
                last = _max_nan(ta, tb)
            else:
                first = -math.inf if inside else math.inf
                last = math.inf if inside else -math.inf
            low = _max_nan(low, first)
            high = _min_nan(high, last)
        lo[k] = low
        hi[k] = high


@njit(nogil=True, cache=True)
def sample_light(
    table: np.ndarray,
    below: np.ndarray,
    frac: np.ndarray,
    signal: np.ndarray,
    ambient: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover
    """The paper rig's light per ray, ``out = ambient + signal E``, with ``E`` the table linearly
    interpolated at cell ``below`` (``E = (table[below + 1] - table[below]) frac + table[below]``):
    the bits of :class:`~metrology.core.simulate.paper_rig._CodeSampler`'s passes followed by
    ``ambient + signal * E`` (flat float64, ``below`` intp)."""
    for k in range(below.size):
        j = below[k]
        base = table[j]
        emitted = (table[j + 1] - base) * frac[k] + base
        out[k] = ambient[k] + signal[k] * emitted


@njit(nogil=True, cache=True)
def board_pixels(
    t: np.ndarray,
    board_xy: np.ndarray,
    in_projector: np.ndarray,
    footprint_scale: float,
    square_mm: float,
    cols: int,
    rows: int,
    light: float,
    dark: float,
    K: np.ndarray,
    coeffs: tuple[float, ...],
    tilt: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    albedo: np.ndarray,
) -> None:  # pragma: no cover
    """The chessboard's albedo and the projector coordinates of ``N`` camera sub-rays (flat float64
    outputs ``u``, ``v``, ``albedo``), the bits of :func:`metrology.core.procam.virtual.board_truth`'s
    numpy passes.

    ``t`` ``(N,)``: each ray's distance parameter to the board's plane; ``board_xy`` ``(N, 3)``: the
    hit in the board's frame, mm (``Z`` unused); ``in_projector`` ``(N, 3)``: the hit in the
    projector's frame, mm. ``footprint_scale = f_x s``: a sub-ray covers ``|t| / (f_x s)`` mm of the
    board. Squares ``square_mm``; the printed board's squares ``c = -1..cols-1``, ``r = -1..rows-1``
    are dark where ``c + r`` is even, the albedo ``light + (dark - light) f`` with ``f`` the dark
    fraction of the sub-ray's box (:func:`~metrology.core.procam.virtual.board_truth`). ``K`` ``(3, 3)``
    and ``coeffs`` (14 floats, OpenCV's order) the projector's; ``tilt`` ``(3, 3)``: its sensor's
    tilt matrix (:func:`metrology.core.distortion.tilt_matrix`), identity when untilted (skipped).
    Rays that do not meet the plane in front of the camera (``t > 0``) and of the projector
    (``Z_p > 0``): ``u = v = NaN``."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = coeffs
    rational = k4 != 0.0 or k5 != 0.0 or k6 != 0.0
    tilted = tx != 0.0 or ty != 0.0
    for i in range(t.size):
        bx, by = board_xy[i, 0], board_xy[i, 1]
        fp = np.abs(t[i]) / footprint_scale
        k = np.rint(bx / square_mm)
        m = np.rint(by / square_mm)
        even = (k + m) % 2.0 == 0.0  # NaN: not even, as in numpy
        c0 = (k >= -1) & (k <= cols - 1)
        c1 = (k - 1 >= -1) & (k - 1 <= cols - 1)
        r0 = (m >= -1) & (m <= rows - 1)
        r1 = (m - 1 >= -1) & (m - 1 <= rows - 1)
        d00 = 1.0 if c0 and r0 and even else 0.0
        d01 = 1.0 if c0 and r1 and not even else 0.0
        d10 = 1.0 if c1 and r0 and not even else 0.0
        d11 = 1.0 if c1 and r1 and even else 0.0
        a = _clip01(0.5 + (bx - k * square_mm) / fp)
        b = _clip01(0.5 + (by - m * square_mm) / fp)
        fraction = a * b * d00 + a * (1 - b) * d01 + (1 - a) * b * d10 + (1 - a) * (1 - b) * d11
        albedo[i] = light + (dark - light) * fraction
        xp, yp, zp = in_projector[i, 0], in_projector[i, 1], in_projector[i, 2]
        if not (t[i] > 0 and zp > 0):
            u[i] = np.nan
            v[i] = np.nan
            continue
        x, y = xp / zp, yp / zp
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if rational:
            radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) + r2 * (s1 + s2 * r2)
        yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy + r2 * (s3 + s4 * r2)
        if tilted:
            w0 = tilt[0, 0] * xd + tilt[0, 1] * yd + tilt[0, 2]
            w1 = tilt[1, 0] * xd + tilt[1, 1] * yd + tilt[1, 2]
            w2 = tilt[2, 0] * xd + tilt[2, 1] * yd + tilt[2, 2]
            xd, yd = w0 / w2, w1 / w2
        u[i] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        v[i] = K[1, 1] * yd + K[1, 2]


@njit(nogil=True, cache=True)
def _clip01(x: float) -> float:  # pragma: no cover
    """``np.clip(x, 0, 1)``: NaN stays NaN."""
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


def warm() -> None:
    """Load (or compile) the kernels now, on empty arrays of the types the renderers pass."""
    e = np.empty(0, np.float64)
    plane_hits(np.empty(0, np.intp), e, e, e, 1.0, 1, 60, e, np.empty(0, np.bool_))
    interp_uniform(e, 0.0, 1.0, np.zeros(2), e)
    lit_intensity(e, np.empty(0, np.int64), e, e, e)
    sine_intensity(e, np.empty(0, np.int64), e, e, e, 0.5, 0.5, 0.0, e)
    slab_interval(e, e, 0.0, 1.0, 0.0, 1.0, e, e)
    sample_light(np.zeros(2), np.empty(0, np.intp), e, e, e, e)
    e3 = np.empty((0, 3), np.float64)
    board_pixels(e, e3, e3, 1.0, 1.0, 1, 1, 0.9, 0.08, np.eye(3), (0.0,) * 14, np.eye(3), e, e, e)
