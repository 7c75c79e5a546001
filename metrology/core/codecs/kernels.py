"""Compiled kernels of the generic decoder's 8-bit tiles (numba, ``nogil``: the tiles of
:func:`metrology.core.tiling.run_tiled` run them on the pool's threads in parallel), each giving
the bits of the numpy and OpenCV passes it replaces (``tests/core/codecs/test_kernels.py``):

- :func:`phase_sums_u8`: a phase sequence's sums (below), and the brightest of its frames;
- :func:`phase_finish`: from ``cv2.cartToPolar``'s magnitude and angle, the phase fraction, the
  fit-residual noise and the modulation (ten passes of the tile);
- :func:`saturation_u8`: the saturation check, reading only the frames that are not phase frames
  (none at all where they are the gray code's: :func:`gray_words_u8` checks them as it reads them);
- :func:`gray_words_u8`: a binary gray code's bits, word and centre in one pass over its frames
  (three passes per bit and a look-up before);
- :func:`reasons`: the reason codes and the refused pixels' NaN (seven passes before);
- :func:`jump_pixels` and :func:`repair_slips`: the slip search of every tile and the serial
  repair after them.

For an 8-bit stack, :func:`phase_sums_u8` computes in one pass over a phase sequence's frames what
took ``4 N`` OpenCV passes (``accumulate``, ``accumulateSquare`` and two ``accumulateWeighted``
per frame, each reading the frame and rewriting a float32 tile), with the same float32
arithmetic, so that both give the same bits: per pixel

    total = sum_k I_k,   Q = sum_k I_k^2                        (exact integers below 2**24)
    x_k = x_{k-1} + a_k (I_k - x_{k-1}),   x_{-1} = 0            (one fused multiply-add, float32)

for each row of running-average factors ``a`` (:func:`metrology.core.codecs.decode._recursive_alphas`:
``x_{N-1} = K C`` and ``-K S``), four frames at a time on a chunk of pixels whose sums stay in the
L1 cache. ``cv2.accumulateWeighted`` rounds ``I - x`` and the fused ``x + a (I - x)`` to float32
(on processors with FMA, which OpenCV and LLVM then both use); ``tests/core/codecs/test_kernels.py``
checks the bits against OpenCV.

This module imports numba, and its first call loads the machine code from numba's disk cache
(0.4 s and 0.4-0.9 s in a fresh process on the reference machine), so
:mod:`metrology.core.codecs.decode` uses it only where it is already loaded: a worker loads it as
it starts (:func:`metrology.jobs.handlers.preload_job_code`), and a caller that decodes many
stacks imports it and calls :func:`warm`; ``gcps decode`` and ``gcps measure``, which decode one
or two stacks, keep the OpenCV passes, which cost less than numba's start. Compiled on first use
and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

CHUNK_PX = 2048
"""Pixels whose four float32 sums (32 KiB) stay in the L1 cache while the frames pass."""


@njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"}, boundscheck=False)
def phase_sums_u8(
    frames: np.ndarray,
    start: int,
    stop: int,
    index: np.ndarray,
    alphas: np.ndarray,
    total: np.ndarray,
    c: np.ndarray,
    neg_s: np.ndarray,
    squares: np.ndarray,
    want_squares: bool,
    peak: np.ndarray,
    peak_mode: int,
) -> None:  # pragma: no cover - compiled
    """The sums of one phase sequence over the pixels ``start:stop`` of a stack (and the brightest
    of its frames, for the saturation check, while they are in the cache).

    Parameters
    ----------
    frames : (F, P) uint8
        The stack, each frame's pixels flattened (C-contiguous).
    start, stop : int
        The pixels decoded, ``0 <= start <= stop <= P``.
    index : (N,) int64
        The sequence's frames.
    alphas : (2, N) float32
        The running-average factors of ``K C`` (row 0) and ``-K S`` (row 1); 0 leaves the average
        as it is.
    total, c, neg_s : (stop - start,) float32
        Written: ``sum I_k``, ``K C``, ``-K S``, grey levels.
    squares : (stop - start,) float32
        Written with ``want_squares`` only: ``sum I_k^2``, grey levels squared.
    peak : (stop - start,) uint8
        ``peak_mode`` 1: written ``max_k I_k``; 2: ``max(peak, max_k I_k)``; 0: untouched.
    """
    n = index.size
    for c0 in range(start, stop, CHUNK_PX):
        c1 = min(c0 + CHUNK_PX, stop)
        o = c0 - start
        m = c1 - c0
        t = total[o : o + m]
        cc = c[o : o + m]
        ss = neg_s[o : o + m]
        q = squares[o : o + m] if want_squares else squares[0:0]
        for j in range(m):
            t[j] = 0.0
            cc[j] = 0.0
            ss[j] = 0.0
        if want_squares:
            for j in range(m):
                q[j] = 0.0
        k = 0
        while k < n:
            if k + 4 <= n:
                f0 = frames[index[k], c0:c1]
                f1 = frames[index[k + 1], c0:c1]
                f2 = frames[index[k + 2], c0:c1]
                f3 = frames[index[k + 3], c0:c1]
                a0, a1, a2, a3 = alphas[0, k], alphas[0, k + 1], alphas[0, k + 2], alphas[0, k + 3]
                b0, b1, b2, b3 = alphas[1, k], alphas[1, k + 1], alphas[1, k + 2], alphas[1, k + 3]
                for j in range(m):
                    x0 = np.float32(f0[j])
                    x1 = np.float32(f1[j])
                    x2 = np.float32(f2[j])
                    x3 = np.float32(f3[j])
                    t[j] = (((t[j] + x0) + x1) + x2) + x3
                    u = cc[j]
                    u = u + a0 * (x0 - u)
                    u = u + a1 * (x1 - u)
                    u = u + a2 * (x2 - u)
                    cc[j] = u + a3 * (x3 - u)
                    v = ss[j]
                    v = v + b0 * (x0 - v)
                    v = v + b1 * (x1 - v)
                    v = v + b2 * (x2 - v)
                    ss[j] = v + b3 * (x3 - v)
                if want_squares:
                    for j in range(m):
                        x0 = np.float32(f0[j])
                        x1 = np.float32(f1[j])
                        x2 = np.float32(f2[j])
                        x3 = np.float32(f3[j])
                        q[j] = (((q[j] + x0 * x0) + x1 * x1) + x2 * x2) + x3 * x3
                k += 4
            else:
                f0 = frames[index[k], c0:c1]
                a0, b0 = alphas[0, k], alphas[1, k]
                for j in range(m):
                    x0 = np.float32(f0[j])
                    t[j] += x0
                    cc[j] = cc[j] + a0 * (x0 - cc[j])
                    ss[j] = ss[j] + b0 * (x0 - ss[j])
                if want_squares:
                    for j in range(m):
                        x0 = np.float32(f0[j])
                        q[j] += x0 * x0
                k += 1
        if peak_mode != 0:
            pk = peak[o : o + m]
            if peak_mode == 1:
                for j in range(m):
                    pk[j] = 0
            for k in range(n):
                f0 = frames[index[k], c0:c1]
                for j in range(m):
                    pk[j] = max(pk[j], f0[j])


@njit(nogil=True, cache=True, boundscheck=False)
def phase_finish(
    angle: np.ndarray,
    mag: np.ndarray,
    total: np.ndarray,
    squares: np.ndarray,
    want_noise: bool,
    total_scale: float,
    mag_scale: float,
    residual_scale: float,
    modulation_scale: float,
    noise: np.ndarray,
    modulation: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """What :func:`metrology.core.codecs.decode._phase_tile` computes from ``cv2.cartToPolar``'s
    magnitude and angle of an 8-bit sequence, in one pass, each step rounded to float32 as the
    OpenCV and numpy passes round it (no fused multiply-add; ``cv2.multiply`` with a scale is
    ``(scale a) b``)::

        frac = angle (1 / 2 pi)                                         (in place of angle)
        R = max(((Q - (s_t T) T) - (s_m |m|) |m|), 0) s_r,   noise = sqrt(R)   (``want_noise``)
        B = |m| s_B

    Parameters
    ----------
    angle, mag : (n,) float32
        Radians in [0, 2 pi]; ``K hypot(C, S)``.
    total, squares : (n,) float32
        ``sum I``, ``sum I^2`` (``squares`` read with ``want_noise`` only).
    total_scale, mag_scale, residual_scale, modulation_scale : float
        ``1 / N``, ``2 / (N K^2)``, ``1 / (N - 3)``, ``2 / (N K)``, rounded to float32.
    noise : (n,) float32
        Written with ``want_noise``.
    modulation : (n,) float32
        Written: B, grey levels (may be ``mag`` itself).
    """
    to_frac = np.float32(1 / (2 * np.pi))
    s_t = np.float32(total_scale)
    s_m = np.float32(mag_scale)
    s_r = np.float32(residual_scale)
    s_b = np.float32(modulation_scale)
    zero = np.float32(0.0)
    for j in range(angle.size):
        angle[j] = angle[j] * to_frac
    if want_noise:
        for j in range(angle.size):
            t = total[j]
            m = mag[j]
            r = (squares[j] - (s_t * t) * t) - (s_m * m) * m
            r = r if (r >= zero or np.isnan(r)) else zero
            noise[j] = np.sqrt(r * s_r)
    for j in range(angle.size):
        modulation[j] = mag[j] * s_b


@njit(nogil=True, cache=True, boundscheck=False)
def saturation_u8(
    frames: np.ndarray,
    start: int,
    stop: int,
    phase_peak: np.ndarray,
    other_index: np.ndarray,
    level: int,
    phase_saturated: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The saturation flags of the pixels ``start:stop`` of an 8-bit stack, in one pass over the
    frames that are not phase frames.

    Parameters
    ----------
    frames : (F, P) uint8
        The stack, each frame's pixels flattened.
    phase_peak : (stop - start,) uint8, or (0,) without phase frames
        The brightest phase frame of the chains (refused where saturated), as
        :func:`phase_sums_u8` writes it.
    other_index : (n,) int64
        The codec's other frames (flagged).
    level : int
        Saturation level, grey levels: a pixel is saturated where ``I >= level``.
    phase_saturated : (stop - start,) bool
        Written where ``phase_peak`` is not empty: ``phase_peak >= level``.

    Returns
    -------
    int
        Pixels at or above ``level`` in some frame of ``phase_index`` or ``other_index``.
    """
    count = 0
    top = np.uint8(min(max(level, 0), 255))
    peak = np.empty(CHUNK_PX, np.uint8)
    for c0 in range(start, stop, CHUNK_PX):
        c1 = min(c0 + CHUNK_PX, stop)
        m = c1 - c0
        o = c0 - start
        if phase_peak.size > 0:
            for j in range(m):
                peak[j] = phase_peak[o + j]
                phase_saturated[o + j] = peak[j] >= top
        else:
            for j in range(m):
                peak[j] = 0
        for k in range(other_index.size):
            f = frames[other_index[k], c0:c1]
            for j in range(m):
                peak[j] = max(peak[j], f[j])
        count += _count_at_least(peak, m, top)
    return count


