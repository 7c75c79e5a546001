"""Decoding of a gcps-v1 capture stack into light codes (Eqs. 1-3, docs/conventions.md).

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

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core import kernel_choice
from metrology.core.option_checks import check_number
from metrology.core.patterns import N_GRAY_BITS, N_PHASE_STEPS, PATTERN_NAMES, binary_from_gray
from metrology.core.tiling import run_tiled, thread_scratch

if TYPE_CHECKING:
    from metrology.core.geometry.base import HeightTerms


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

# dPhi in code units for cv2.LUT, indexed by (l^ mod 4) * 8 + floor(t), with t = (2/pi) Phi and
# Phi in [0, 2 pi] (t = 4 is Phi = 2 pi = 0): the quadrants t in [0, 1), [1, 2) are columns 2, 3 of
# DPHI_TABLE; [2, 3), [3, 4) are columns 0, 1 with Phi - 2 pi, i.e. 4 codes less; [4] is column 2.
_COLUMN_AND_SHIFT_FROM_FLOOR_T = ((2, 0.0), (3, 0.0), (0, -4.0), (1, -4.0), (2, -4.0))
_K_LUT = np.full(256, np.nan, np.float32)
for _row in range(4):
    for _floor_t, (_column, _shift) in enumerate(_COLUMN_AND_SHIFT_FROM_FLOOR_T):
        _K_LUT[8 * _row + _floor_t] = DPHI_TABLE[_row, _column] * (2 / np.pi) + _shift

_BINARY_FROM_GRAY = binary_from_gray(np.arange(256), n_bits=8)
_BINARY_FROM_GRAY_F32_LUT = _BINARY_FROM_GRAY.astype(np.float32)  # gray word -> binary word l^
_ROW8_FROM_GRAY_LUT = ((_BINARY_FROM_GRAY & 3) * 8).astype(np.uint8)  # gray word -> (l^ mod 4) * 8
_BIT_WEIGHTS = (1 << np.arange(N_GRAY_BITS - 1, -1, -1)).astype(np.uint8)[:, None, None]
_NAN_UNLESS_TRUE_LUT = np.where(np.arange(256) == 1, 0, np.nan).astype(np.float32)  # bool -> 0 or NaN
_CODES_PER_RADIAN = 2 / np.pi


@functools.lru_cache(maxsize=16)
def _gray_only_codes_lut(nlp: int) -> np.ndarray:
    """Gray word -> centre ``l^ + 0.5`` of its cell, NaN beyond the coded field."""
    centres = _BINARY_FROM_GRAY + 0.5
    return np.where(centres <= nlp, centres, np.nan).astype(np.float32)


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


MAX_SMOOTHING_PX = 50.0
"""Largest Gaussian smoothing sigma accepted, px."""


@dataclass(frozen=True)
class GcpsV1Options:
    """Settings of the paper's gcps-v1 decoder that no other codec has (the codec-independent
    thresholds are :class:`metrology.core.filters.FilterOptions`).

    ``consistency_codes``: how far, in code units, the combined code may fall outside the gray
    word's cell after the dPhi correction (Eq. 3); the codec decoder's ``consistency_periods``
    for the built-in gcps-v1 codec is this over 4 (its phase period is 4 codes).
    ``smoothing_px``: Gaussian sigma (px) applied along X to the phase images before Eq. 2, the
    paper's digital smoothing of square-wave fringes; 0 disables it (a codec states its waveform).
    """

    consistency_codes: float = 0.35
    smoothing_px: float = 0.0

    def __post_init__(self) -> None:
        check_number("consistency_codes", self.consistency_codes)
        check_number("smoothing_px", self.smoothing_px, upper=MAX_SMOOTHING_PX)

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return ("consistency_codes", "smoothing_px")

    def to_dict(self) -> dict[str, Any]:
        return {"consistency_codes": self.consistency_codes, "smoothing_px": self.smoothing_px}


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
        Worker threads over row tiles; default :data:`~metrology.core.tiling.DEFAULT_THREADS`.

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
        decode_rows(
            stack[:N_GRAY_BITS, rows],
            phase_images[:, rows],
            nlp,
            float(min_modulation),
            consistency_codes,
            field_margin_codes,
            codes[rows],
            gray_out=gray_codes[rows],
            modulation_out=modulation[rows],
            mask_out=mask[rows],
            visibility_out=visibility[rows],
        )

    run_tiled(run, height, width, threads)
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


def decode_rows(
    gray_images: np.ndarray,
    phase_images: np.ndarray,
    nlp: int,
    min_modulation: float,
    consistency_codes: float,
    field_margin_codes: float,
    codes_out: np.ndarray,
    *,
    gray_out: np.ndarray | None = None,
    modulation_out: np.ndarray | None = None,
    mask_out: np.ndarray | None = None,
    visibility_out: np.ndarray | None = None,
    fraction_out: np.ndarray | None = None,
    word_out: np.ndarray | None = None,
) -> None:
    """Decode one tile of rows into the given outputs (the hot loop: see benchmarks/decode.py).

    Parameters
    ----------
    gray_images : (7, h, W) array
        The tile of the gray-code images.
    phase_images : (4, h, W) array
        The tile of the phase images, of the same dtype (or float32 after smoothing).
    nlp, min_modulation, consistency_codes, field_margin_codes
        As in :func:`decode_stack`.
    codes_out : (h, W) float32 array
        Receives the combined codes, NaN where invalid.
    gray_out, modulation_out, mask_out, visibility_out : (h, W) arrays, optional
        Receive the gray-code-only codes (float32), the modulation ``B`` (float32), the
        validity (bool) and ``B / 4A`` (float32, half the visibility).
    fraction_out, word_out : (h, W) float32 arrays, optional
        Receive, before any validity test, ``l - l^`` (the combined code within the gray word's
        cell ``[0, 1)`` when consistent; NaN where gray and phase disagree by two codes) and the
        binary word ``l^``: what the codec self-check reads (:func:`metrology.core.measure.check_gcps_v1_sample`).

    Notes
    -----
    Every temporary lives in the thread's :class:`~metrology.core.tiling.Scratch`, so a
    tile allocates nothing. 8-bit stacks take OpenCV's vectorised ``cartToPolar`` for
    the phase (max error 1.7e-4 rad, i.e. 1.1e-4 code units, a tenth of the phase error
    that 8-bit quantisation alone causes on a 100-grey-level fringe); other dtypes take
    numpy's exact ``arctan2``, 25 times slower on this machine. The dPhi table is applied
    with ``cv2.LUT`` on an index ``(l^ mod 4) * 8 + floor((2/pi) Phi)``.
    """
    scratch = thread_scratch()
    shape = codes_out.shape

    def f32(name: str) -> np.ndarray:
        return scratch.get(name, shape, np.float32)

    p0, p1, p2, p3 = (phase_images[i] for i in range(N_PHASE_STEPS))
    if phase_images.dtype == np.uint8 and gray_images.dtype == np.uint8:
        sf = cv2.subtract(p1, p3, dst=f32("sin"), dtype=cv2.CV_32F)
        cf = cv2.subtract(p0, p2, dst=f32("cos"), dtype=cv2.CV_32F)
        total = np.add(p0, p2, out=scratch.get("total", shape, np.uint16), dtype=np.uint16)  # 4 A
        total += np.add(p1, p3, out=scratch.get("half_total", shape, np.uint16), dtype=np.uint16)
        # g > A  <=>  g > floor(4A / 4) for integers; |x - 0.375| rounded is floor(x / 4) here
        threshold = cv2.convertScaleAbs(total, dst=scratch.get("threshold", shape, np.uint8), alpha=0.25, beta=-0.375)
        gray = gray_images
        modulation, phase = cv2.cartToPolar(cf, sf, magnitude=f32("modulation"), angle=f32("phase"))  # [0, 2 pi]
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
        modulation = np.hypot(sf, cf)
        phase = np.arctan2(sf, cf)
        phase += np.float32(2 * np.pi) * (phase < 0)  # [0, 2 pi]

    # gray word: all seven bit planes thresholded at once, weighted and summed (MSB first)
    bits = np.greater(gray, threshold, out=scratch.get("bits", gray.shape, bool)).view(np.uint8)
    bits *= _BIT_WEIGHTS
    gray_word = bits.sum(axis=0, dtype=np.uint8, out=scratch.get("gray_word", shape, np.uint8))

    # Eq. 3: l = l^ + (2/pi)(Phi + dPhi), dPhi looked up by (l^ mod 4) * 8 + floor(t), t = (2/pi) Phi;
    # |x - 0.5| rounded is floor(x) for x in [0, 4] (ties at whole t give either side, both valid)
    index: np.ndarray = cv2.convertScaleAbs(
        phase, dst=scratch.get("index", shape, np.uint8), alpha=_CODES_PER_RADIAN, beta=-0.5
    )
    index += cv2.LUT(gray_word, _ROW8_FROM_GRAY_LUT, dst=scratch.get("row", shape, np.uint8))
    # sin and cos are spent: their buffers take the fraction and the word
    fraction: np.ndarray = cv2.LUT(index, _K_LUT, dst=f32("sin"))  # NaN where gray and phase disagree
    fraction = cv2.scaleAdd(phase, _CODES_PER_RADIAN, fraction, dst=fraction)  # l - l^
    word = cv2.LUT(gray_word, _BINARY_FROM_GRAY_F32_LUT, dst=f32("cos"))
    np.add(word, fraction, out=codes_out)
    if fraction_out is not None:
        np.copyto(fraction_out, fraction)
    if word_out is not None:
        np.copyto(word_out, word)

    # validity: within the gray word's cell +- consistency_codes, modulated, inside the field
    valid = scratch.get("valid", shape, bool)
    test = scratch.get("test", shape, bool)
    np.subtract(fraction, np.float32(0.5), out=fraction)
    np.abs(fraction, out=fraction)
    np.less_equal(fraction, np.float32(0.5 + consistency_codes), out=valid)
    modulated = np.greater_equal(modulation, np.float32(min_modulation), out=scratch.get("modulated", shape, bool))
    valid &= modulated
    centred = np.subtract(codes_out, np.float32(nlp / 2), out=fraction)
    np.abs(centred, out=centred)
    valid &= np.less_equal(centred, np.float32(nlp / 2 - field_margin_codes), out=test)
    codes_out += cv2.LUT(valid.view(np.uint8), _NAN_UNLESS_TRUE_LUT, dst=word)  # word is spent

    if mask_out is not None:
        np.copyto(mask_out, valid)
    if modulation_out is not None:
        np.copyto(modulation_out, modulation)
    if visibility_out is not None:
        # fringe visibility B / 4A (half of B / 2A; only ratios of it are used): independent
        # of albedo and exposure; NaN or inf where the pixel is black
        with np.errstate(divide="ignore", invalid="ignore"):
            np.divide(modulation, total, out=visibility_out, dtype=np.float32)
    if gray_out is not None:
        cv2.LUT(gray_word, _gray_only_codes_lut(nlp), dst=gray_out)
        gray_out += cv2.LUT(modulated.view(np.uint8), _NAN_UNLESS_TRUE_LUT, dst=word)


def use_compiled(dtype: npt.DTypeLike, pixels: int) -> bool:
    """Whether :func:`decode_tile` takes the compiled kernel (:mod:`metrology.core.decode_kernels`)
    for a stack of ``dtype`` and frames of ``pixels``: 8-bit stacks only, by the rule of every
    compiled kernel (:func:`metrology.core.kernel_choice.use_compiled`: where numba is already
    imported, or the frame is large); numpy's otherwise (a ``gcps measure`` process would pay more
    for importing numba than the kernel saves). Both give the same numbers."""
    if np.dtype(dtype) != np.uint8:
        return False
    return kernel_choice.use_compiled(pixels)


def decode_tile(
    stack: np.ndarray,
    phase_images: np.ndarray,
    rows: slice,
    nlp: int,
    min_modulation: float,
    consistency_codes: float,
    field_margin_codes: float,
    codes: np.ndarray,
    *,
    compiled: bool,
    gray_codes: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
    heights: HeightTerms | None = None,
    z_mm: np.ndarray | None = None,
) -> bool:
    """Decode the rows ``rows`` of a gcps-v1 stack into the full-frame outputs: :func:`decode_rows`,
    or with ``compiled`` (8-bit stacks) the compiled kernel
    (:func:`metrology.core.decode_kernels.gcps_v1_rows`: the same numbers in one pass over the
    frames), which also writes the heights in the same pass.

    ``stack`` (11, H, W); ``phase_images`` (4, H, W): its phase frames (float32 once smoothed);
    ``codes``, ``gray_codes``, ``visibility`` (H, W) float32 as :func:`decode_rows`' ``codes_out``,
    ``gray_out``, ``visibility_out``; ``heights``: the model's closed form over the frame
    (:meth:`~metrology.core.geometry.base.PreparedGeometry.height_terms`), ``z_mm`` (H, W) float32.
    Returns True when the rows of ``z_mm`` were written (the caller triangulates them otherwise).
    """
    outputs = [a for a in (codes, gray_codes, visibility, z_mm) if a is not None]
    if heights is not None:
        outputs += [heights.ref_codes, heights.slope_mm]
    eight_bit = stack.dtype == np.uint8 and phase_images.dtype == np.uint8
    if not (compiled and eight_bit and stack.flags.c_contiguous and all(a.flags.c_contiguous for a in outputs)):
        decode_rows(
            stack[:N_GRAY_BITS, rows],
            phase_images[:, rows],
            nlp,
            min_modulation,
            consistency_codes,
            field_margin_codes,
            codes[rows],
            gray_out=None if gray_codes is None else gray_codes[rows],
            visibility_out=None if visibility is None else visibility[rows],
        )
        return False
    from metrology.core import decode_kernels as kernels

    phase_lut, quadrant_bounds = kernels.phase_tables()
    empty = np.empty((0, 0), np.float32)
    zero = np.float32(0)
    ref_codes, slope, q, d, L, z = empty, empty, zero, zero, zero, empty
    with_heights = heights is not None and z_mm is not None
    if heights is not None and z_mm is not None:
        ref_codes, slope, z = heights.ref_codes, heights.slope_mm, z_mm
        q, d, L = heights.q, heights.d_mm, heights.L_mm
    kernels.gcps_v1_rows(
        stack,
        rows.start,
        rows.stop,
        phase_lut,
        quadrant_bounds,
        kernels.min_square(min_modulation),
        np.float32(0.5 + consistency_codes),
        np.float32(nlp / 2),
        np.float32(nlp / 2 - field_margin_codes),
        codes,
        _gray_only_codes_lut(nlp),
        empty if gray_codes is None else gray_codes,
        gray_codes is not None,
        empty if visibility is None else visibility,
        visibility is not None,
        ref_codes,
        slope,
        q,
        d,
        L,
        z,
        with_heights,
    )
    return with_heights


def decode_sampled_rows(
    stack: np.ndarray,
    rows: np.ndarray,
    nlp: int,
    min_modulation: float,
    fraction_out: np.ndarray,
    word_out: np.ndarray,
    modulation_out: np.ndarray,
) -> None:
    """:func:`decode_rows`' ``fraction_out``, ``word_out`` and ``modulation_out`` ((n, W) float32) on
    the rows ``rows`` ((n,) intp) of a gcps-v1 stack (11, H, W): what the codec self-check reads
    (:func:`metrology.core.measure.check_gcps_v1_sample`). A C-contiguous 8-bit stack takes the
    compiled kernel where :func:`use_compiled` says so
    (:func:`metrology.core.decode_kernels.gcps_v1_sample`, the same numbers)."""
    _, height, width = stack.shape
    if stack.flags.c_contiguous and use_compiled(stack.dtype, height * width):
        from metrology.core import decode_kernels as kernels

        kernels.gcps_v1_sample(stack, rows, *kernels.phase_tables(), fraction_out, word_out, modulation_out)
        return
    decode_rows(
        np.ascontiguousarray(stack[:N_GRAY_BITS, rows]),
        np.ascontiguousarray(stack[N_GRAY_BITS:, rows]),
        nlp,
        min_modulation,
        0.0,
        0.0,
        np.empty(fraction_out.shape, np.float32),
        modulation_out=modulation_out,
        fraction_out=fraction_out,
        word_out=word_out,
    )


def set_nan_where_false(values: np.ndarray, keep: np.ndarray, threads: int | None = None) -> None:
    """Set ``values`` ((H, W) float32) to NaN where ``keep`` ((H, W) bool) is False, in place,
    tile by tile."""
    height, width = values.shape

    def run(rows: slice) -> None:
        v = values[rows]
        nan_or_zero = thread_scratch().get("nan", v.shape, np.float32)
        v += cv2.LUT(keep[rows].view(np.uint8), _NAN_UNLESS_TRUE_LUT, dst=nan_or_zero)

    run_tiled(run, height, width, threads)
