"""Compiled kernel of the generic decoder's phase sums (numba, ``nogil``: the tiles of
:func:`metrology.core.tiling.run_tiled` run it on the pool's threads in parallel).

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
) -> None:  # pragma: no cover - compiled
    """The sums of one phase sequence over the pixels ``start:stop`` of a stack.

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


def warm() -> None:
    """Load (or compile) the kernel now, on empty arrays of the types the tiles pass (numba's first
    call costs a few tenths of a second; a worker or a benchmark pays it before its first decode)."""
    e = np.empty(0, np.float32)
    alphas = np.zeros((2, 1), np.float32)
    phase_sums_u8(np.zeros((1, 0), np.uint8), 0, 0, np.zeros(1, np.int64), alphas, e, e, e, e, False)
