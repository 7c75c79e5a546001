"""The gcps-v1 pattern set (docs/conventions.md): seven gray-code and four phase-shift patterns.

Light codes ``l`` run linearly across the projector's columns, from 0 at the left
edge of the coded field to ``nlp`` at its right edge. Pattern ``GC_k`` is bit k
(k = 0 most significant) of the 7-bit reflected gray code of ``floor(l)``;
``PS_i`` is ``0.5 + 0.5 cos(pi/2 l - i pi/2)`` (Eq. 1), or, with ``square=True``,
the square wave of the same phase (the paper's binary fringes, to be smoothed).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

N_GRAY_BITS = 7
N_PHASE_STEPS = 4
GRAY_NAMES: tuple[str, ...] = tuple(f"GC_{k}" for k in range(N_GRAY_BITS))
PHASE_NAMES: tuple[str, ...] = tuple(f"PS_{i}" for i in range(N_PHASE_STEPS))
PATTERN_NAMES: tuple[str, ...] = GRAY_NAMES + PHASE_NAMES
"""The eleven pattern names, in projection order."""

PHASE_PERIOD_CODES = 4
"""Period of the phase-shift fringes, in code units."""


def gray_from_binary(words: npt.ArrayLike) -> np.ndarray:
    """Reflected binary gray code ``g = w ^ (w >> 1)`` of non-negative integers.

    Examples
    --------
    >>> gray_from_binary([0, 1, 2, 3, 4]).tolist()
    [0, 1, 3, 2, 6]
    """
    w = np.asarray(words)
    if w.dtype.kind not in "iu":
        raise ValueError(f"words must be integers, got dtype {w.dtype}")
    return w ^ (w >> 1)


def binary_from_gray(gray: npt.ArrayLike, n_bits: int = N_GRAY_BITS) -> np.ndarray:
    """Inverse of :func:`gray_from_binary` (prefix XOR of the bits, MSB first).

    Examples
    --------
    >>> binary_from_gray([0, 1, 3, 2, 6]).tolist()
    [0, 1, 2, 3, 4]
    """
    g = np.asarray(gray)
    if g.dtype.kind not in "iu":
        raise ValueError(f"gray must be integers, got dtype {g.dtype}")
    w = g.copy()
    shift = 1
    while shift < n_bits:
        w ^= w >> shift
        shift <<= 1
    return w


def gray_code_table(n_bits: int) -> np.ndarray:
    """Table 1 of the paper: ``(n_bits, 2**n_bits)`` uint8, row r = bit r (MSB first) of word c."""
    if not 1 <= n_bits <= 16:
        raise ValueError(f"n_bits must be in 1..16, got {n_bits}")
    g = gray_from_binary(np.arange(2**n_bits))
    shifts = np.arange(n_bits - 1, -1, -1)[:, None]
    return ((g[None, :] >> shifts) & 1).astype(np.uint8)


def pattern_intensity(codes: npt.ArrayLike, name: str, square: bool = False) -> np.ndarray:
    """Ideal relative intensity of pattern ``name`` at light codes ``codes``.

    Parameters
    ----------
    codes : array_like of float, any shape
        Light codes in code units; the field is [0, nlp] (nlp <= 128).
    name : str
        One of :data:`PATTERN_NAMES`.
    square : bool
        Phase patterns as square waves (1 where the cosine is >= 0) instead of sinusoids.

    Returns
    -------
    intensity : float64 ndarray, same shape, in [0, 1]
        Zero outside the coded field is *not* applied here (the projector's
        field limits belong to the rig model).
    """
    l = np.asarray(codes, dtype=np.float64)
    if name in GRAY_NAMES:
        k = GRAY_NAMES.index(name)
        words = np.clip(np.floor(l), 0, 2**N_GRAY_BITS - 1).astype(np.int64)
        bit = (gray_from_binary(words) >> (N_GRAY_BITS - 1 - k)) & 1
        return bit.astype(np.float64)
    if name in PHASE_NAMES:
        i = PHASE_NAMES.index(name)
        c = np.cos(np.pi / 2 * l - i * np.pi / 2)
        if square:
            return (c >= 0).astype(np.float64)
        return 0.5 + 0.5 * c
    raise ValueError(f"unknown pattern name {name!r}; expected one of {', '.join(PATTERN_NAMES)}")


def projector_codes(width_px: int, nlp: int = 128) -> np.ndarray:
    """Light code at the centre of each projector column: ``(width_px,)`` float64."""
    if width_px <= 0 or nlp <= 0:
        raise ValueError(f"width_px and nlp must be positive, got {width_px}, {nlp}")
    return (np.arange(width_px) + 0.5) * (nlp / width_px)


def projector_patterns(width_px: int, height_px: int, nlp: int = 128, square: bool = False) -> np.ndarray:
    """The eleven projector images of gcps-v1.

    Parameters
    ----------
    width_px, height_px : int
        Projector resolution, pixels.
    nlp : int
        Codes spanning the projector width (128 for the 7-bit gray code).
    square : bool
        Square-wave phase patterns (to be smoothed by defocus or on acquisition).

    Returns
    -------
    images : (11, height_px, width_px) uint8 array
        In :data:`PATTERN_NAMES` order; fringes parallel to the columns.
    """
    if width_px <= 0 or height_px <= 0:
        raise ValueError(f"projector size must be positive, got {width_px}x{height_px}")
    if not 1 <= nlp <= 2**N_GRAY_BITS:
        raise ValueError(f"nlp must be in 1..128, got {nlp}")
    l = projector_codes(width_px, nlp)
    rows = np.stack([pattern_intensity(l, name, square) for name in PATTERN_NAMES])
    rows8 = np.round(rows * 255.0).astype(np.uint8)
    return np.ascontiguousarray(np.broadcast_to(rows8[:, None, :], (len(PATTERN_NAMES), height_px, width_px)))
