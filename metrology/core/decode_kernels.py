"""The compiled kernel of the fused gcps-v1 path (numba, ``nogil``): decoding (Eqs. 1-3) and the
closed-form heights (Eqs. 14, 16, 17) of an 8-bit tile in one pass over its eleven frames, with no
temporaries (issue 22 item 4).

:func:`~metrology.core.decode.decode_rows` takes about thirty numpy and OpenCV passes over a tile,
each writing a float32 or bool temporary; :func:`gcps_v1_rows` reads each pixel's eleven bytes once
and writes only the outputs asked for. It computes the same numbers, bit for bit on this kind of
processor (``tests/core/test_decode_kernels.py`` compares the two on every 8-bit pair of
differences):

- the phase ``Phi = atan2(I1 - I3, I0 - I2)`` in ``[0, 2 pi)`` and the quadrant index
  ``floor((2/pi) Phi)`` are read from tables over the 511 x 511 integer differences
  (:func:`phase_tables`), filled by the very OpenCV calls the numpy path makes
  (``cv2.cartToPolar``, ``cv2.convertScaleAbs``);
- the modulation ``B = sqrt(s^2 + c^2)`` is float32, correctly rounded (as ``cartToPolar``'s);
- ``l - l^ = K + (2/pi) Phi`` is rounded once to float32 from the exact float64 product and
  sum (as ``cv2.scaleAdd``'s fused multiply-add), the other float32 operations in numpy's order.

Compiled on first use and
cached on disk (``cache=True``: a new process loads the machine code instead of compiling it).
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
"""Rows and columns of the phase tables: the differences ``-255..255``."""


@functools.lru_cache(maxsize=1)
def phase_tables() -> tuple[np.ndarray, np.ndarray]:
    """``(phase, quadrant)``: ``(511 * 511,)`` float32 ``Phi`` in rad (``cv2.cartToPolar``, [0, 2 pi])
    and uint8 ``floor((2/pi) Phi)`` as :func:`~metrology.core.decode.decode_rows` rounds it
    (``cv2.convertScaleAbs(Phi, 2/pi, -0.5)``), at flat index ``(s + 255) * 511 + (c + 255)`` for
    ``s = I1 - I3``, ``c = I0 - I2``."""
    diffs = np.arange(-255, 256, dtype=np.float32)
    s, c = np.meshgrid(diffs, diffs, indexing="ij")
    _, phase = cv2.cartToPolar(c, s)
    quadrant = cv2.convertScaleAbs(phase, alpha=2 / np.pi, beta=-0.5)  # decode.py's rounding
    phase, quadrant = phase.reshape(-1), quadrant.reshape(-1)
    phase.setflags(write=False)
    quadrant.setflags(write=False)
    return phase, quadrant


@njit(nogil=True, cache=True, error_model="numpy")
def gcps_v1_rows(
    stack: np.ndarray,
    row_start: int,
    row_stop: int,
    phase_lut: np.ndarray,
    quadrant_lut: np.ndarray,
    k_lut: np.ndarray,
    row8_lut: np.ndarray,
    word_lut: np.ndarray,
    min_modulation: np.float32,
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
    order (seven gray-code frames MSB first, four phase frames); ``phase_lut``, ``quadrant_lut``:
    :func:`phase_tables`; ``k_lut`` (256,) float32 dPhi in code units by ``(l^ mod 4) * 8 +
    floor(t)``, ``row8_lut`` (256,) uint8 ``(l^ mod 4) * 8`` and ``word_lut`` (256,) float32 ``l^``
    by gray word (the tables of :mod:`metrology.core.decode`). The outputs are (H, W) float32,
    C-contiguous; only their rows ``row_start:row_stop`` are written.

    Per pixel: ``4A = I0 + I1 + I2 + I3``, bit ``k`` is ``G_k > floor(4A / 4)``; ``l = l^ + K +
    (2/pi) Phi`` (Eq. 3), valid where ``|l - l^ - 0.5| <= max_offset`` (0.5 + consistency),
    ``B >= min_modulation`` and ``|l - half_nlp| <= max_centred``; ``codes_out``: ``l``, NaN where
    invalid. ``gray_out``: ``gray_lut[word]``, NaN where ``B`` is below ``min_modulation``;
    ``visibility_out``: ``B / 4A``. With ``want_heights``, ``z_out`` mm: ``D = slope (l - r) / (1 +
    q l)``, ``z = L D / (d + D)`` against ``ref_codes`` ``r`` and ``slope_mm`` ((H, W) float32).

    Each row takes three loops over small row buffers: the integer part (sums, the gray word, the
    table index; vectorised), the table look-ups, then the float32 part (vectorised).
    """
    width = stack.shape[2]
    alpha = np.float64(np.float32(2.0 / math.pi))
    one = np.float32(1.0)
    half = np.float32(0.5)
    nan = np.float32(np.nan)
    flat = np.empty(width, np.int32)
    words = np.empty(width, np.int32)
    squares = np.empty(width, np.int32)
    totals = np.empty(width, np.int32)
    fractions = np.empty(width, np.float32)
    binary = np.empty(width, np.float32)
    for r in range(row_start, row_stop):
        for x in range(width):
            p0 = np.int32(stack[7, r, x])
            p1 = np.int32(stack[8, r, x])
            p2 = np.int32(stack[9, r, x])
            p3 = np.int32(stack[10, r, x])
            s = p1 - p3
            c = p0 - p2
            total = p0 + p1 + p2 + p3
            threshold = total >> 2
            word = np.int32(0)
            for k in range(7):
                word = word * 2 + np.int32(np.int32(stack[k, r, x]) > threshold)
            flat[x] = (s + 255) * 511 + (c + 255)
            words[x] = word
            squares[x] = s * s + c * c
            totals[x] = total
        for x in range(width):
            f = flat[x]
            word = words[x]
            index = np.int32(quadrant_lut[f]) + np.int32(row8_lut[word])
            # one rounding of the exact product and sum, as cv2.scaleAdd's fused multiply-add
            fractions[x] = np.float32(np.float64(k_lut[index]) + np.float64(phase_lut[f]) * alpha)
            binary[x] = word_lut[word]
        for x in range(width):
            fraction = fractions[x]
            l = binary[x] + fraction
            modulation = np.float32(math.sqrt(np.float32(squares[x])))
            valid = (
                (modulation >= min_modulation)
                & (abs(fraction - half) <= max_offset)
                & (abs(l - half_nlp) <= max_centred)
            )
            codes_out[r, x] = l if valid else nan
        if want_gray:
            for x in range(width):
                modulation = np.float32(math.sqrt(np.float32(squares[x])))
                gray_out[r, x] = gray_lut[words[x]] if modulation >= min_modulation else nan
        if want_visibility:
            for x in range(width):
                visibility_out[r, x] = np.float32(math.sqrt(np.float32(squares[x]))) / np.float32(totals[x])
        if want_heights:
            for x in range(width):
                l = codes_out[r, x]
                den = l * q + one
                num = (l - ref_codes[r, x]) * slope_mm[r, x]
                num = num / den  # D_R, mm
                den = num + d_mm
                z_out[r, x] = (num * L_mm) / den


def warm() -> None:
    """Load (or compile) the kernel now, on empty arrays of the types the tiles pass, and fill the
    phase tables: the first call otherwise costs a few tenths of a second in the first frame."""
    stack, f32 = np.zeros((11, 1, 1), np.uint8), np.zeros((1, 1), np.float32)
    phase_lut, quadrant_lut = phase_tables()
    lut_f32, lut_u8 = np.zeros(256, np.float32), np.zeros(256, np.uint8)
    z = np.float32(0)
    gcps_v1_rows(
        stack, 0, 0, phase_lut, quadrant_lut, lut_f32, lut_u8, lut_f32,
        z, z, z, z, f32, lut_f32, f32, False, f32, False, f32, f32, z, z, z, f32, False,
    )  # fmt: skip


__all__ = ["PHASE_SIDE", "gcps_v1_rows", "phase_tables", "warm"]
