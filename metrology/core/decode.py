"""Decoding of a gcps-v1 capture stack into light codes (Eqs. 1-3, DESIGN.md 1.4).

Per pixel:

* the four phase-shift images give the phase ``Phi = atan2(I1 - I3, I0 - I2)``
  (Eq. 2), the modulation ``B = hypot(I1 - I3, I0 - I2)`` and the mean
  brightness ``A = (I0 + I1 + I2 + I3) / 4``;
* each gray-code image is thresholded against ``A``; the seven bits form the
  gray word, converted to the binary word ``l^`` by a running XOR (prefix XOR);
* Eq. 3 combines them: ``l = l^ + (2/pi)(Phi + dPhi)``, with dPhi from
  :data:`DPHI_TABLE`, indexed by ``l^ mod 4`` and the quadrant of ``Phi``.

Derivation of the dPhi table (the paper's Table 2 is damaged in our copy).
With the pattern ``PS_i = 0.5 + 0.5 cos(pi/2 l - i pi/2)``, ``Phi`` is
``(pi/2) l`` wrapped to [-pi, pi), so ``t = (2/pi) Phi`` is ``l`` modulo 4,
wrapped to [-2, 2). The combined code is ``l = 4 n + t`` for the phase period
``n`` whose code lies nearest to the centre ``l^ + 0.5`` of the gray word's cell,
which tolerates a gray word off by one at stripe transitions. Writing
``l^ = 4 m + r`` and evaluating at the centre of each quadrant ``q`` of ``t``
gives ``dPhi = (pi/2)(4 (n - m) - r)``. When ``t`` lies in the quadrant
opposite to the one the gray word predicts, the two codes disagree by two code
units, which no off-by-one transition explains: that entry is NaN (invalid).

>>> import numpy as np
>>> np.round(DPHI_TABLE / (np.pi / 2)).tolist()  # dPhi in units of pi/2
[[nan, 0.0, 0.0, 0.0], [3.0, nan, -1.0, -1.0], [2.0, 2.0, nan, -2.0], [1.0, 1.0, 1.0, nan]]

Rows are ``l^ mod 4 = 0..3``; columns the quadrants
``Phi in [-pi, -pi/2), [-pi/2, 0), [0, pi/2), [pi/2, pi]``.

Pixels are invalid (NaN code) where the modulation is below ``min_modulation``
(shadows, outside the projector's field, dark surfaces), where the code falls
outside [0, nlp], or where gray code and phase disagree by more than
``consistency_codes`` beyond the gray word's cell.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.patterns import N_GRAY_BITS, N_PHASE_STEPS, PATTERN_NAMES, binary_from_gray


def _derive_dphi_table() -> np.ndarray:
    """dPhi (rad) for ``l^ mod 4`` (rows) and quadrant of Phi (columns), from the principle."""
    table = np.full((4, 4), np.nan)
    quadrant_centres = np.array([-1.5, -0.5, 0.5, 1.5])  # t = (2/pi) Phi
    for r in range(4):
        for q, t in enumerate(quadrant_centres):
            # candidate combined codes 4 n + t (with m = 0); pick the one nearest r + 0.5
            candidates = 4 * np.arange(-1, 3) + t
            distance = np.abs(candidates - (r + 0.5))
            best = np.sort(distance)
            if math.isclose(best[0], best[1]):
                continue  # opposite quadrant: two periods equally far, gray and phase disagree
            l_code = candidates[np.argmin(distance)]
            table[r, q] = (np.pi / 2) * (l_code - t - r)
    return table


DPHI_TABLE: np.ndarray = _derive_dphi_table()
"""dPhi of Eq. 3 in radians, shape (4, 4): rows ``l^ mod 4``, columns quadrant of Phi; NaN = invalid."""
DPHI_TABLE.setflags(write=False)

# dPhi in code units for cv2.LUT, indexed by (l^ mod 4) * 4 + 2 [sin Phi >= 0] + [cos Phi > 0]:
# the sign pairs (0, 0), (0, 1), (1, 1), (1, 0) are the quadrants 0, 1, 2, 3 of DPHI_TABLE.
_QUADRANT_FROM_SIGNS = (0, 1, 3, 2)
_K_LUT = np.full(256, np.nan, np.float32)
for _row in range(4):
    for _signs, _quadrant in enumerate(_QUADRANT_FROM_SIGNS):
        _K_LUT[4 * _row + _signs] = DPHI_TABLE[_row, _quadrant] * (2 / np.pi)

_BINARY_FROM_GRAY = binary_from_gray(np.arange(256), n_bits=8)
_BINARY_FROM_GRAY_F32_LUT = _BINARY_FROM_GRAY.astype(np.float32)  # gray word -> binary word l^
_ROW4_FROM_GRAY_LUT = ((_BINARY_FROM_GRAY & 3) * 4).astype(np.uint8)  # gray word -> (l^ mod 4) * 4
_BIT_WEIGHTS = (1 << np.arange(N_GRAY_BITS - 1, -1, -1)).astype(np.uint8)[:, None, None]

DEFAULT_TILE_PX = 1 << 14
"""Pixels per tile of work: small enough that a tile's temporaries stay in cache."""

