"""The compiled kernel of the fused gcps-v1 path (numba, ``nogil``): decoding (Eqs. 1-3) and the
closed-form heights (Eqs. 14, 16, 17) of an 8-bit tile in one pass over its eleven frames, with no
temporaries (issue 22 item 4).

:func:`~metrology.core.decode.decode_rows` takes about thirty numpy and OpenCV passes over a tile,
each writing a float32 or bool temporary; :func:`gcps_v1_rows` reads each pixel's eleven bytes once
and writes only the outputs asked for. It computes the same numbers, bit for bit on this kind of
processor (``tests/core/test_decode_kernels.py`` compares the two on every 8-bit pair of
differences):

- the phase ``Phi = atan2(I1 - I3, I0 - I2)`` in ``[0, 2 pi)`` is read from a table over the
  511 x 511 integer differences (:func:`phase_tables`), filled by the very OpenCV call the numpy
  path makes (``cv2.cartToPolar``); the quadrant index ``floor((2/pi) Phi)`` (``cv2.convertScaleAbs``
  there) is a step function of that phase, its steps found on the table;
- dPhi of Eq. 3 and the binary word are computed (:func:`dphi_codes`, :func:`binary_word`), equal to
  :mod:`metrology.core.decode`'s tables entry for entry;
- the modulation ``B = sqrt(s^2 + c^2)`` is float32, correctly rounded (as ``cartToPolar``'s);
- ``l - l^ = K + (2/pi) Phi`` is rounded once to float32 from the exact float64 product and
  sum (as ``cv2.scaleAdd``'s fused multiply-add), the other float32 operations in numpy's order.

Per pixel the kernel makes one table look-up (the phase: 1 MB, in L2), the rest vectorises (the
integer part in 8 to 32 bits, the float part in float32, 16 lanes with AVX-512). Compiled on first
use and cached on disk (``cache=True``: a new process loads the machine code instead of compiling it).
This module imports numba (0.3-0.65 s in a fresh process): :func:`metrology.core.decode.use_compiled`
decides when it is worth it.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numba import njit

PHASE_SIDE = 511
"""Rows and columns of the phase table: the differences ``-255..255``."""


@functools.lru_cache(maxsize=1)
def phase_tables() -> tuple[np.ndarray, np.ndarray]:
    """``(phase, quadrant_bounds)``: ``(511 * 511,)`` float32 ``Phi`` in rad (``cv2.cartToPolar``,
    [0, 2 pi]) at flat index ``(s + 255) * 511 + (c + 255)`` for ``s = I1 - I3``, ``c = I0 - I2``;
    and ``(4,)`` float32 bounds ``b_1 <= ... <= b_4`` (inf where no phase reaches the quadrant) such
    that the quadrant index ``floor((2/pi) Phi)``, as :func:`~metrology.core.decode.decode_rows` rounds
    it (``cv2.convertScaleAbs(Phi, 2/pi, -0.5)``, 0..4), is the number of bounds ``<= Phi`` for every
    phase of the table (it is non-decreasing in ``Phi``; checked here, on all 261,121 entries)."""
    diffs = np.arange(-255, 256, dtype=np.float32)
    s, c = np.meshgrid(diffs, diffs, indexing="ij")
    _, phase = cv2.cartToPolar(c, s)
    quadrant = cv2.convertScaleAbs(phase, alpha=2 / np.pi, beta=-0.5)  # decode.py's rounding
    phase, quadrant = phase.reshape(-1), quadrant.reshape(-1)
    bounds = np.array(
        [phase[quadrant >= q].min() if (quadrant >= q).any() else np.inf for q in range(1, 5)], np.float32
    )
    counted = (phase[:, None] >= bounds[None, :]).sum(axis=1)
    if not np.array_equal(counted, quadrant):  # pragma: no cover - a rounding that is not monotonic
        raise RuntimeError("the quadrant of cv2.convertScaleAbs is not a step function of the phase")
    phase.setflags(write=False)
    bounds.setflags(write=False)
    return phase, bounds


@functools.lru_cache(maxsize=16)
def min_square(min_modulation: float) -> np.int32:
    """The least ``n = s^2 + c^2`` (``0 .. 2 * 255^2``) whose modulation ``B = sqrt(n)``, float32 as the
    numpy kernel computes it, reaches ``float32(min_modulation)`` (``2 * 255^2 + 1`` if none): for the
    integer differences of 8-bit frames ``B >= min_modulation`` is ``n >= min_square`` (a correctly
    rounded square root does not decrease with ``n``), one integer comparison per pixel."""
    n = np.arange(2 * 255**2 + 1, dtype=np.float32)
    reached = np.sqrt(n) >= np.float32(min_modulation)
    return np.int32(np.argmax(reached) if reached.any() else n.size)


@njit(inline="always")
def binary_word(gray: np.int32) -> np.int32:  # pragma: no cover - compiled
    """The binary word ``l^`` of a 7-bit gray word: the prefix XOR of its bits, MSB first
    (:func:`~metrology.core.patterns.binary_from_gray`)."""
    b = gray ^ (gray >> 1)
    b ^= b >> 2
    return b ^ (b >> 4)


@njit(inline="always")
def dphi_codes(quadrant: np.int32, row: np.int32) -> np.float64:  # pragma: no cover - compiled
    """dPhi of Eq. 3 in code units for the quadrant index ``q = floor((2/pi) Phi)`` (0..4) and
    ``r = l^ mod 4``: :mod:`metrology.core.decode`'s table (``_K_LUT``, from :data:`DPHI_TABLE`) in closed
    form, ``e - q`` with ``e = ((q - r + 1) mod 4) - 1``, the quadrant's offset from the one the gray
    word predicts (-1, 0 or 1: ``l - l^ = e + (2/pi) Phi - q``); NaN for ``e = 2``, the opposite
    quadrant."""
    e = ((quadrant - row + 1) & 3) - 1
    return np.float64(e - quadrant) if e != 2 else np.float64(np.nan)


@njit(inline="always")
def _row_integers(
    stack: np.ndarray,
    r: int,
    flat: np.ndarray,
    words: np.ndarray,
    binary: np.ndarray,
    squares: np.ndarray,
    totals: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The integer part of row ``r`` of an (11, H, W) uint8 stack into (W,) buffers: the phase
    table's index ``flat`` (uint32), the gray word and its binary word ``l^`` (int32), ``s^2 + c^2``
    and ``4A`` (int32). Bit ``k`` is ``G_k > floor(4A / 4)``, compared in 8 bits."""
    for x in range(stack.shape[2]):
        p0 = np.uint16(stack[7, r, x])
        p1 = np.uint16(stack[8, r, x])
        p2 = np.uint16(stack[9, r, x])
        p3 = np.uint16(stack[10, r, x])
        total = np.uint16(p0 + p1 + p2 + p3)
        threshold = np.uint8(total >> np.uint16(2))
        gray = np.uint8(0)
        for k in range(7):
            gray = np.uint8((gray << np.uint8(1)) | np.uint8(stack[k, r, x] > threshold))
        s = np.int32(p1) - np.int32(p3)
        c = np.int32(p0) - np.int32(p2)
        flat[x] = np.uint32((s + 255) * 511 + (c + 255))
        words[x] = np.int32(gray)
        binary[x] = binary_word(np.int32(gray))
        squares[x] = s * s + c * c
        totals[x] = np.int32(total)


