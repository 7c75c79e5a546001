"""Decoding a stack of any codec to absolute projector coordinates.

Per coded axis (u = projector columns, v = rows) and camera pixel:

* every phase sequence of N >= 3 frames gives, by least squares,
  ``C = sum_k I_k cos(2 pi shift k / N)``, ``S = sum_k I_k sin(2 pi shift k / N)``,
  the phase ``theta = atan2(-S, C)``, the modulation ``B = (2/N) hypot(C, S)``, the mean
  ``A = (1/N) sum_k I_k`` and, for N >= 4, the noise estimate ``sigma = sqrt(R / (N - 3))``
  from the residual ``R = sum_k I_k^2 - N A^2 - (N/2) B^2`` of the three-parameter fit;
  its wrapped coordinate is ``x_w = origin + period * ((theta / 2 pi) mod 1)``;
* the gray code: bit = frame > threshold (strictly), with the threshold the bit's inverse
  frame, else the mean of the white and black frames, else the mean A of the axis's first
  phase sequence; ``inverted`` flips the bits; the word's centre is ``origin + (n + 0.5) word``;
  a multi-level code (``levels`` L > 2) classifies each digit against level centres estimated
  from the stack (:mod:`metrology.core.codecs.gray`), normalised by the white and black frames,
  else by the first phase sequence's ``A -+ B``;
* the unwrapping chain, coarse to fine: a stage of period P turns the previous stage's
  coordinate ``x_c`` into ``x = x_w + P * round((x_c - x_w) / P)``; a beat of two sequences
  has ``theta_b = theta_s - theta_l`` and ``P_b = P_s P_l / (P_l - P_s)`` (its operands s and l
  may themselves be beats: beats of beats, computed recursively); a first stage
  without gray code is unwrapped against the projector's centre (its period covers the
  projector); a gray-only axis gives the word's centre.

Reason codes (uint8, one per pixel and axis; the first that applies wins, in this order):
1 too dark (B of a phase sequence in the chain below ``min_modulation``; gray-only axes:
half the white-black difference, or half the smallest inverse contrast), 2 saturated (a
phase frame at or above ``saturation_level``), 5 low inverse contrast (``|frame - inverse|``
below ``min_inverse_contrast`` for some bit), 7 gray level ambiguous (a multi-level gray digit
within ``LEVEL_MARGIN`` of a level gap from its threshold, or every pixel of an axis whose frames
do not show the described number of levels: ``metrology.core.codecs.gray``), 4 gray/phase
inconsistent (the first phase
stage lies more than ``consistency_periods`` of its period outside the gray word's cell, or a
phase stage lies more than ``unwrap_consistency_periods`` of its period from the coarser phase
stage it was unwrapped from),
3 outside the projector (``x`` outside ``[-0.5, size - 0.5]``), 6 slip repaired but kept, 0
valid. Coordinates are NaN unless the reason is 0 or 6.

Slips: where the gray word is at least as wide as the period of the stage after it, a gray
bit misread at a cell edge moves a pixel by whole periods while staying consistent. Such
pixels are found against the median of the valid coordinates of their 5x5 neighbourhood
(at least 13 of 25 valid): where ``|x - median| > P / 2`` the pixel is moved by
``P * round((median - x) / P)`` (re-snapped onto the final stage's phase) and kept with reason 6,
provided the moved coordinate lies within the gray/phase tolerance of its decoded word's cell
(a misread bit puts the true coordinate at that word's edge); a pixel whose 5x5 neighbourhood
straddles a depth edge is otherwise left as decoded.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from types import ModuleType
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.check import (
    INCONSISTENT,
    AxisCheck,
    check_axis_rows,
    check_rows,
    checkable,
    summary_of,
    with_suggestion,
)
from metrology.core.codecs.gray import LevelModel, centre_lut, classify_tile, digit_positions, sample_levels
from metrology.core.codecs.model import Axis, Codec, Stage
from metrology.core.patterns import binary_from_gray
from metrology.core.tiling import run_beside, run_tiled, thread_scratch

REASON_VALID = 0
REASON_TOO_DARK = 1
REASON_SATURATED = 2
REASON_OUTSIDE = 3
REASON_INCONSISTENT = 4
REASON_LOW_INVERSE_CONTRAST = 5
REASON_SLIP_REPAIRED = 6
REASON_LEVEL_AMBIGUOUS = 7
REASONS: dict[int, str] = {
    REASON_VALID: "valid",
    REASON_TOO_DARK: "too dark",
    REASON_SATURATED: "saturated",
    REASON_OUTSIDE: "outside the projector",
    REASON_INCONSISTENT: "gray/phase inconsistent",
    REASON_LOW_INVERSE_CONTRAST: "low inverse contrast",
    REASON_SLIP_REPAIRED: "slip repaired but kept",
    REASON_LEVEL_AMBIGUOUS: "gray level ambiguous",
}
"""Reason codes of the quality maps."""

TWO_PI = 2 * math.pi


@dataclass(frozen=True)
class CodecDecodeOptions:
    """Validity rules of :func:`decode_codec` (None: the default, resolved per codec and bit depth).

    Parameters
    ----------
    min_modulation : float, optional
        Smallest accepted modulation B (fringe amplitude), grey levels of the input. Default
        4 grey levels at 8 bits, scaled with the bit depth (``4 * full_scale / 255``); for the
        built-in gcps-v1 codec today's 2 % of full scale (4 % on the old ``hypot`` scale).
    min_inverse_contrast : float, optional
        Smallest accepted ``|frame - inverse|`` of a gray bit with an inverse frame, grey levels.
        Default 4 grey levels at 8 bits, scaled with the bit depth.
    consistency_periods : float, optional
        How far, in periods of the first phase stage, its coordinate may lie outside the gray
        word's cell. Default 0.25; gcps-v1 keeps today's 0.35 words = 0.0875 periods.
    unwrap_consistency_periods : float, optional
        How far, in periods of a phase stage unwrapped from another phase (or beat) stage, its
        coordinate may lie from that coarser stage's: ``|x - x_c| <= tol * P``, else the pixel is
        refused as inconsistent (unwrapping fails at half a period; pixels whose coarse
        coordinate is that noisy are refused before they slip). Default 1/3.
    saturation_level : float, optional
        Grey level at or above which a frame is saturated. Default the full scale of the
        dtype (255, 65535); no check for float images.
    repair_slips : bool
        Repair gray-code slips against the 5x5 median where the word is at least a period wide.
    exact_phase : bool, optional
        Use numpy's exact ``arctan2``; default True except for 8-bit stacks, which take
        OpenCV's ``cartToPolar`` (max error 1.7e-4 rad, far below 8-bit quantisation noise).
    """

    min_modulation: float | None = None
    min_inverse_contrast: float | None = None
    consistency_periods: float | None = None
    unwrap_consistency_periods: float | None = None
    saturation_level: float | None = None
    repair_slips: bool = True
    exact_phase: bool | None = None

    def __post_init__(self) -> None:
        for name in (
            "min_modulation",
            "min_inverse_contrast",
            "consistency_periods",
            "unwrap_consistency_periods",
            "saturation_level",
        ):
            value = getattr(self, name)
            if value is None:
                continue
            bad_type = isinstance(value, bool) or not isinstance(value, (int, float))
            # the saturation level may be infinite (no check: float images)
            finite_ok = name == "saturation_level" and value == math.inf
            if bad_type or (not math.isfinite(value) and not finite_ok) or value < 0:
                raise ValueError(f"option {name} must be a finite number >= 0, got {value!r}")
        if not isinstance(self.repair_slips, bool):
            raise ValueError(f"option repair_slips must be a bool, got {self.repair_slips!r}")

    def resolved(self, codec: Codec, dtype: npt.DTypeLike) -> CodecDecodeOptions:
        """The options with every default filled in for ``codec`` and images of ``dtype``."""
        dt = np.dtype(dtype)
        integer = dt.kind in "ui"
        full = float(np.iinfo(dt).max) if integer else 1.0
        gcps_v1 = codec.name == "gcps-v1"
        min_mod = self.min_modulation
        if min_mod is None:
            min_mod = 0.02 * full if gcps_v1 else 4.0 * full / 255.0
        contrast = self.min_inverse_contrast
        if contrast is None:
            contrast = 4.0 * full / 255.0
        consistency = self.consistency_periods
        if consistency is None:
            consistency = 0.35 / 4 if gcps_v1 else 0.25
        unwrap = self.unwrap_consistency_periods
        if unwrap is None:
            unwrap = 1 / 3
        saturation = self.saturation_level
        if saturation is None:
            saturation = full if integer else math.inf
        exact = self.exact_phase if self.exact_phase is not None else dt != np.uint8
        return CodecDecodeOptions(
            min_modulation=float(min_mod),
            min_inverse_contrast=float(contrast),
            consistency_periods=float(consistency),
            unwrap_consistency_periods=float(unwrap),
            saturation_level=float(saturation),
            repair_slips=self.repair_slips,
            exact_phase=bool(exact),
        )

    def to_dict(self) -> dict[str, Any]:
        """The options as a JSON-ready dict (inf as None)."""
        return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True, eq=False)
class AxisDecoding:
    """The decoding of one coded axis.

    Attributes
    ----------
    coordinate : (H, W) float32
        Absolute projector coordinate, projector units; NaN where not decoded.
    modulation : (H, W) float32
        B of the chain's final phase sequence (a beat: the smallest of its sequences'), grey levels;
        gray-only axes: half the white-black difference (or the smallest inverse contrast).
    mean : (H, W) float32
        A of the axis's first phase sequence, or the white/black mean, grey levels (NaN if none).
    noise : (H, W) float32
        Fit-residual noise of the final phase sequence, grey levels; NaN for N = 3 or gray only.
    reason : (H, W) uint8
        Reason codes (:data:`REASONS`).
    slips_repaired : int
        Pixels moved by the slip repair (reason 6).
    """

    coordinate: np.ndarray
    modulation: np.ndarray
    mean: np.ndarray
    noise: np.ndarray
    reason: np.ndarray
    slips_repaired: int = 0

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: decoded (reason 0 or 6)."""
        return (self.reason == REASON_VALID) | (self.reason == REASON_SLIP_REPAIRED)

    def reason_counts(self) -> dict[str, int]:
        """Pixels per reason name."""
        counts = np.bincount(self.reason.ravel(), minlength=len(REASONS))
        return {REASONS[i]: int(counts[i]) for i in REASONS}