DEFAULT_THREADS = 1
"""Threads over tiles. Measured on 2 cores (1280x1024): 1 thread 28.7 ms, 2 threads 33 ms at
16k-pixel tiles; 2 threads only pay off with 64k-pixel tiles (32.6 ms), which fall out of cache.
A cache-sized tile is ~45 numpy calls of a few microseconds, whose dispatch holds the GIL."""


@dataclass(frozen=True)
class DecodedStack:
    """Result of decoding one capture stack.

    Attributes
    ----------
    codes : (H, W) float32 array
        Combined GCPS light codes (Eq. 3), code units in [0, nlp], NaN where invalid.
    gray_codes : (H, W) float32 array
        Gray-code-only codes: the centre ``l^ + 0.5`` of the decoded word's cell,
        NaN where the modulation is too low (the paper's comparison method).
    modulation : (H, W) float32 array
        ``B = hypot(I1 - I3, I0 - I2)``, grey levels of the input (twice the
        fringe amplitude).
    mask : (H, W) bool array
        True where ``codes`` is valid.
    visibility : (H, W) float32 array
        Fringe visibility ``B / 2A`` (0..1 for unsaturated images); NaN where the pixel is black.
    """

    codes: np.ndarray
    gray_codes: np.ndarray
    modulation: np.ndarray
    mask: np.ndarray
    visibility: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.codes.shape

    @property
    def valid_fraction(self) -> float:
        return float(self.mask.mean()) if self.mask.size else 0.0


def default_min_modulation(dtype: npt.DTypeLike) -> float:
    """Default modulation threshold: 4 % of full scale (about 10 grey levels at 8 bits)."""
    dtype = np.dtype(dtype)
    full_scale = float(np.iinfo(dtype).max) if dtype.kind in "ui" else 1.0
    return 0.04 * full_scale


def validate_stack(images: npt.ArrayLike) -> np.ndarray:
    """Check a stack's shape and dtype; return it as an ndarray.

    Raises
    ------
    ValueError
        If ``images`` is not ``(11, H, W)`` of uint8, uint16 or float.
    """
    stack = np.asarray(images)
    n = len(PATTERN_NAMES)
    if stack.ndim != 3 or stack.shape[0] != n:
        raise ValueError(f"images must have shape ({n}, H, W), got {stack.shape}")
    if stack.shape[1] < 1 or stack.shape[2] < 1:
        raise ValueError(f"images must not be empty, got shape {stack.shape}")
    if stack.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise ValueError(f"images must be uint8, uint16 or float, got dtype {stack.dtype}")
    return stack