@njit(inline="always")
def _fraction(phase: np.float32, word: np.int32, bounds: np.ndarray) -> np.float32:  # pragma: no cover - compiled
    """``l - l^ = K + (2/pi) Phi`` (Eq. 3), float32, NaN where gray and phase disagree: the quadrant
    counted on ``bounds`` (:func:`phase_tables`), ``K`` by :func:`dphi_codes`, one rounding of the
    exact float64 product and sum (as ``cv2.scaleAdd``'s fused multiply-add)."""
    quadrant = (
        np.int32(phase >= bounds[0])
        + np.int32(phase >= bounds[1])
        + np.int32(phase >= bounds[2])
        + np.int32(phase >= bounds[3])
    )
    alpha = np.float64(np.float32(2.0 / math.pi))
    return np.float32(dphi_codes(quadrant, word & 3) + np.float64(phase) * alpha)


@njit(nogil=True, cache=True, error_model="numpy")
def gcps_v1_rows(
    stack: np.ndarray,
    row_start: int,
    row_stop: int,
    phase_lut: np.ndarray,
    quadrant_bounds: np.ndarray,
    min_square: np.int32,
    max_offset: np.float32,
    half_nlp: np.float32,
    max_centred: np.float32,
    codes_out: np.ndarray,
    gray_lut: np.ndarray,
    gray_out: np.ndarray,
    want_gray: bool,
    visibility_out: np.ndarray,
    want_visibility: bool,
    ref_codes: np.ndarray,
    slope_mm: np.ndarray,
    q: np.float32,
    d_mm: np.float32,
    L_mm: np.float32,
    z_out: np.ndarray,
    want_heights: bool,
) -> None:  # pragma: no cover - compiled
    """Decode the rows ``row_start:row_stop`` of an 8-bit gcps-v1 stack; optionally their heights.

    ``stack``: (11, H, W) uint8, C-contiguous, in :data:`~metrology.core.patterns.PATTERN_NAMES`
    order (seven gray-code frames MSB first, four phase frames); ``phase_lut``, ``quadrant_bounds``:
    :func:`phase_tables`; ``min_square``: :func:`min_square` of ``min_modulation``; ``gray_lut``
    (256,) float32 gray-code-only code by gray word (the table of :mod:`metrology.core.decode`).
    The outputs are (H, W) float32, C-contiguous; only their rows ``row_start:row_stop`` are
    written.

    Per pixel: ``4A = I0 + I1 + I2 + I3``, bit ``k`` is ``G_k > floor(4A / 4)``; ``l = l^ + K +
    (2/pi) Phi`` (Eq. 3, ``K``: :func:`dphi_codes`), valid where ``|l - l^ - 0.5| <= max_offset``
    (0.5 + consistency), ``B >= min_modulation`` and ``|l - half_nlp| <= max_centred``;
    ``codes_out``: ``l``, NaN where invalid. ``gray_out``: ``gray_lut[word]``, NaN where ``B`` is
    below ``min_modulation``; ``visibility_out``: ``B / 4A``. With ``want_heights``, ``z_out`` mm:
    ``D = slope (l - r) / (1 + q l)``, ``z = L D / (d + D)`` against ``ref_codes`` ``r`` and
    ``slope_mm`` ((H, W) float32).

    Each row takes three loops over small row buffers: the integer part (sums, the gray and binary
    words, the table index; vectorised, in 8 and 32 bits), the phase look-up (the one gather), then
    the float part (the quadrant, ``K``, the code, its tests and the heights; vectorised).
    """
    width = stack.shape[2]
    one = np.float32(1.0)
    half = np.float32(0.5)
    nan = np.float32(np.nan)
    flat = np.empty(width, np.uint32)
    words = np.empty(width, np.int32)
    binary = np.empty(width, np.int32)
    squares = np.empty(width, np.int32)
    totals = np.empty(width, np.int32)
    phases = np.empty(width, np.float32)
    for r in range(row_start, row_stop):
        _row_integers(stack, r, flat, words, binary, squares, totals)
        for x in range(width):
            phases[x] = phase_lut[flat[x]]
        for x in range(width):
            word = binary[x]
            fraction = _fraction(phases[x], word, quadrant_bounds)
            l = np.float32(word) + fraction
            valid = (
                (squares[x] >= min_square) & (abs(fraction - half) <= max_offset) & (abs(l - half_nlp) <= max_centred)
            )
            l = l if valid else nan
            codes_out[r, x] = l
            if want_heights:
                den = l * q + one
                num = (l - ref_codes[r, x]) * slope_mm[r, x]
                num = num / den  # D_R, mm
                den = num + d_mm
                z_out[r, x] = (num * L_mm) / den
        if want_gray:
            for x in range(width):
                gray_out[r, x] = gray_lut[words[x]] if squares[x] >= min_square else nan
        if want_visibility:
            for x in range(width):
                visibility_out[r, x] = np.float32(math.sqrt(np.float32(squares[x]))) / np.float32(totals[x])