@dataclass(frozen=True, eq=False)
class CodecDecoding:
    """Decoded projector coordinates of a stack (one :class:`AxisDecoding` per coded axis).

    Attributes
    ----------
    axes : mapping of str to AxisDecoding
    options : CodecDecodeOptions
        The resolved validity rules used.
    saturated_pixels : int
        Pixels at or above the saturation level in at least one frame of the codec (flagged;
        refused only where a phase frame is saturated).
    shape : (H, W)
    exposure : mapping of str to (H, W) uint8
        A multi-exposure capture's fused decoding only (:mod:`metrology.core.codecs.exposures`):
        per axis the index of the exposure each pixel used, 255 where none; empty otherwise.
    exposure_names : tuple of str
        The exposures' names in index order (empty for a single stack).
    """

    axes: Mapping[str, AxisDecoding]
    options: CodecDecodeOptions
    saturated_pixels: int
    shape: tuple[int, int]
    stats: dict[str, Any] = field(default_factory=dict)
    codec_check: Mapping[str, AxisCheck] = field(default_factory=dict)
    exposure: Mapping[str, np.ndarray] = field(default_factory=dict)
    exposure_names: tuple[str, ...] = ()

    def uv(self) -> np.ndarray:
        """``(H, W, 2)`` float32: u and v, NaN for an axis that is not coded or a pixel not decoded."""
        out = np.full((*self.shape, 2), np.nan, np.float32)
        for index, name in enumerate(("u", "v")):
            if name in self.axes:
                out[..., index] = self.axes[name].coordinate
        return out

    def quality_arrays(self) -> dict[str, np.ndarray]:
        """The quality file's arrays: ``modulation_a``, ``noise_a`` (float32) and ``reason_a`` (uint8);
        for a multi-exposure capture also ``exposure_a`` (uint8, 255 where no exposure measured)."""
        arrays: dict[str, np.ndarray] = {}
        for name, axis in self.axes.items():
            arrays[f"modulation_{name}"] = axis.modulation.astype(np.float32, copy=False)
            arrays[f"noise_{name}"] = axis.noise.astype(np.float32, copy=False)
            arrays[f"reason_{name}"] = axis.reason.astype(np.uint8, copy=False)
            if name in self.exposure:
                arrays[f"exposure_{name}"] = self.exposure[name].astype(np.uint8, copy=False)
        return arrays

    def summary(self) -> dict[str, Any]:
        """JSON-ready counts per axis and reason, slips, saturated pixels, the options; for a
        multi-exposure capture the exposures' names and, per axis, the pixels each measured."""
        exposures = self.exposure_summary()
        return {
            "shape": list(self.shape),
            "axes": {
                name: {
                    "decoded": int(axis.valid.sum()),
                    "slips_repaired": axis.slips_repaired,
                    "reasons": axis.reason_counts(),
                }
                for name, axis in self.axes.items()
            },
            "saturated_pixels": self.saturated_pixels,
            "options": self.options.to_dict(),
            **({"gray_levels": self.stats["gray_levels"]} if "gray_levels" in self.stats else {}),
            "codec_check": summary_of(self.codec_check),
            **({"exposures": exposures} if exposures is not None else {}),
        }

    def exposure_summary(self) -> dict[str, Any] | None:
        """A multi-exposure capture's exposures: ``{"names": [...], "pixels": {axis: {name: count,
        "none": count}}}`` (the pixels each exposure measured); None for a single stack."""
        if not self.exposure_names:
            return None
        return {
            "names": list(self.exposure_names),
            "pixels": {name: _exposure_pixels(index, self.exposure_names) for name, index in self.exposure.items()},
        }


def _exposure_pixels(index: np.ndarray, names: tuple[str, ...]) -> dict[str, int]:
    """Pixels per exposure name of an ``exposure_a`` map, and ``"none"`` (255)."""
    counts = np.bincount(index.ravel(), minlength=256)
    row = {name: int(counts[i]) for i, name in enumerate(names)}
    row["none"] = int(counts[255])
    return row


MIN_FRINGE_SHARE = 0.01
"""Least share of a stack's sampled pixels that must decode on some axis for :func:`fringe_refusal`."""


def fringe_refusal(images: npt.ArrayLike, codec: Codec, *, min_share: float = MIN_FRINGE_SHARE) -> str | None:
    """Why a camera stack does not show ``codec``'s fringes, in a sentence; None when it does.

    Decodes about 32 pairs of rows (:func:`~metrology.core.codecs.check.sampled_rows`), as the codec
    self-check does, and refuses the stack when

    - no axis decodes at least ``min_share`` of the sampled pixels: the frames hold no modulation
      (dark, flat, overexposed, the projector off or not seen); the sentence gives the share and
      the commonest reason;
    - an axis's self-check is ``inconsistent``: the coordinates do not follow the code (frames of
      random noise have a "modulation" of their own, but no gray word agrees with its phase).

    Parameters
    ----------
    images : (frames, H, W) array of uint8, uint16 or float
        The stack in ``codec``'s frame order, grey levels.
    codec : Codec
    min_share : float
        In (0, 1].
    """
    from metrology.core.codecs.check import sampled_rows

    stack = np.asarray(images)
    sample = np.ascontiguousarray(stack[:, sampled_rows(stack.shape[1])])
    decoding = decode_codec(sample, codec, with_noise=False, threads=1, paired_rows=True)
    shares = {name: float(axis.valid.mean()) for name, axis in decoding.axes.items()}
    if shares and max(shares.values()) < min_share:
        name = max(shares, key=lambda n: shares[n])
        counts = decoding.axes[name].reason_counts()
        reason, count = max(((r, c) for r, c in counts.items() if r != REASONS[REASON_VALID]), key=lambda rc: rc[1])
        total = max(1, sum(counts.values()))
        return (
            f"the frames show no fringes of the codec: {100 * shares[name]:.1f} % of the sampled pixels decode "
            f"(at least {100 * min_share:g} % needed; {100 * count / total:.0f} % {reason}); "
            "check that the projector is on and seen by the camera, and the exposure"
        )
    inconsistent = [
        f"axis {name}: {check.findings or check.message}"
        for name, check in decoding.codec_check.items()
        if check.status == INCONSISTENT
    ]
    if inconsistent:
        return (
            "the frames do not show the codec's fringes (their coordinates do not follow the code, as with "
            f"frames of random noise or another pattern): {'; '.join(inconsistent)}"
        )
    return None


# ----------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class _SequencePlan:
    frames: tuple[int, ...]
    weights: np.ndarray  # (3, N) float32: cos, -sin (so row 1 gives -S), ones
    steps: int
    period: float
    origin: float
    need_noise: bool
    # 8-bit stacks: C and -S by running weighted averages (OpenCV's accumulateWeighted reads the
    # uint8 frames directly): x_k = (1 - a_k) x_{k-1} + a_k I_k ends at K sum_k w_k I_k when
    # a_k = K w_k / prod_{j > k} (1 - a_j); rows: cos, -sin; K = recursive_scale
    recursive: np.ndarray = field(default_factory=lambda: np.zeros((2, 0)))
    recursive_scale: float = 1.0
    frame_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (N,) int64: frames
    # (2, N) float32: ``recursive`` as OpenCV's accumulateWeighted uses it, 0 where it skips a frame
    recursive_f32: np.ndarray = field(default_factory=lambda: np.zeros((2, 0), np.float32))