@njit(nogil=True, cache=True, boundscheck=False)
def _count_at_least(values: np.ndarray, m: int, top: int | np.uint8) -> int:  # pragma: no cover - compiled
    """How many of ``values[:m]`` (uint8) are at least ``top``: the saturated pixels of a chunk."""
    n = np.int32(0)
    for j in range(m):
        n += np.int32(values[j] >= top)
    return int(n)


@njit(nogil=True, cache=True, boundscheck=False)
def gray_words_u8(
    frames: np.ndarray,
    start: int,
    stop: int,
    gray_index: np.ndarray,
    weights: np.ndarray,
    lut: np.ndarray,
    mode: int,
    total: np.ndarray,
    steps: int,
    threshold: np.ndarray,
    inverse_index: np.ndarray,
    min_contrast: np.ndarray,
    low_contrast: np.ndarray,
    contrast_limit: float,
    centre: np.ndarray,
    peak: np.ndarray,
    level: int,
    phase_saturated: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """A binary gray code's words and their centres on the pixels ``start:stop`` of an 8-bit stack
    (and, with ``peak``, the saturation check of :func:`saturation_u8` where the gray frames are
    all the frames that are not phase frames).

    The word is ``sum_i b_i weights_i`` with the bit ``b_i = I_{gray_i} > t`` (strictly), the
    threshold ``t`` by ``mode``: 0 the first phase sequence's mean, as ``floor(total / steps)``
    (``total`` an exact integer sum of uint8 frames: ``I > A <=> I > floor(A)``); 1 the array
    ``threshold`` (white/black); 2 the bit's inverse frame, where also
    ``min_contrast = min_i |I_gray_i - I_inverse_i|`` and ``low_contrast = min_contrast < contrast_limit``.

    Parameters
    ----------
    frames : (F, P) uint8
    gray_index, weights : (B,) int64
        The bits' frames and their words' weights ``2**position``.
    lut : (2**B,) float32
        Word -> centre, projector units.
    total : (stop - start,) float32
        Mode 0: the sum of the first phase sequence's frames.
    threshold : (stop - start,) uint8
        Mode 1.
    inverse_index : (B,) int64
        Mode 2.
    min_contrast : (stop - start,) uint8, low_contrast : (stop - start,) bool
        Written in mode 2.
    centre : (stop - start,) float32
        Written: ``lut[word]``.
    peak : (stop - start,) uint8, or (0,) for no saturation check
        The brightest phase frame; rewritten: the brightest of it and the gray (and inverse) frames.
    level : int
        Saturation level, grey levels.
    phase_saturated : (stop - start,) bool
        Written with ``peak``: ``peak >= level`` before the gray frames.

    Returns
    -------
    int
        With ``peak``: the pixels at or above ``level`` in some phase or gray frame; else 0.
    """
    limit = np.float32(contrast_limit)
    top = np.uint8(min(max(level, 0), 255))
    saturation = peak.size > 0
    count = 0
    inv_steps = 1.0 / steps
    bits = gray_index.size
    word = np.empty(CHUNK_PX, np.int32)
    thr = np.empty(CHUNK_PX, np.uint8)
    for c0 in range(start, stop, CHUNK_PX):
        c1 = min(c0 + CHUNK_PX, stop)
        m = c1 - c0
        o = c0 - start
        for j in range(m):
            word[j] = 0
        if mode == 0:
            # floor(total / steps) exactly: total <= 255 steps is an integer, and float64's rounding
            # error (< 1e-13) is far below the 1 / steps between total / steps and the next integer
            for j in range(m):
                thr[j] = np.uint8(np.floor(np.float64(total[o + j]) * inv_steps))
        elif mode == 1:
            for j in range(m):
                thr[j] = threshold[o + j]
        else:
            for j in range(m):
                min_contrast[o + j] = 255
        mc = min_contrast[o : o + m] if mode == 2 else min_contrast[0:0]
        pk = peak[o : o + m] if saturation else peak[0:0]
        if saturation:
            for j in range(m):
                phase_saturated[o + j] = pk[j] >= top
        for i in range(bits):
            f = frames[gray_index[i], c0:c1]
            if saturation:
                for j in range(m):
                    pk[j] = max(pk[j], f[j])
                if mode == 2:
                    g = frames[inverse_index[i], c0:c1]
                    for j in range(m):
                        pk[j] = max(pk[j], g[j])
            weight = np.int32(weights[i])
            if mode == 2:
                inv = frames[inverse_index[i], c0:c1]
                for j in range(m):
                    a = f[j]
                    b = inv[j]
                    word[j] += weight * np.int32(a > b)
                    mc[j] = min(mc[j], max(a, b) - min(a, b))
            else:
                for j in range(m):
                    word[j] += weight * np.int32(f[j] > thr[j])
        for j in range(m):
            centre[o + j] = lut[word[j]]
        if mode == 2:
            for j in range(m):
                low_contrast[o + j] = np.float32(min_contrast[o + j]) < limit
        if saturation:
            count += _count_at_least(pk, m, top)
    return count


@njit(nogil=True, cache=True, boundscheck=False)
def reasons(
    x: np.ndarray,
    low: float,
    high: float,
    inconsistent: np.ndarray,
    low_contrast: np.ndarray,
    saturated: np.ndarray,
    dark: np.ndarray,
    ambiguous: np.ndarray,
    reason: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The reason codes of a tile's pixels, and its coordinates set to NaN where not valid.

    The first that applies: 1 ``dark``, 2 ``saturated``, 5 ``low_contrast``, 7 ``ambiguous``,
    4 ``inconsistent``, 3 outside ``[low, high]`` (NaN included), else 0 (valid: ``x + 0``, else
    ``x + NaN``, as the numpy path writes them).

    Parameters
    ----------
    x : (n,) float32
        Coordinates, projector units; rewritten.
    low, high : float
        ``-0.5`` and ``extent - 0.5``, compared in float32.
    inconsistent, low_contrast, saturated, dark, ambiguous : (n,) bool, or (0,) for none
    reason : (n,) uint8
        Written.

    Returns
    -------
    int
        Pixels of reason 0, 3 or 4 (those the codec self-check judges).
    """
    lo = np.float32(low)
    hi = np.float32(high)
    zero = np.float32(0.0)
    nan = np.float32(np.nan)
    judged = 0
    has_i, has_l, has_s, has_d, has_a = (
        inconsistent.size > 0,
        low_contrast.size > 0,
        saturated.size > 0,
        dark.size > 0,
        ambiguous.size > 0,
    )
    n = x.size
    # the codes in reverse priority, each pass a select the compiler vectorises
    for j in range(n):
        v = x[j]
        reason[j] = np.uint8(0) if (v >= lo and v <= hi) else np.uint8(3)
    for present, mask, code in (
        (has_i, inconsistent, np.uint8(4)),
        (has_a, ambiguous, np.uint8(7)),
        (has_l, low_contrast, np.uint8(5)),
        (has_s, saturated, np.uint8(2)),
        (has_d, dark, np.uint8(1)),
    ):
        if present:
            for j in range(n):
                reason[j] = code if mask[j] else reason[j]
    for j in range(n):
        r = reason[j]
        judged += int((r == 0) | (r == 3) | (r == 4))
        x[j] = x[j] + (zero if r == 0 else nan)
    return judged


@njit(nogil=True, cache=True, boundscheck=False)
def jump_pixels(x: np.ndarray, half: float, out: np.ndarray) -> int:  # pragma: no cover - compiled
    """Flat indices of the pixels of ``x`` (h, w) float32 that differ by more than ``half`` (compared
    in float32) from a 4-neighbour (NaN never counts), written to ``out`` (h w,) intp in row-major
    order; returns how many."""
    h, w = x.shape
    t = np.float32(half)
    n = 0
    across = np.zeros(w + 1, np.bool_)  # across[j + 1]: a jump between columns j and j + 1
    above = np.zeros(w, np.bool_)  # a jump to the row above
    below = np.zeros(w, np.bool_)  # a jump to the row below
    for i in range(h):
        row = x[i]
        for j in range(w - 1):
            across[j + 1] = abs(row[j + 1] - row[j]) > t
        if i + 1 < h:
            nxt = x[i + 1]
            for j in range(w):
                below[j] = abs(nxt[j] - row[j]) > t
        else:
            below[:] = False
        any_jump = False
        for j in range(w):
            any_jump |= across[j] | across[j + 1] | above[j] | below[j]
        if any_jump:
            for j in range(w):
                if across[j] | across[j + 1] | above[j] | below[j]:
                    out[n] = i * w + j
                    n += 1
        above, below = below, above
    return n


@njit(nogil=True, cache=True, boundscheck=False)
def repair_slips(
    x: np.ndarray,
    reason: np.ndarray,
    flat: np.ndarray,
    slip_period: float,
    final_period: float,
    centre: np.ndarray,
    cell_reach: float,
    repaired: int,
) -> int:  # pragma: no cover - compiled
    """:func:`metrology.core.codecs.decode.repair_slips` on the candidates ``flat`` (sorted, unique
    flat indices into ``x``), in place, with its float32 arithmetic: per candidate the median ``m``
    of the valid coordinates of its 5x5 neighbourhood (at least 13), and where ``|x - m| > P / 2``
    the moved ``x' = x + P_f rint(P rint((m - x) / P) / P_f)``, kept (reason ``repaired``) where
    ``|x' - centre| <= cell_reach`` (``centre`` (0, 0) for no bound). The medians are all taken
    before any pixel moves.

    Parameters
    ----------
    x : (H, W) float32
        Coordinates, NaN where not valid; rewritten.
    reason : (H, W) uint8
        Rewritten where a pixel moves.
    flat : (n,) intp

    Returns
    -------
    int
        Pixels moved.
    """
    height, width = x.shape
    half = np.float32(slip_period / 2)
    p = np.float32(slip_period)
    pf = np.float32(final_period)
    reach = np.float32(cell_reach)
    bounded = centre.size > 0
    moved = np.empty(flat.size, np.float32)
    keep = np.zeros(flat.size, np.bool_)
    window = np.empty(25, np.float32)
    for k in range(flat.size):
        r = flat[k] // width
        c = flat[k] - r * width
        count = 0
        for i in range(max(r - 2, 0), min(r + 3, height)):
            for j in range(max(c - 2, 0), min(c + 3, width)):
                v = x[i, j]
                if np.isfinite(v):
                    # insertion into the sorted window
                    q = count
                    while q > 0 and window[q - 1] > v:
                        window[q] = window[q - 1]
                        q -= 1
                    window[q] = v
                    count += 1
        if count < 13:
            continue
        med = np.float32(0.5) * (window[(count - 1) // 2] + window[count // 2])
        value = x[r, c]
        if not abs(value - med) > half:
            continue
        shift = p * np.float32(np.rint(np.float32((med - value) / p)))
        snapped = pf * np.float32(np.rint(np.float32(shift / pf)))
        new = value + snapped
        if bounded and not abs(new - centre[r, c]) <= reach:
            continue
        moved[k] = new
        keep[k] = True
    n = 0
    for k in range(flat.size):
        if keep[k]:
            r = flat[k] // width
            c = flat[k] - r * width
            x[r, c] = moved[k]
            reason[r, c] = repaired
            n += 1
    return n


def warm() -> None:
    """Load (or compile) the kernel now, on empty arrays of the types the tiles pass (numba's first
    call costs a few tenths of a second; a worker or a benchmark pays it before its first decode)."""
    e = np.empty(0, np.float32)
    alphas = np.zeros((2, 1), np.float32)
    frames = np.zeros((1, 0), np.uint8)
    i = np.zeros(1, np.int64)
    b = np.zeros(0, np.bool_)
    u = np.zeros(0, np.uint8)
    phase_sums_u8(frames, 0, 0, i, alphas, e, e, e, e, False, u, 0)
    saturation_u8(frames, 0, 0, u, i, 255, b)
    phase_finish(e, e, e, e, True, 1.0, 1.0, 1.0, 1.0, e, e)
    gray_words_u8(frames, 0, 0, i, i, np.zeros(2, np.float32), 0, e, 1, u, i, u, b, 4.0, e, u, 255, b)
    reasons(e, -0.5, 0.5, b, b, b, b, b, u)
    x = np.zeros((0, 0), np.float32)
    jump_pixels(x, 0.5, np.zeros(0, np.intp))
    repair_slips(x, np.zeros((0, 0), np.uint8), np.zeros(0, np.intp), 2.0, 1.0, x, np.inf, 6)