def decode_stack(
    images: npt.ArrayLike,
    nlp: int = 128,
    *,
    min_modulation: float | None = None,
    consistency_codes: float = 0.35,
    smoothing_px: float = 0.0,
    field_margin_codes: float = 0.0,
    threads: int | None = None,
) -> DecodedStack:
    """Decode a gcps-v1 capture stack into light codes (Eqs. 1-3).

    Parameters
    ----------
    images : (11, H, W) array of uint8, uint16 or float
        Camera images in :data:`~metrology.core.patterns.PATTERN_NAMES` order.
    nlp : int
        Number of light codes across the coded field; codes outside [0, nlp] are invalid.
    min_modulation : float, optional
        Minimum ``B = hypot(I1 - I3, I0 - I2)`` in grey levels of the input; default
        :func:`default_min_modulation` of the dtype (4 % of full scale).
    consistency_codes : float
        How far, in code units, the combined code may fall outside the gray word's
        cell ``[l^, l^ + 1]`` after the dPhi correction. Larger tolerates more
        defocus between gray code and phase; smaller drops more mixed pixels.
    smoothing_px : float
        Gaussian sigma, pixels, applied along X to the phase images before Eq. 2:
        the paper's digital smoothing of square-wave fringes. 0 disables it.
    field_margin_codes : float
        Codes closer than this to 0 or ``nlp`` are invalid: at the edges of the coded
        field the projector's blur mixes fringes with darkness and biases the phase.
    threads : int, optional
        Worker threads over row tiles; default 1 (see :data:`DEFAULT_THREADS`).

    Returns
    -------
    DecodedStack

    Raises
    ------
    ValueError
        On a malformed stack or out-of-range parameters.
    """
    stack = validate_stack(images)
    if not 1 <= nlp <= 2**N_GRAY_BITS:
        raise ValueError(f"nlp must be in 1..{2**N_GRAY_BITS}, got {nlp}")
    if consistency_codes < 0 or not math.isfinite(consistency_codes):
        raise ValueError(f"consistency_codes must be a non-negative number, got {consistency_codes}")
    if smoothing_px < 0:
        raise ValueError(f"smoothing_px must be >= 0, got {smoothing_px}")
    if not 0 <= field_margin_codes < nlp / 2:
        raise ValueError(f"field_margin_codes must be in [0, nlp/2), got {field_margin_codes}")
    if min_modulation is None:
        min_modulation = default_min_modulation(stack.dtype)
    if min_modulation < 0:
        raise ValueError(f"min_modulation must be >= 0, got {min_modulation}")

    _, height, width = stack.shape
    phase_images = stack[N_GRAY_BITS:]
    if smoothing_px > 0:
        phase_images = smooth_fringes(phase_images, smoothing_px)

    codes = np.empty((height, width), np.float32)
    gray_codes = np.empty((height, width), np.float32)
    modulation = np.empty((height, width), np.float32)
    mask = np.empty((height, width), bool)
    visibility = np.empty((height, width), np.float32)

    def run(rows: slice) -> None:
        _decode_rows(
            stack[:N_GRAY_BITS, rows],
            phase_images[:, rows],
            nlp,
            float(min_modulation),
            consistency_codes,
            field_margin_codes,
            codes[rows],
            gray_codes[rows],
            modulation[rows],
            mask[rows],
            visibility[rows],
        )

    _run_tiled(run, height, width, threads)
    visibility *= np.float32(2)  # the kernel gives B / 4A
    return DecodedStack(codes=codes, gray_codes=gray_codes, modulation=modulation, mask=mask, visibility=visibility)