def _recursive_alphas(weights: np.ndarray) -> tuple[np.ndarray, float]:
    """The running-average factors ``a`` (2, N) float64 and the scale K of :class:`_SequencePlan`.

    K = 1 / (2 max_row sum |w|) keeps every product ``prod (1 - a_j)`` >= 1/2.
    """
    w = np.asarray(weights, np.float64)
    scale = 1.0 / (2.0 * float(np.abs(w).sum(axis=1).max()))
    alphas = np.zeros_like(w)
    for row in range(w.shape[0]):
        product = 1.0
        for k in range(w.shape[1] - 1, -1, -1):
            alphas[row, k] = scale * w[row, k] / product
            product *= 1.0 - alphas[row, k]
    return alphas, scale


def _kernel_alphas(alphas: np.ndarray) -> np.ndarray:
    """(2, N) float32: the running-average factors as :func:`_opencv_sums` applies them (float32;
    0 for the factors it skips, which leaves the average exactly as it is)."""
    return np.where(np.abs(alphas) > _SKIPPED_ALPHA, alphas, 0.0).astype(np.float32)


_SKIPPED_ALPHA = 1e-9
"""Running-average factors at most this small are skipped (sin 0 and cos(pi / 2) ~ 6e-17)."""


@dataclass(frozen=True)
class _AxisPlan:
    name: str
    axis: Axis
    extent: int
    sequences: tuple[_SequencePlan, ...]
    chain: tuple[Stage, ...]
    used: tuple[int, ...]  # phase sequences used by the chain
    final: tuple[int, ...]  # sequences whose B is the modulation (the final stage's)
    gray_lut: np.ndarray | None  # gray word -> centre, float32
    gray_positions: tuple[int, ...]  # bit position of each gray frame
    slip_period: float  # > 0 when slips are possible: period of the stage after the gray
    levels: LevelModel | None = None  # multi-level gray codes: level centres estimated from the stack


def _plan(codec: Codec, with_noise: bool = True) -> list[_AxisPlan]:
    plans = []
    for name, axis in codec.axes.items():
        chain = axis.chain()
        used: list[int] = []
        for stage in chain:
            for i in stage.indices:
                if i not in used:
                    used.append(i)
        last = chain[-1]
        final = last.indices
        noise_index = min(final, key=lambda j: axis.phase[j].period) if final else -1
        sequences = []
        for i, seq in enumerate(axis.phase):
            k = np.arange(seq.steps)
            delta = 2 * np.pi * seq.shift * k / seq.steps
            weights = np.stack([np.cos(delta), -np.sin(delta), np.ones(seq.steps)]).astype(np.float32)
            alphas, alpha_scale = _recursive_alphas(np.stack([np.cos(delta), -np.sin(delta)]))
            sequences.append(
                _SequencePlan(
                    seq.frames,
                    weights,
                    seq.steps,
                    seq.period,
                    seq.origin,
                    need_noise=with_noise and seq.steps >= 4 and i == noise_index,
                    recursive=alphas,
                    recursive_scale=alpha_scale,
                    frame_index=np.asarray(seq.frames, np.int64),
                    recursive_f32=_kernel_alphas(alphas),
                )
            )
        lut = None
        positions: tuple[int, ...] = ()
        slip = 0.0
        g = axis.gray
        if g is not None and g.levels != 2:
            positions, lut = digit_positions(g), centre_lut(g)
        elif g is not None:
            bits = g.bits
            positions = tuple(bits - 1 - i if g.order == "msb_first" else i for i in range(bits))
            words = np.arange(2**bits, dtype=np.int64)
            if g.inverted:
                words = words ^ (2**bits - 1)
            binary = binary_from_gray(words, n_bits=bits)
            lut = (g.origin + (binary + 0.5) * g.word).astype(np.float32)
            if len(chain) > 1 and chain[0].kind == "gray" and g.word >= chain[1].period:
                slip = chain[1].period
        plans.append(
            _AxisPlan(name, axis, codec.extent(name), tuple(sequences), chain, tuple(used), final, lut, positions, slip)
        )
    return plans


# ----------------------------------------------------------------------------- decoding
def validate_codec_stack(images: np.ndarray, codec: Codec) -> np.ndarray:
    """Check that ``images`` is a ``(frames, H, W)`` stack of ``codec``: returns it as an ndarray.

    Raises
    ------
    ValueError
        If the frame count differs from the codec's or the dtype is unsupported.
    """
    stack = np.asarray(images)
    if stack.ndim != 3 or 0 in stack.shape:
        raise ValueError(f"images must be a non-empty (frames, H, W) array, got shape {stack.shape}")
    if stack.shape[0] != codec.n_frames:
        raise ValueError(f"the stack holds {stack.shape[0]} frames but the codec describes {codec.n_frames}")
    if stack.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise ValueError(f"images must be uint8, uint16 or float, got dtype {stack.dtype}")
    return stack