@njit(nogil=True, cache=True, error_model="numpy")
def gcps_v1_sample(
    stack: np.ndarray,
    rows: np.ndarray,
    phase_lut: np.ndarray,
    quadrant_bounds: np.ndarray,
    fraction_out: np.ndarray,
    word_out: np.ndarray,
    modulation_out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """What the codec self-check reads (:func:`~metrology.core.measure.check_gcps_v1_sample`) on the
    rows ``rows`` ((n,) intp) of an 8-bit gcps-v1 stack (as :func:`gcps_v1_rows`), as
    :func:`~metrology.core.decode.decode_rows`' ``fraction_out``, ``word_out`` and
    ``modulation_out`` ((n, W) float32): ``l - l^`` before any validity test (NaN where gray and
    phase disagree), the binary word ``l^`` and ``B``."""
    width = stack.shape[2]
    flat = np.empty(width, np.uint32)
    words = np.empty(width, np.int32)
    binary = np.empty(width, np.int32)
    squares = np.empty(width, np.int32)
    totals = np.empty(width, np.int32)
    for i in range(rows.size):
        _row_integers(stack, rows[i], flat, words, binary, squares, totals)
        for x in range(width):
            word = binary[x]
            fraction_out[i, x] = _fraction(phase_lut[flat[x]], word, quadrant_bounds)
            word_out[i, x] = np.float32(word)
            modulation_out[i, x] = np.float32(math.sqrt(np.float32(squares[x])))


def warm() -> None:
    """Load (or compile) the kernel now, on empty arrays of the types the tiles pass, and fill the
    phase tables: the first call otherwise costs a few tenths of a second in the first frame."""
    stack, f32 = np.zeros((11, 1, 1), np.uint8), np.zeros((1, 1), np.float32)
    phase_lut, quadrant_bounds = phase_tables()
    lut_f32 = np.zeros(256, np.float32)
    z = np.float32(0)
    gcps_v1_sample(stack, np.zeros(0, np.intp), phase_lut, quadrant_bounds, f32, f32, f32)
    gcps_v1_rows(
        stack, 0, 0, phase_lut, quadrant_bounds,
        np.int32(0), z, z, z, f32, lut_f32, f32, False, f32, False, f32, f32, z, z, z, f32, False,
    )  # fmt: skip


__all__ = [
    "PHASE_SIDE",
    "binary_word",
    "dphi_codes",
    "gcps_v1_rows",
    "gcps_v1_sample",
    "min_square",
    "phase_tables",
    "warm",
]