def smooth_fringes(phase_images: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing along X of the phase images: ``(4, H, W)`` -> float32 ``(4, H, W)``."""

    radius = max(1, math.ceil(3 * sigma_px))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma_px) ** 2)
    kernel = (kernel / kernel.sum()).astype(np.float32)
    one = np.ones(1, np.float32)
    return np.stack(
        [
            cv2.sepFilter2D(img.astype(np.float32), cv2.CV_32F, kernel, one, borderType=cv2.BORDER_REFLECT)
            for img in phase_images
        ]
    )


def row_tiles(height: int, width: int, tile_px: int = DEFAULT_TILE_PX) -> list[slice]:
    """Split ``height`` rows into slices of about ``tile_px`` pixels each (cache-sized work)."""
    rows_per_tile = max(1, tile_px // max(1, width))
    return [slice(r, min(height, r + rows_per_tile)) for r in range(0, height, rows_per_tile)]


def _run_tiled(run: object, height: int, width: int, threads: int | None) -> None:
    tiles = row_tiles(height, width)
    n_threads = threads if threads is not None else DEFAULT_THREADS
    if n_threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    if n_threads == 1 or len(tiles) == 1:
        for rows in tiles:
            run(rows)  # type: ignore[operator]
        return
    with ThreadPoolExecutor(max_workers=n_threads) as pool:
        list(pool.map(run, tiles))  # type: ignore[arg-type]


def _decode_rows(
    gray_images: np.ndarray,
    phase_images: np.ndarray,
    nlp: int,
    min_modulation: float,
    consistency_codes: float,
    field_margin_codes: float,
    codes_out: np.ndarray,
    gray_out: np.ndarray | None = None,
    modulation_out: np.ndarray | None = None,
    mask_out: np.ndarray | None = None,
    visibility_out: np.ndarray | None = None,
) -> None:
    """Decode one tile of rows in place (the hot loop: see benchmarks/decode.py).

    Integer arithmetic where the input is integral; the dPhi table is applied with
    ``cv2.LUT`` on a 4-bit index and invalid codes are set to NaN by OR-ing the
    quiet-NaN bit pattern, both several times faster than fancy indexing and
    boolean assignment in numpy.
    """
    p0, p1, p2, p3 = (phase_images[i] for i in range(N_PHASE_STEPS))
    if phase_images.dtype == np.uint8 and gray_images.dtype == np.uint8:
        # 8-bit fast path: OpenCV goes from uint8 straight to float32 / uint16 in one pass
        sf = cv2.subtract(p1, p3, dtype=cv2.CV_32F)
        cf = cv2.subtract(p0, p2, dtype=cv2.CV_32F)
        total = cv2.add(cv2.add(p0, p2, dtype=cv2.CV_16U), cv2.add(p1, p3, dtype=cv2.CV_16U))  # 4 A
        # g > A  <=>  g > floor(4A / 4) for integers; |x - 0.375| rounded is floor(x / 4) here
        threshold = cv2.convertScaleAbs(total, alpha=0.25, beta=-0.375)
        gray = gray_images
    else:
        work = np.int32 if phase_images.dtype == np.uint16 else np.float32
        i0, i1, i2, i3 = (p.astype(work) for p in (p0, p1, p2, p3))
        sf = (i1 - i3).astype(np.float32, copy=False)
        cf = (i0 - i2).astype(np.float32, copy=False)
        total = i0 + i1 + i2 + i3  # 4 A
        if work is np.float32:
            gray = gray_images.astype(np.float32, copy=False)
            threshold = total * np.float32(0.25)
        else:
            gray = gray_images
            threshold = (total >> 2).astype(gray_images.dtype)

    # gray word: all seven bit planes thresholded at once, weighted and summed (MSB first)
    bits = np.greater(gray, threshold).view(np.uint8)
    bits *= _BIT_WEIGHTS
    gray_word = bits.sum(axis=0, dtype=np.uint8)

    modulation2 = sf * sf
    modulation2 += cf * cf
    t = np.arctan2(sf, cf)
    t *= np.float32(2 / np.pi)  # wrapped phase in code units, [-2, 2]

    # table index: (l^ mod 4) * 4 (one table look-up from the gray word) + the signs of sin and
    # cos of Phi, which select its quadrant ([-pi,-pi/2), [-pi/2,0), [0,pi/2), [pi/2,pi])
    index: np.ndarray = cv2.LUT(gray_word, _ROW4_FROM_GRAY_LUT)
    upper = (sf >= 0).view(np.uint8)
    index |= upper << np.uint8(1)
    index |= (cf > 0).view(np.uint8)
    fraction: np.ndarray = cv2.LUT(index, _K_LUT)  # dPhi in code units, NaN where inconsistent
    fraction += t  # l - l^ (Eq. 3)

    word_f: np.ndarray = cv2.LUT(gray_word, _BINARY_FROM_GRAY_F32_LUT)
    np.add(word_f, fraction, out=codes_out)
    fraction -= np.float32(0.5)
    np.abs(fraction, out=fraction)
    valid = fraction <= np.float32(0.5 + consistency_codes)
    modulated = modulation2 >= np.float32(min_modulation * min_modulation)
    valid &= modulated
    valid &= codes_out >= np.float32(field_margin_codes)
    valid &= codes_out <= np.float32(nlp - field_margin_codes)
    _set_nan(codes_out, valid)
    if mask_out is not None:
        mask_out[...] = valid
    if modulation_out is not None or visibility_out is not None:
        modulation = np.sqrt(modulation2, out=modulation_out)
        if visibility_out is not None:
            # fringe visibility B / 4A (half of B / 2A; only ratios of it are used): independent
            # of albedo and exposure; NaN or inf where the pixel is black
            with np.errstate(divide="ignore", invalid="ignore"):
                np.divide(modulation, total, out=visibility_out, dtype=np.float32)
    if gray_out is not None:
        word_f += np.float32(0.5)
        modulated &= word_f <= np.float32(nlp)
        np.copyto(gray_out, word_f)
        _set_nan(gray_out, modulated)


_QUIET_NAN_BITS = np.uint32(0x7FC00000)


def _set_nan(values: np.ndarray, valid: np.ndarray) -> None:
    """Set float32 ``values`` to NaN where ``valid`` is False, in place (bitwise OR)."""
    invalid = (~valid).astype(np.uint32)
    invalid *= _QUIET_NAN_BITS
    values.view(np.uint32)[...] |= invalid