def decode_codec(
    images: npt.ArrayLike,
    codec: Codec,
    options: CodecDecodeOptions | None = None,
    *,
    with_noise: bool = True,
    threads: int | None = None,
    paired_rows: bool = False,
) -> CodecDecoding:
    """Decode a stack of ``codec`` to absolute projector coordinates.

    Parameters
    ----------
    images : (frames, H, W) array of uint8, uint16 or float
        Camera images in the codec's frame order, grey levels.
    codec : Codec
    options : CodecDecodeOptions, optional
        Validity rules; defaults resolved per codec and bit depth (recorded in the result).
    with_noise : bool
        Compute the fit-residual noise maps (N >= 4); without them ``noise`` is NaN and the
        decoding skips the sums of squares (``gcps decode`` asks for them with ``--quality``).
    threads : int, optional
        Worker threads over row tiles (default :data:`~metrology.core.tiling.DEFAULT_THREADS`).
    paired_rows : bool
        The images are rows of a larger capture sampled in neighbouring pairs
        (:func:`~metrology.core.codecs.check.sampled_rows`), for the self-check.

    Returns
    -------
    CodecDecoding
        Per coded axis: coordinate, modulation, mean, noise (float32) and reason (uint8) maps.

    Raises
    ------
    ValueError
        If the stack does not match the codec.
    """
    stack = validate_codec_stack(np.asarray(images), codec)
    if stack.dtype == np.float64:
        stack = stack.astype(np.float32)
    opts = (options or CodecDecodeOptions()).resolved(codec, stack.dtype)
    _, height, width = stack.shape
    plans = [_with_levels(plan, stack, codec, opts) for plan in _plan(codec, with_noise)]
    outputs: dict[str, dict[str, np.ndarray]] = {}
    for plan in plans:
        outputs[plan.name] = {
            "coordinate": np.empty((height, width), np.float32),
            "modulation": np.empty((height, width), np.float32),
            "mean": np.empty((height, width), np.float32),
            "noise": np.empty((height, width), np.float32),
            "reason": np.empty((height, width), np.uint8),
        }
        if opts.repair_slips and plan.slip_period > 0:  # the decoded gray words bound the slip repair
            outputs[plan.name]["centre"] = np.empty((height, width), np.float32)
    # the self-check (check.py) reads some rows only: their coordinates before the tolerances
    # refuse anything and their gray words' centres are kept as the tiles pass them
    if paired_rows:
        sample_rows, top, under = np.arange(height, dtype=np.intp), np.arange(height, dtype=np.intp), np.empty(0)
    else:
        sample_rows, top, under = check_rows(height, width)
    samples = {
        plan.name: _RowSample(
            sample_rows,
            np.empty((sample_rows.size, width), np.float32),
            np.empty((sample_rows.size, width), np.float32),
        )
        for plan in plans
        if checkable(plan.axis)
    }
    judged_counts: dict[str, int] = dict.fromkeys(samples, 0)
    used_frames = sorted(
        {f for plan in plans for s in plan.used for f in plan.sequences[s].frames}
        | {f for plan in plans if plan.axis.gray is not None for f in plan.axis.gray.frames}
        | {
            f
            for plan in plans
            if plan.axis.gray is not None and plan.axis.gray.inverse_frames
            for f in plan.axis.gray.inverse_frames
        }
        | set(codec.white)
        | set(codec.black)
    )
    saturated_counts: list[int] = []
    candidates: dict[str, list[np.ndarray]] = {plan.name: [] for plan in plans}
    tile_starts: list[int] = []
    lock = threading.Lock()

    def run(rows: slice) -> None:
        n_sat, judged = _decode_tile(stack, rows, codec, plans, opts, outputs, used_frames, samples)
        found = {}
        for plan in plans:
            if opts.repair_slips and plan.slip_period > 0:
                found[plan.name] = slip_candidates(outputs[plan.name]["coordinate"][rows], plan.slip_period / 2)
                found[plan.name] += (rows.start or 0) * width
        with lock:
            saturated_counts.append(n_sat)
            tile_starts.append(rows.start or 0)
            for name, flat in found.items():
                candidates[name].append(flat)
            for name, count in judged.items():
                judged_counts[name] += count

    run_tiled(run, height, width, threads)
    # the self-check's rows, judged before the slip repair changes any reason (reasons 0, 3, 4)
    check_rows_of = {
        plan.name: (sample.coordinate, sample.centre, cv2.LUT(outputs[plan.name]["reason"][sample.rows], _JUDGED_LUT))
        for plan in plans
        if (sample := samples.get(plan.name)) is not None
    }

    def self_check() -> dict[str, AxisCheck]:
        checks: dict[str, AxisCheck] = {}
        for plan in plans:
            if plan.name not in check_rows_of:
                continue
            coordinate, centre, judged = check_rows_of[plan.name]
            rows_of = (coordinate, centre, judged.view(bool))
            if paired_rows:  # every row counts; vertical pairs (2k, 2k + 1)
                lower = tuple(a[1::2] for a in rows_of)
                upper = tuple(a[0 : 2 * lower[0].shape[0] : 2] for a in rows_of)
            else:  # views where the positions are evenly spaced (they are: every s-th row and the next)
                upper, lower = (
                    tuple(a[_evenly(top[: under.size])] for a in rows_of),
                    tuple(a[_evenly(under)] for a in rows_of),
                )
            checks[plan.name] = check_axis_rows(
                rows_of if paired_rows else tuple(a[_evenly(top)] for a in rows_of),  # type: ignore[arg-type]
                (upper, lower),  # type: ignore[arg-type]
                judged_counts[plan.name],
                plan.axis,
                plan.extent,
            )
            if checks[plan.name].status == INCONSISTENT and not paired_rows:  # name the likely correction
                checks[plan.name] = with_suggestion(checks[plan.name], stack, codec, plan.name, decode_codec, options)
        return checks

    # the check reads its own copies of the rows: it runs beside the slip repair on a pool thread
    checked = run_beside(self_check, threads if any(opts.repair_slips and p.slip_period > 0 for p in plans) else 1)
    axes: dict[str, AxisDecoding] = {}
    for plan in plans:
        out = outputs[plan.name]
        slips = 0
        if opts.repair_slips and plan.slip_period > 0:
            final_period = plan.chain[-1].period
            # jumps across the tiles' first rows (each tile saw only its own rows)
            for start in sorted(tile_starts):
                if start > 0:
                    pair = slip_candidates(out["coordinate"][start - 1 : start + 1], plan.slip_period / 2)
                    candidates[plan.name].append(pair + (start - 1) * width)
            found = np.concatenate(candidates[plan.name]) if candidates[plan.name] else np.empty(0, np.intp)
            assert plan.axis.gray is not None and opts.consistency_periods is not None
            reach = plan.axis.gray.word / 2 + opts.consistency_periods * plan.slip_period
            slips = repair_slips(
                out["coordinate"], out["reason"], plan.slip_period, final_period, found, out["centre"], reach
            )
        axes[plan.name] = AxisDecoding(
            coordinate=out["coordinate"],
            modulation=out["modulation"],
            mean=out["mean"],
            noise=out["noise"],
            reason=out["reason"],
            slips_repaired=slips,
        )
    levels = {plan.name: plan.levels.summary() for plan in plans if plan.levels is not None}
    return CodecDecoding(
        axes=axes,
        options=opts,
        saturated_pixels=int(sum(saturated_counts)),
        shape=(height, width),
        stats={"gray_levels": levels} if levels else {},
        codec_check=checked(),
    )


def _with_levels(plan: _AxisPlan, stack: np.ndarray, codec: Codec, opts: CodecDecodeOptions) -> _AxisPlan:
    """The plan with the level centres of its multi-level gray code estimated from ``stack`` (else as is)."""
    g = plan.axis.gray
    if g is None or g.levels == 2:
        return plan
    assert opts.min_modulation is not None
    first = plan.axis.phase[0] if plan.axis.phase else None
    model = sample_levels(stack, g, codec.white, codec.black, first, opts.min_modulation, f"axes.{plan.name}.gray")
    return replace(plan, levels=model)


def _evenly(index: np.ndarray) -> slice | np.ndarray:
    """``index`` (sorted intp positions) as a slice when evenly spaced (a view instead of a copy)."""
    if index.size == 0:
        return slice(0, 0)
    step = int(index[1] - index[0]) if index.size > 1 else 1
    if step > 0 and np.array_equal(index, np.arange(index[0], index[0] + step * index.size, step)):
        return slice(int(index[0]), int(index[0]) + step * index.size, step)
    return index


@dataclass(frozen=True, eq=False)
class _RowSample:
    """Rows of an axis kept for the self-check: ``rows`` (n,) intp sorted image rows; ``coordinate``
    (n, W) float32 before the tolerances refuse anything; ``centre`` (n, W) float32 gray word centres."""

    rows: np.ndarray
    coordinate: np.ndarray
    centre: np.ndarray


KERNELS_MODULE = "metrology.core.codecs.kernels"


def compiled_kernels() -> ModuleType | None:
    """:mod:`metrology.core.codecs.kernels` when this process has loaded it, else None.

    With it, an 8-bit tile is decoded by its compiled kernels (phase sums, saturation, gray
    words, reasons, slip search and repair) around the OpenCV calls whose rounding they keep
    (``cartToPolar``, ``addWeighted``), to the same bits as without it.
    Importing numba and loading the kernel from numba's disk cache cost 0.8-1.4 s in a fresh
    process on the reference machine, far more than the kernel saves on the one or two stacks a
    ``gcps decode`` or ``gcps measure`` decodes (20-30 ms of CPU per 2048x1536 stack of 18 phase
    frames, ``benchmarks/codecs.py``), so the decoder never imports it: it uses the kernel where
    a worker (:func:`metrology.jobs.handlers.preload_job_code`) or a caller decoding many stacks
    has loaded it. Both paths give the same bits.
    """
    return sys.modules.get(KERNELS_MODULE)


@dataclass(frozen=True, eq=False)
class _TilePixels:
    """A tile as the compiled kernel reads it: ``frames`` (F, H W) uint8 the stack's flattened
    frames (a view), the tile's pixels ``start:stop``, and the kernels' module."""

    frames: np.ndarray
    start: int
    stop: int
    kernels: ModuleType


def _decode_tile(
    stack: np.ndarray,
    rows: slice,
    codec: Codec,
    plans: list[_AxisPlan],
    opts: CodecDecodeOptions,
    outputs: dict[str, dict[str, np.ndarray]],
    used_frames: list[int],
    samples: Mapping[str, _RowSample],
) -> tuple[int, dict[str, int]]:
    """Decode the rows ``rows`` of every axis into ``outputs``; returns (saturated pixels, judged
    pixels per self-checked axis)."""
    scratch = thread_scratch()
    tile = stack[:, rows]
    h, w = tile.shape[1:]
    shape = (h, w)
    integer = stack.dtype.kind in "ui"
    pixels: _TilePixels | None = None
    kernels = compiled_kernels()
    if kernels is not None and stack.dtype == np.uint8 and stack.flags.c_contiguous:
        start = (rows.start or 0) * w
        pixels = _TilePixels(stack.reshape(stack.shape[0], -1), start, start + h * w, kernels)
    assert opts.saturation_level is not None

    # saturation: the brightest value of each pixel over the phase frames (refused) and over all (flagged)
    check_saturation = math.isfinite(opts.saturation_level) and not (
        integer and opts.saturation_level > np.iinfo(stack.dtype).max
    )
    phase_frames = sorted({f for plan in plans for i in plan.used for f in plan.sequences[i].frames})
    phase_saturated: np.ndarray | None = None
    n_saturated = 0
    gray_saturation: _GraySaturation | None = None
    # with the compiled kernels, every phase sequence's sums come first: they also give the
    # brightest phase frame, so that the saturation check reads only the other frames again
    precomputed: dict[str, dict[int, _PhaseResult]] = {}
    if pixels is not None:
        phase_peak = scratch.get("phase_peak", shape, np.uint8) if check_saturation and phase_frames else None
        peak_mode = 1
        for plan in plans:
            out = outputs[plan.name]
            results = precomputed[plan.name] = {}
            for i in plan.used:
                results[i] = _phase_tile(
                    tile,
                    plan.sequences[i],
                    bool(opts.exact_phase),
                    scratch,
                    f"{plan.name}{i}",
                    modulation_dst=out["modulation"][rows] if plan.final == (i,) else None,
                    noise_dst=out["noise"][rows] if plan.sequences[i].need_noise else None,
                    pixels=pixels,
                    peak=phase_peak,
                    peak_mode=peak_mode if phase_peak is not None else 0,
                )
                peak_mode = 2
    if check_saturation:
        level = stack.dtype.type(opts.saturation_level) if integer else np.float32(opts.saturation_level)
        peak = scratch.get("peak", shape, stack.dtype)
        others = [f for f in used_frames if f not in phase_frames]
        gray = plans[0].axis.gray if len(plans) == 1 else None
        if (
            pixels is not None
            and phase_peak is not None
            and gray is not None
            and gray.levels == 2
            and (set(others) == set(gray.frames) | set(gray.inverse_frames or ()))
        ):
            # the frames besides the phase frames are the gray code's: its pass checks them
            phase_saturated = scratch.get("phase_sat", shape, bool)
            gray_saturation = _GraySaturation(phase_peak.reshape(-1), int(level))
        elif pixels is not None:
            # one pass over the frames instead of a maximum per frame and three comparisons
            phase_saturated = scratch.get("phase_sat", shape, bool)
            n_saturated = pixels.kernels.saturation_u8(
                pixels.frames,
                pixels.start,
                pixels.stop,
                phase_peak.reshape(-1) if phase_peak is not None else np.empty(0, np.uint8),
                np.asarray(others, np.int64),
                int(level),
                phase_saturated.reshape(-1),
            )
            if not phase_frames:
                phase_saturated = None
        elif phase_frames:
            _max_into(peak, tile, phase_frames)
            phase_saturated = np.greater_equal(peak, level, out=scratch.get("phase_sat", shape, bool))
            for f in others:
                np.maximum(peak, tile[f], out=peak)
        else:
            _max_into(peak, tile, others)
        if pixels is None:
            n_saturated = int(np.count_nonzero(peak >= level))

    # white / black threshold, shared by the axes
    white_black: np.ndarray | None = None
    white_black_half: np.ndarray | None = None
    white_black_mid: np.ndarray | None = None
    if codec.white and codec.black:
        wmean = _mean_of(tile, codec.white, scratch.get("wmean", shape, np.float32))
        bmean = _mean_of(tile, codec.black, scratch.get("bmean", shape, np.float32))
        white_black_mid = np.add(wmean, bmean, out=scratch.get("wbmid", shape, np.float32))
        white_black_mid *= np.float32(0.5)
        white_black_half = np.subtract(wmean, bmean, out=wmean)
        white_black_half *= np.float32(0.5)
        white_black = np.floor(white_black_mid).astype(stack.dtype) if integer else white_black_mid

    judged: dict[str, int] = {}
    for plan in plans:
        out = {key: value[rows] for key, value in outputs[plan.name].items()}
        sample = samples.get(plan.name)
        local: np.ndarray | None = None
        if sample is not None:
            start = rows.start or 0
            lo, hi = np.searchsorted(sample.rows, (start, start + h))
            local = sample.rows[lo:hi] - start
            out["sample_coordinate"] = sample.coordinate[lo:hi]
            out["sample_centre"] = sample.centre[lo:hi]
        count = _decode_axis_tile(
            tile,
            plan,
            opts,
            out,
            integer,
            phase_saturated,
            white_black,
            white_black_half,
            white_black_mid,
            scratch,
            local,
            pixels,
            precomputed.get(plan.name),
            gray_saturation,
        )
        if sample is not None:
            judged[plan.name] = count
    if gray_saturation is not None:
        n_saturated = gray_saturation.count
    return n_saturated, judged


@dataclass
class _GraySaturation:
    """The saturation check left to the gray code's compiled pass: ``peak`` (h w,) uint8 the
    brightest phase frame, ``level`` the saturation level; the pass writes ``count``, the pixels
    saturated in some frame (and the axis's ``phase_saturated``)."""

    peak: np.ndarray
    level: int
    count: int = 0


def _max_into(peak: np.ndarray, tile: np.ndarray, frames: list[int]) -> None:
    np.copyto(peak, tile[frames[0]])
    for f in frames[1:]:
        np.maximum(peak, tile[f], out=peak)


def _mean_of(tile: np.ndarray, frames: tuple[int, ...], out: np.ndarray) -> np.ndarray:
    np.copyto(out, tile[frames[0]], casting="unsafe")
    for f in frames[1:]:
        np.add(out, tile[f], out=out, casting="unsafe")
    if len(frames) > 1:
        out *= np.float32(1 / len(frames))
    return out


@dataclass
class _PhaseResult:
    frac: np.ndarray  # (h, w) float32 in [0, 1): theta / 2 pi
    modulation: np.ndarray  # B
    total: np.ndarray  # sum of the frames (N A)
    noise: np.ndarray | None


def _phase_tile(
    tile: np.ndarray,
    seq: _SequencePlan,
    exact: bool,
    scratch: Any,
    tag: str,
    modulation_dst: np.ndarray | None = None,
    noise_dst: np.ndarray | None = None,
    pixels: _TilePixels | None = None,
    peak: np.ndarray | None = None,
    peak_mode: int = 0,
) -> _PhaseResult:
    """Least-squares phase, modulation, sum and (N >= 4, when asked) noise of one sequence on a tile.

    The sum and the sum of squares come from OpenCV's accumulators reading the frames directly
    (float32 for 8-bit stacks, whose sums stay exact integers below 2**24; float64 otherwise).
    8-bit stacks: ``K C`` and ``-K S`` are running weighted averages over the uint8 frames
    (``cv2.accumulateWeighted``, one in-cache pass per frame and sum, factors from
    :func:`_recursive_alphas`), the scale K divided out of B and the noise. Other stacks: ``C``
    and ``-S`` from ``einsum`` in float64 (numpy's own loops: OpenBLAS threads busy-wait badly
    on a shared machine) over the differences of frames half a turn apart when N is even. The
    noise ``R = sum I^2 - (sum I)^2 / N - (N / 2) B^2`` with ``(N / 2) B^2 = (2 / N)(C^2 + S^2)``.

    With ``pixels`` (an 8-bit tile, the compiled kernel loaded: :func:`compiled_kernels`) the same
    four sums, to the bit, come from :func:`metrology.core.codecs.kernels.phase_sums_u8` in one
    pass over the frames instead.

    ``modulation_dst`` and ``noise_dst`` (h, w) float32, optional: where B and the noise are
    written (else scratch arrays). ``peak`` (h, w) uint8, with ``pixels`` only: the brightest of
    the sequence's frames written (``peak_mode`` 1) or maxed into it (2).
    """
    h, w = tile.shape[1:]
    n = seq.steps
    work = np.float32 if tile.dtype == np.uint8 else np.float64
    total = scratch.get(f"total{tag}", (h, w), work)
    sq = scratch.get(f"squares{work.__name__}", (h, w), work) if seq.need_noise else None
    res = scratch.get(f"sums{tag}", (2, h * w), work)
    scale = seq.recursive_scale  # c and neg_s below are K C and -K S
    if pixels is not None and tile.dtype == np.uint8:
        pixels.kernels.phase_sums_u8(
            pixels.frames,
            pixels.start,
            pixels.stop,
            seq.frame_index,
            seq.recursive_f32,
            total.reshape(-1),
            res[0],
            res[1],
            (sq if sq is not None else total).reshape(-1),
            sq is not None,
            peak.reshape(-1) if peak is not None else np.empty(0, np.uint8),
            peak_mode if peak is not None else 0,
        )
    else:
        scale = _opencv_sums(tile, seq, total, sq, res, scratch)
    c, neg_s = (res[i].reshape(h, w) for i in range(2))
    mag = scratch.get(f"mag{tag}", (h, w), np.float32)
    angle = scratch.get(f"angle{tag}", (h, w), np.float32)
    if exact:
        np.copyto(angle, np.arctan2(neg_s, c), casting="unsafe")
        angle += np.float32(TWO_PI) * (angle < 0)
        np.copyto(mag, np.hypot(c, neg_s), casting="unsafe")
    else:
        cv2.cartToPolar(c, neg_s, magnitude=mag, angle=angle)
    if pixels is not None and not exact and work is np.float32:
        # the compiled kernel: frac, the noise and B in one pass, to the bits of the passes below
        b_dst = modulation_dst if modulation_dst is not None else mag
        noise_out = noise_dst if noise_dst is not None else sq
        pixels.kernels.phase_finish(
            angle.reshape(-1),
            mag.reshape(-1),
            total.reshape(-1),
            (sq if sq is not None else total).reshape(-1),
            sq is not None,
            1 / n,
            2 / n / scale**2,
            1 / (n - 3) if n > 3 else 1.0,
            2 / n / scale,
            (noise_out if noise_out is not None else total).reshape(-1),
            b_dst.reshape(-1),
        )
        return _PhaseResult(frac=angle, modulation=b_dst, total=total, noise=noise_out)
    # frac in [0, 1]: frac = 1 (theta = 2 pi) unwraps like 0, the rounding below absorbs it
    frac = np.multiply(angle, np.float32(1 / TWO_PI), out=angle)
    noise = None
    if sq is not None and work is np.float32:
        # 8-bit: sum I^2 is an exact integer below 2**24; (sum I)^2 / N ~ 1e6 keeps ~0.1 grey^2;
        # (C^2 + S^2) (2 / N) from the magnitude, in fused OpenCV passes
        t = scratch.get("resid_t", (h, w), np.float32)
        cv2.multiply(total, total, dst=t, scale=1 / n)
        cv2.subtract(sq, t, dst=sq)
        cv2.multiply(mag, mag, dst=t, scale=2 / n / scale**2)
        cv2.subtract(sq, t, dst=sq)
        np.maximum(sq, 0, out=sq)
        sq *= np.float32(1 / (n - 3))
        noise = np.sqrt(sq, out=noise_dst if noise_dst is not None else sq)
    b = np.multiply(mag, np.float32(2 / n / scale), out=modulation_dst if modulation_dst is not None else mag)
    if sq is not None and work is not np.float32:
        # 16-bit and float: combined in float64 (a small difference of large sums)
        r = sq.ravel().astype(np.float64)
        cc, ss, tt = c.ravel(), neg_s.ravel(), total.ravel()
        r -= (cc * cc + ss * ss) * (2 / n) + tt * tt * (1 / n)
        np.maximum(r, 0, out=r)
        r *= 1 / (n - 3)
        noise = noise_dst if noise_dst is not None else np.empty((h, w), np.float32)
        np.copyto(noise, np.sqrt(r).reshape(h, w), casting="unsafe")
    total32 = total if total.dtype == np.float32 else total.astype(np.float32)
    return _PhaseResult(frac=frac, modulation=b, total=total32, noise=noise)


def _opencv_sums(
    tile: np.ndarray, seq: _SequencePlan, total: np.ndarray, sq: np.ndarray | None, res: np.ndarray, scratch: Any
) -> float:
    """The sums of :func:`_phase_tile` by OpenCV passes and ``einsum``: writes ``total`` (h, w),
    ``sq`` (h, w, when given) and ``res`` (2, h w) = ``K C`` and ``-K S`` (float32 for 8-bit tiles,
    float64 otherwise); returns K (1 but for the 8-bit running averages)."""
    h, w = tile.shape[1:]
    n = seq.steps
    work = total.dtype.type
    cv_work = cv2.CV_32F if work is np.float32 else cv2.CV_64F
    frames = seq.frames
    total.fill(0)
    if sq is not None:
        sq.fill(0)
    for fi in frames:  # OpenCV's accumulators read the 8/16-bit frames directly
        cv2.accumulate(tile[fi], total)
        if sq is not None:
            cv2.accumulateSquare(tile[fi], sq)
    if work is np.float32:
        # 8-bit: one running weighted average per sum, reading the uint8 frames directly
        sums = res.reshape(2, h, w)
        sums.fill(0)
        for row in range(2):
            for k, fi in enumerate(frames):
                alpha = float(seq.recursive[row, k])
                if abs(alpha) > _SKIPPED_ALPHA:  # sin 0 and cos(pi / 2) ~ 6e-17 leave the average as it is
                    cv2.accumulateWeighted(tile[fi], sums[row], alpha)
        return seq.recursive_scale
    if n % 2 == 0:
        # cos and sin change sign half a turn later: C = sum_{k < N/2} cos_k (I_k - I_{k + N/2}), same for S
        half = n // 2
        d = scratch.get(f"pairs{work.__name__}", (half, h, w), work)
        for k in range(half):
            cv2.subtract(tile[frames[k]], tile[frames[k + half]], dst=d[k], dtype=cv_work)
        np.einsum("ik,kj->ij", seq.weights[:2, :half].astype(work, copy=False), d.reshape(half, h * w), out=res)
    else:
        f = scratch.get(f"frames{work.__name__}", (n, h, w), work)
        for k, fi in enumerate(frames):
            np.copyto(f[k], tile[fi], casting="unsafe")
        np.einsum("ik,kj->ij", seq.weights[:2].astype(work, copy=False), f.reshape(n, h * w), out=res)
    return 1.0


def _decode_axis_tile(
    tile: np.ndarray,
    plan: _AxisPlan,
    opts: CodecDecodeOptions,
    out: dict[str, np.ndarray],
    integer: bool,
    phase_saturated: np.ndarray | None,
    white_black: np.ndarray | None,
    white_black_half: np.ndarray | None,
    white_black_mid: np.ndarray | None,
    scratch: Any,
    sample_rows: np.ndarray | None = None,
    pixels: _TilePixels | None = None,
    precomputed: Mapping[int, _PhaseResult] | None = None,
    gray_saturation: _GraySaturation | None = None,
) -> int:
    """Decode one axis on a tile into ``out`` (views of the outputs' rows); ``sample_rows``: the
    tile's rows kept for the self-check (into ``out["sample_coordinate"]``, ``out["sample_centre"]``);
    ``precomputed``: the chain's phase sequences already decoded on the tile (with the kernels);
    ``gray_saturation``: the saturation check the gray pass makes (writing ``phase_saturated``).
    Returns the pixels the self-check judges (reasons 0, 3, 4), 0 without ``sample_rows``."""
    h, w = tile.shape[1:]
    shape = (h, w)
    assert opts.min_modulation is not None and opts.min_inverse_contrast is not None
    assert opts.consistency_periods is not None and opts.unwrap_consistency_periods is not None
    exact = bool(opts.exact_phase)
    min_mod = np.float32(opts.min_modulation)
    dark = scratch.get(f"dark{plan.name}", shape, bool)
    dark.fill(False)
    results: dict[int, _PhaseResult] = {}
    for i in plan.used:
        # the final sequence's B and noise go straight into the outputs
        r = results[i] = (
            precomputed[i]
            if precomputed is not None
            else _phase_tile(
                tile,
                plan.sequences[i],
                exact,
                scratch,
                f"{plan.name}{i}",
                modulation_dst=out["modulation"] if plan.final == (i,) else None,
                noise_dst=out["noise"] if plan.sequences[i].need_noise else None,
                pixels=pixels,
            )
        )
        dark |= r.modulation < min_mod
    first_total: np.ndarray | None = None
    first: _PhaseResult | None = None
    if plan.axis.phase:
        first = results.get(0)
        if first is None:  # the gray threshold (and the mean map) need the first sequence
            first = _phase_tile(tile, plan.sequences[0], exact, scratch, f"{plan.name}0", pixels=pixels)
        first_total = first.total
    mean = out["mean"]
    if first_total is not None:
        np.multiply(first_total, np.float32(1 / plan.sequences[0].steps), out=mean)
    elif white_black_mid is not None:
        np.copyto(mean, white_black_mid)
    else:
        mean.fill(np.nan)

    # gray code
    centre: np.ndarray | None = None
    low_contrast: np.ndarray | None = None
    ambiguous: np.ndarray | None = None
    min_contrast: np.ndarray | None = None
    g = plan.axis.gray
    # the gray words' centres go straight to the output when it is kept (slip repair)
    centre_dst = out["centre"] if "centre" in out else scratch.get(f"centre{plan.name}", shape, np.float32)
    if g is not None and g.levels != 2:
        assert plan.gray_lut is not None and plan.levels is not None
        # references: black and white frames, else the first phase sequence's A -+ B
        lo = scratch.get(f"mllo{plan.name}", shape, np.float32)
        span = scratch.get(f"mlspan{plan.name}", shape, np.float32)
        if white_black_mid is not None and white_black_half is not None:
            np.subtract(white_black_mid, white_black_half, out=lo)
            np.multiply(white_black_half, np.float32(2), out=span)
        else:
            assert first is not None  # validation: a gray code has a threshold source
            np.subtract(mean, first.modulation, out=lo)
            np.multiply(first.modulation, np.float32(2), out=span)
        # a digit misread at a word edge gives the neighbouring word, which a phase stage of at
        # least two words' period unwraps correctly: such pixels are kept
        chain = plan.chain
        adjacent_ok = len(chain) > 1 and chain[0].kind == "gray" and chain[1].period >= 2 * g.word
        index, ambiguous = classify_tile(
            tile, g, plan.levels, lo, span, scratch, plan.name, resolve_adjacent=adjacent_ok
        )
        centre = np.take(plan.gray_lut, index, out=centre_dst)
    elif g is not None and pixels is not None:
        # the compiled kernel: thresholds, bits, word and centre in one pass over the gray frames
        assert plan.gray_lut is not None
        empty_u8 = np.empty(0, np.uint8)
        if g.inverse_frames is not None:
            mode, inverse_index = 2, np.asarray(g.inverse_frames, np.int64)
            low_contrast = scratch.get(f"lowc{plan.name}", shape, bool)
            min_contrast = scratch.get(f"minc{plan.name}", shape, np.uint8)
        else:
            mode, inverse_index = (1 if white_black is not None else 0), np.empty(0, np.int64)
        assert mode != 0 or first_total is not None
        count = pixels.kernels.gray_words_u8(
            pixels.frames,
            pixels.start,
            pixels.stop,
            np.asarray(g.frames, np.int64),
            np.left_shift(1, np.asarray(plan.gray_positions, np.int64)),
            plan.gray_lut,
            mode,
            first_total.reshape(-1) if mode == 0 and first_total is not None else np.empty(0, np.float32),
            plan.sequences[0].steps if plan.sequences else 1,
            white_black.reshape(-1) if mode == 1 and white_black is not None else empty_u8,
            inverse_index,
            min_contrast.reshape(-1) if min_contrast is not None else empty_u8,
            low_contrast.reshape(-1) if low_contrast is not None else np.empty(0, bool),
            float(opts.min_inverse_contrast),
            centre_dst.reshape(-1),
            gray_saturation.peak if gray_saturation is not None else empty_u8,
            gray_saturation.level if gray_saturation is not None else 255,
            phase_saturated.reshape(-1)
            if gray_saturation is not None and phase_saturated is not None
            else np.empty(0, bool),
        )
        if gray_saturation is not None:
            gray_saturation.count = count
        centre = centre_dst
    elif g is not None:
        assert plan.gray_lut is not None
        word_dtype = np.uint8 if g.bits <= 8 else np.uint16
        word = scratch.get(f"word{plan.name}", shape, word_dtype)
        word.fill(0)
        weighted = scratch.get(f"weighted{plan.name}", shape, word_dtype)
        bit = scratch.get("bit", shape, bool)
        threshold: np.ndarray | None = None
        if g.inverse_frames is None:
            if white_black is not None:
                threshold = white_black
            else:
                assert first_total is not None
                n0 = np.float32(plan.sequences[0].steps)
                if tile.dtype == np.uint8:
                    # floor(S / N) = round((S - (N - 1) / 2) / N) for an integer sum S (no ties), and
                    # frame > A <=> frame > floor(A) for integer frames; saturating 8-bit output
                    n_steps = plan.sequences[0].steps
                    threshold = cv2.convertScaleAbs(
                        first_total,
                        dst=scratch.get(f"threshold{plan.name}", shape, np.uint8),
                        alpha=1 / n_steps,
                        beta=-(n_steps - 1) / (2 * n_steps),
                    )
                elif integer:
                    # floor((sum + 0.5) / N) = floor(A) exactly for integer sums: frame > A <=> frame > floor(A)
                    t = (first_total + np.float32(0.5)) / n0
                    threshold = np.floor(t, out=t).astype(tile.dtype)
                else:
                    threshold = first_total / n0
        else:
            low_contrast = scratch.get(f"lowc{plan.name}", shape, bool)
            low_contrast.fill(False)
            min_contrast = scratch.get(f"minc{plan.name}", shape, tile.dtype)
            min_contrast.fill(np.iinfo(tile.dtype).max if integer else np.inf)
            contrast = scratch.get("contrast", shape, tile.dtype)
        for i, f in enumerate(g.frames):
            frame = tile[f]
            if g.inverse_frames is not None:
                assert low_contrast is not None and min_contrast is not None
                inverse = tile[g.inverse_frames[i]]
                np.greater(frame, inverse, out=bit)
                cv2.absdiff(frame, inverse, dst=contrast)
                np.minimum(min_contrast, contrast, out=min_contrast)
            else:
                assert threshold is not None
                np.greater(frame, threshold, out=bit)
            np.multiply(bit.view(np.uint8), word_dtype(1 << plan.gray_positions[i]), out=weighted)
            np.bitwise_or(word, weighted, out=word)
        if min_contrast is not None and low_contrast is not None:
            np.less(min_contrast, np.float32(opts.min_inverse_contrast), out=low_contrast)
        if word_dtype == np.uint8:
            lut = np.full(256, np.nan, np.float32)
            lut[: plan.gray_lut.size] = plan.gray_lut
            centre = cv2.LUT(word, lut, dst=centre_dst)
        else:
            centre = np.take(plan.gray_lut, word, out=centre_dst)
    if g is not None:
        assert centre is not None
        if sample_rows is not None:
            np.take(centre, sample_rows, axis=0, out=out["sample_centre"])
        if not plan.used:
            # gray-only chain: modulation from white/black, else half the smallest inverse contrast,
            # else the B of the phase sequence that gives the threshold
            modulation = out["modulation"]
            if white_black_half is not None:
                np.copyto(modulation, white_black_half)
            elif min_contrast is not None:
                np.multiply(min_contrast, np.float32(0.5), out=modulation, casting="unsafe")
            else:
                assert first is not None  # validation: a gray code has a threshold source
                np.copyto(modulation, first.modulation)
            dark |= ~(modulation >= min_mod)

    # unwrapping chain, coarse to fine
    x = out["coordinate"]
    inconsistent: np.ndarray | None = None
    previous: Stage | None = None
    tmp = scratch.get("unwrap_tmp", shape, np.float32)
    for stage in plan.chain:
        if stage.kind == "gray":
            assert centre is not None
            np.copyto(x, centre)
            previous = stage
            continue
        frac = _stage_frac(stage, results, scratch, shape)
        # x_w = origin + P frac; x = x_w + P round((x_c - x_w) / P) = origin + P (frac + round((x_c - origin)/P - frac))
        if previous is None:
            x.fill((plan.extent - 1) / 2)
        # k = round((x_c - origin) / P - frac); x = origin + P (frac + k), two fused passes
        cv2.addWeighted(x, 1 / stage.period, frac, -1.0, -stage.origin / stage.period, dst=tmp)
        if previous is not None and previous.kind != "gray":
            # a phase stage unwrapped from another: |x - x_c| = P |t - round(t)| must stay within
            # the tolerance (a coarse coordinate that far off is too close to a wrong period)
            deviation = scratch.get("unwrap_dev", shape, np.float32)
            cv2.absdiff(tmp, np.rint(tmp, out=deviation), dst=deviation)
            limit = np.float32(opts.unwrap_consistency_periods)
            if inconsistent is None:
                inconsistent = np.greater(deviation, limit, out=scratch.get(f"incons{plan.name}", shape, bool))
            else:
                inconsistent |= deviation > limit
        np.rint(tmp, out=tmp)
        cv2.addWeighted(tmp, stage.period, frac, stage.period, stage.origin, dst=x)
        if centre is not None and g is not None:
            # every phase stage (not only the first: a beat wider than the word is unwrapped by
            # the word almost vacuously, and its noise can move the finer stages by whole periods)
            tolerance = np.float32(g.word / 2 + opts.consistency_periods * stage.period)
            cv2.absdiff(x, centre, dst=tmp)
            if inconsistent is None:
                inconsistent = np.greater(tmp, tolerance, out=scratch.get(f"incons{plan.name}", shape, bool))
            else:
                inconsistent |= tmp > tolerance
        previous = stage

    if plan.used:
        final = [results[i].modulation for i in plan.final]
        if len(final) == 1:
            if final[0] is not out["modulation"]:
                np.copyto(out["modulation"], final[0])
        else:
            np.minimum(final[0], final[1], out=out["modulation"])
            for more in final[2:]:  # a final beat of beats
                np.minimum(out["modulation"], more, out=out["modulation"])
    noise_out = out["noise"]
    noise = next((results[i].noise for i in plan.used if results[i].noise is not None), None)
    if noise is not None:
        if noise is not noise_out:
            np.copyto(noise_out, noise)
    else:
        noise_out.fill(np.nan)

    if pixels is not None:
        # the compiled kernel: the reasons and the NaN of the refused pixels in one pass
        if sample_rows is not None:
            np.take(x, sample_rows, axis=0, out=out["sample_coordinate"])
        none = np.empty(0, bool)
        masks = [
            m.reshape(-1) if m is not None else none
            for m in (inconsistent, low_contrast, phase_saturated if plan.used else None, dark, ambiguous)
        ]
        judged = pixels.kernels.reasons(x.reshape(-1), -0.5, plan.extent - 0.5, *masks, out["reason"].reshape(-1))
        return judged if sample_rows is not None else 0

    # reasons: the flags form a 6-bit index (ambiguous level 32, dark 16, saturated 8, low contrast 4,
    # inconsistent 2, outside 1) that a table turns into the first applicable reason
    flags = scratch.get("flags", shape, np.uint8)
    flag = scratch.get("flag", shape, np.uint8)
    inside = np.greater_equal(x, np.float32(-0.5), out=scratch.get("inside", shape, bool))
    inside &= x <= np.float32(plan.extent - 0.5)
    np.subtract(np.uint8(1), inside.view(np.uint8), out=flags)
    for mask, weight in (
        (inconsistent, 2),
        (low_contrast, 4),
        (phase_saturated if plan.used else None, 8),
        (dark, 16),
        (ambiguous, 32),
    ):
        if mask is not None:
            np.multiply(mask.view(np.uint8), np.uint8(weight), out=flag)
            np.bitwise_or(flags, flag, out=flags)
    reason = cv2.LUT(flags, _REASON_LUT, dst=out["reason"])
    judged = 0
    if sample_rows is not None:
        np.take(x, sample_rows, axis=0, out=out["sample_coordinate"])
        judged = cv2.countNonZero(cv2.LUT(reason, _JUDGED_LUT, dst=flag))
    x += cv2.LUT(reason, _NAN_UNLESS_VALID_LUT, dst=scratch.get("nan_or_zero", shape, np.float32))
    return judged


def _stage_frac(stage: Stage, results: Mapping[int, _PhaseResult], scratch: Any, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) float32 ``theta / 2 pi`` of a phase or beat stage, in [0, 1].

    A beat is ``frac_s - frac_l`` (+1 where negative), s its operand of the shorter period;
    operands that are beats are computed first, recursively (beats of beats).
    """
    if stage.kind == "phase":
        return results[stage.indices[0]].frac
    short, long_ = stage.ordered_parts()
    frac_s = _stage_frac(short, results, scratch, shape)
    frac_l = _stage_frac(long_, results, scratch, shape)
    # one scratch array per beat of the tree, named by its operand text
    frac = np.subtract(frac_s, frac_l, out=scratch.get(f"beat{stage.operand}", shape, np.float32))
    frac += np.float32(1) * (frac < 0)
    return frac


def _reason_lut() -> np.ndarray:
    lut = np.zeros(256, np.uint8)
    for index in range(64):
        for bit, code in (
            (16, REASON_TOO_DARK),
            (8, REASON_SATURATED),
            (4, REASON_LOW_INVERSE_CONTRAST),
            (32, REASON_LEVEL_AMBIGUOUS),
            (2, REASON_INCONSISTENT),
            (1, REASON_OUTSIDE),
        ):
            if index & bit:
                lut[index] = code
                break
    return lut


_REASON_LUT = _reason_lut()
_JUDGED_LUT = np.isin(np.arange(256), (REASON_VALID, REASON_OUTSIDE, REASON_INCONSISTENT)).astype(np.uint8)
_NAN_UNLESS_VALID_LUT = np.where(np.arange(256) == REASON_VALID, 0, np.nan).astype(np.float32)


def slip_candidates(x: np.ndarray, half_period: float) -> np.ndarray:
    """Flat indices (into ``x``) of pixels differing by more than ``half_period`` from a 4-neighbour.

    ``x``: (h, W) float32 coordinates, NaN where invalid (NaN never counts as a jump).
    """
    half = float(half_period)
    h, w = x.shape
    # 1 where a jump (NaN compares false); a tile without any needs no index search. The
    # differences go to per-thread scratch arrays (fresh large arrays cost page faults)
    scratch = thread_scratch()
    kernels = compiled_kernels()
    if kernels is not None and x.dtype == np.float32 and x.flags.c_contiguous:
        # a tile's indices in the thread's scratch; a whole frame's (a caller without candidates) not kept
        found = scratch.get("jump_flat", (h * w,), np.intp) if h * w <= 1 << 18 else np.empty(h * w, np.intp)
        return found[: kernels.jump_pixels(x, half, found)].copy()
    mx = my = None
    if w > 1:
        dx = cv2.absdiff(x[:, 1:], x[:, :-1], dst=scratch.get("jump_dx", (h, w - 1), np.float32))
        mx = np.greater(dx, half, out=scratch.get("jump_mx", (h, w - 1), bool)).view(np.uint8)
    if h > 1:
        dy = cv2.absdiff(x[1:, :], x[:-1, :], dst=scratch.get("jump_dy", (h - 1, w), np.float32))
        my = np.greater(dy, half, out=scratch.get("jump_my", (h - 1, w), bool)).view(np.uint8)
    if not any(m is not None and cv2.countNonZero(m) for m in (mx, my)):
        return np.empty(0, np.intp)
    jump = scratch.get("jump", (h, w), np.uint8)
    jump.fill(0)
    if mx is not None:
        cv2.bitwise_or(jump[:, 1:], mx, dst=jump[:, 1:])
        cv2.bitwise_or(jump[:, :-1], mx, dst=jump[:, :-1])
    if my is not None:
        cv2.bitwise_or(jump[1:, :], my, dst=jump[1:, :])
        cv2.bitwise_or(jump[:-1, :], my, dst=jump[:-1, :])
    points = cv2.findNonZero(jump)  # (n, 1, 2) x, y in row-major order; far faster than flatnonzero
    if points is None:
        return np.empty(0, np.intp)
    xy = points.reshape(-1, 2).astype(np.intp)
    return xy[:, 1] * w + xy[:, 0]


def repair_slips(
    coordinate: np.ndarray,
    reason: np.ndarray,
    slip_period: float,
    final_period: float,
    candidates: np.ndarray | None = None,
    centre: np.ndarray | None = None,
    cell_reach: float = math.inf,
) -> int:
    """Repair whole-period slips against the 5x5 median, in place; returns the number repaired.

    Candidates are valid pixels differing by more than ``slip_period / 2`` from a valid
    4-neighbour. A candidate whose 5x5 neighbourhood holds at least 13 valid coordinates and
    lies more than ``slip_period / 2`` from their median ``m`` is moved to
    ``x' = x + P_f round(P round((m - x) / P) / P_f)`` (P the slip period, P_f the final stage's)
    and given reason 6, provided ``x'`` could have been read as the pixel's gray word: a bit
    misread at a word edge puts the true coordinate at that edge, so ``|x' - centre| <= cell_reach``
    (``centre``: (H, W) float32 centres of the decoded gray words; ``cell_reach``: half the word
    plus the gray/phase tolerance). Without that bound a neighbourhood straddling a depth edge
    (two surfaces, the median on the other one) would move correct pixels by whole words.
    """
    x = coordinate
    half = np.float32(slip_period / 2)
    flat = slip_candidates(x, slip_period / 2) if candidates is None else np.unique(candidates)
    kernels = compiled_kernels()
    if kernels is not None and x.dtype == np.float32 and x.flags.c_contiguous and reason.flags.c_contiguous:
        bound = centre if centre is not None else np.empty((0, 0), np.float32)
        return int(
            kernels.repair_slips(
                x, reason, flat.astype(np.intp), slip_period, final_period, bound, cell_reach, REASON_SLIP_REPAIRED
            )
        )
    rows, cols = np.divmod(flat, x.shape[1])
    if rows.size == 0:
        return 0
    height, width = x.shape
    offsets = np.arange(-2, 3)
    row_index = rows[:, None, None] + offsets[None, :, None]
    col_index = cols[:, None, None] + offsets[None, None, :]
    inside = (row_index >= 0) & (row_index < height) & (col_index >= 0) & (col_index < width)
    window = x[np.clip(row_index, 0, height - 1), np.clip(col_index, 0, width - 1)]
    window[~inside] = np.nan  # beyond the image
    window = np.sort(window.reshape(rows.size, 25), axis=1)  # NaN sorts last
    count = np.count_nonzero(np.isfinite(window), axis=1)
    enough = count >= 13
    index = np.arange(rows.size)
    low = window[index, np.maximum(count - 1, 0) // 2]
    high = window[index, np.minimum(count // 2, 24)]
    med = np.where(enough, np.float32(0.5) * (low + high), np.float32(np.nan))
    values = x[rows, cols]
    with np.errstate(invalid="ignore"):
        slipped = enough & (np.abs(values - med) > half)
    if not slipped.any():
        return 0
    r, c = rows[slipped], cols[slipped]
    shift = slip_period * np.rint((med[slipped] - values[slipped]) / slip_period)
    snapped = final_period * np.rint(shift / final_period)
    moved = values[slipped] + snapped.astype(np.float32)
    if centre is not None:
        reachable = np.abs(moved - centre[r, c]) <= np.float32(cell_reach)
        r, c, moved = r[reachable], c[reachable], moved[reachable]
    x[r, c] = moved
    reason[r, c] = REASON_SLIP_REPAIRED
    return int(r.size)
