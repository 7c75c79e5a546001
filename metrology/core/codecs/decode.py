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
* the unwrapping chain, coarse to fine: a stage of period P turns the previous stage's
  coordinate ``x_c`` into ``x = x_w + P * round((x_c - x_w) / P)``; a beat of two sequences
  has ``theta_b = theta_s - theta_l`` and ``P_b = P_s P_l / (P_l - P_s)``; a first stage
  without gray code is unwrapped against the projector's centre (its period covers the
  projector); a gray-only axis gives the word's centre.

Reason codes (uint8, one per pixel and axis; the first that applies wins, in this order):
1 too dark (B of a phase sequence in the chain below ``min_modulation``; gray-only axes:
half the white-black difference, or half the smallest inverse contrast), 2 saturated (a
phase frame at or above ``saturation_level``), 5 low inverse contrast (``|frame - inverse|``
below ``min_inverse_contrast`` for some bit), 4 gray/phase inconsistent (the first phase
stage lies more than ``consistency_periods`` of its period outside the gray word's cell),
3 outside the projector (``x`` outside ``[-0.5, size - 0.5]``), 6 slip repaired but kept, 0
valid. Coordinates are NaN unless the reason is 0 or 6.

Slips: where the gray word is at least as wide as the period of the stage after it, a gray
bit misread at a cell edge moves a pixel by whole periods while staying consistent. Such
pixels are found against the median of the valid coordinates of their 5x5 neighbourhood
(at least 13 of 25 valid): where ``|x - median| > P / 2`` the pixel is moved by
``P * round((median - x) / P)`` (re-snapped onto the final stage's phase) and kept with reason 6.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Axis, Codec, Stage
from metrology.core.patterns import binary_from_gray
from metrology.core.tiling import run_tiled, thread_scratch

REASON_VALID = 0
REASON_TOO_DARK = 1
REASON_SATURATED = 2
REASON_OUTSIDE = 3
REASON_INCONSISTENT = 4
REASON_LOW_INVERSE_CONTRAST = 5
REASON_SLIP_REPAIRED = 6
REASONS: dict[int, str] = {
    REASON_VALID: "valid",
    REASON_TOO_DARK: "too dark",
    REASON_SATURATED: "saturated",
    REASON_OUTSIDE: "outside the projector",
    REASON_INCONSISTENT: "gray/phase inconsistent",
    REASON_LOW_INVERSE_CONTRAST: "low inverse contrast",
    REASON_SLIP_REPAIRED: "slip repaired but kept",
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
    saturation_level: float | None = None
    repair_slips: bool = True
    exact_phase: bool | None = None

    def __post_init__(self) -> None:
        for name in ("min_modulation", "min_inverse_contrast", "consistency_periods", "saturation_level"):
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
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
        saturation = self.saturation_level
        if saturation is None:
            saturation = full if integer else math.inf
        exact = self.exact_phase if self.exact_phase is not None else dt != np.uint8
        return CodecDecodeOptions(
            min_modulation=float(min_mod),
            min_inverse_contrast=float(contrast),
            consistency_periods=float(consistency),
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
        B of the chain's final phase sequence (a beat: the smaller of its two), grey levels;
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
    """

    axes: Mapping[str, AxisDecoding]
    options: CodecDecodeOptions
    saturated_pixels: int
    shape: tuple[int, int]
    stats: dict[str, Any] = field(default_factory=dict)

    def uv(self) -> np.ndarray:
        """``(H, W, 2)`` float32: u and v, NaN for an axis that is not coded or a pixel not decoded."""
        out = np.full((*self.shape, 2), np.nan, np.float32)
        for index, name in enumerate(("u", "v")):
            if name in self.axes:
                out[..., index] = self.axes[name].coordinate
        return out

    def quality_arrays(self) -> dict[str, np.ndarray]:
        """The quality file's arrays: ``modulation_a``, ``noise_a`` (float32) and ``reason_a`` (uint8)."""
        arrays: dict[str, np.ndarray] = {}
        for name, axis in self.axes.items():
            arrays[f"modulation_{name}"] = axis.modulation.astype(np.float32, copy=False)
            arrays[f"noise_{name}"] = axis.noise.astype(np.float32, copy=False)
            arrays[f"reason_{name}"] = axis.reason.astype(np.uint8, copy=False)
        return arrays

    def summary(self) -> dict[str, Any]:
        """JSON-ready counts per axis and reason, slips, saturated pixels, the options."""
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
        }


# ----------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class _SequencePlan:
    frames: tuple[int, ...]
    weights: np.ndarray  # (3, N) float32: cos, -sin (so row 1 gives -S), ones
    steps: int
    period: float
    origin: float
    need_noise: bool


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


def _plan(codec: Codec) -> list[_AxisPlan]:
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
            sequences.append(
                _SequencePlan(
                    seq.frames,
                    weights,
                    seq.steps,
                    seq.period,
                    seq.origin,
                    need_noise=seq.steps >= 4 and i == noise_index,
                )
            )
        lut = None
        positions: tuple[int, ...] = ()
        slip = 0.0
        g = axis.gray
        if g is not None:
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
    threads: int | None = None,
) -> CodecDecoding:
    """Decode a stack of ``codec`` to absolute projector coordinates.

    Parameters
    ----------
    images : (frames, H, W) array of uint8, uint16 or float
        Camera images in the codec's frame order, grey levels.
    codec : Codec
    options : CodecDecodeOptions, optional
        Validity rules; defaults resolved per codec and bit depth (recorded in the result).
    threads : int, optional
        Worker threads over row tiles (default :data:`~metrology.core.tiling.DEFAULT_THREADS`).

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
    plans = _plan(codec)
    outputs: dict[str, dict[str, np.ndarray]] = {}
    for plan in plans:
        outputs[plan.name] = {
            "coordinate": np.empty((height, width), np.float32),
            "modulation": np.empty((height, width), np.float32),
            "mean": np.empty((height, width), np.float32),
            "noise": np.empty((height, width), np.float32),
            "reason": np.empty((height, width), np.uint8),
        }
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
    lock = threading.Lock()

    def run(rows: slice) -> None:
        n_sat = _decode_tile(stack, rows, codec, plans, opts, outputs, used_frames)
        with lock:
            saturated_counts.append(n_sat)

    run_tiled(run, height, width, threads)
    axes: dict[str, AxisDecoding] = {}
    for plan in plans:
        out = outputs[plan.name]
        slips = 0
        if opts.repair_slips and plan.slip_period > 0:
            final_period = plan.chain[-1].period
            slips = repair_slips(out["coordinate"], out["reason"], plan.slip_period, final_period)
        axes[plan.name] = AxisDecoding(
            coordinate=out["coordinate"],
            modulation=out["modulation"],
            mean=out["mean"],
            noise=out["noise"],
            reason=out["reason"],
            slips_repaired=slips,
        )
    return CodecDecoding(axes=axes, options=opts, saturated_pixels=int(sum(saturated_counts)), shape=(height, width))


def _decode_tile(
    stack: np.ndarray,
    rows: slice,
    codec: Codec,
    plans: list[_AxisPlan],
    opts: CodecDecodeOptions,
    outputs: dict[str, dict[str, np.ndarray]],
    used_frames: list[int],
) -> int:
    scratch = thread_scratch()
    tile = stack[:, rows]
    h, w = tile.shape[1:]
    shape = (h, w)
    integer = stack.dtype.kind in "ui"
    assert opts.saturation_level is not None and opts.min_modulation is not None
    assert opts.min_inverse_contrast is not None and opts.consistency_periods is not None

    # saturation flag over every used frame
    if math.isfinite(opts.saturation_level):
        level = opts.saturation_level
        if integer and level > np.iinfo(stack.dtype).max:
            n_saturated = 0
        else:
            peak = scratch.get("peak", shape, stack.dtype)
            np.copyto(peak, tile[used_frames[0]])
            for f in used_frames[1:]:
                np.maximum(peak, tile[f], out=peak)
            n_saturated = int(np.count_nonzero(peak >= level))
    else:
        n_saturated = 0

    # white / black threshold, shared by the axes
    white_black: np.ndarray | None = None
    white_black_half: np.ndarray | None = None
    white_black_mid: np.ndarray | None = None
    if codec.white and codec.black:
        wsum = np.zeros(shape, np.float32)
        for f in codec.white:
            wsum += tile[f]
        bsum = np.zeros(shape, np.float32)
        for f in codec.black:
            bsum += tile[f]
        wmean = wsum / np.float32(len(codec.white))
        bmean = bsum / np.float32(len(codec.black))
        mid = white_black_mid = (wmean + bmean) * np.float32(0.5)
        white_black = np.floor(mid).astype(stack.dtype) if integer else mid
        white_black_half = (wmean - bmean) * np.float32(0.5)

    for plan in plans:
        out = {key: value[rows] for key, value in outputs[plan.name].items()}
        _decode_axis_tile(tile, plan, opts, out, integer, white_black, white_black_half, white_black_mid, scratch)
    return n_saturated


def _phase_tile(
    tile: np.ndarray, seq: _SequencePlan, exact: bool, scratch: Any, tag: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """(frac, B, sum, noise or None, max over the frames) of one sequence on a tile."""
    h, w = tile.shape[1:]
    n = seq.steps
    f = scratch.get("f32frames", (n, h, w), np.float32)
    frames = seq.frames
    if frames == tuple(range(frames[0], frames[0] + n)):
        np.copyto(f, tile[frames[0] : frames[0] + n], casting="unsafe")
    else:
        for k, fi in enumerate(frames):
            np.copyto(f[k], tile[fi], casting="unsafe")
    flat = f.reshape(n, h * w)
    res = scratch.get(f"gemm{tag}", (3, h * w), np.float32)
    np.matmul(seq.weights, flat, out=res)
    c, neg_s, total = (res[i].reshape(h, w) for i in range(3))
    if exact:
        angle = np.arctan2(neg_s, c)
        angle[angle < 0] += np.float32(TWO_PI)
        mag = np.hypot(c, neg_s)
    else:
        mag, angle = cv2.cartToPolar(c, neg_s)
    frac = np.multiply(angle, np.float32(1 / TWO_PI), out=angle)
    frac[frac >= 1] -= np.float32(1)
    b = np.multiply(mag, np.float32(2 / n), out=mag)
    noise = None
    if seq.need_noise:
        sq = np.einsum("ij,ij->j", flat, flat)
        resid = sq - total.ravel() * total.ravel() / np.float32(n) - b.ravel() * b.ravel() * np.float32(n / 2)
        np.maximum(resid, 0, out=resid)
        noise = np.sqrt(resid / np.float32(n - 3)).reshape(h, w)
    peak = f.max(axis=0)
    return frac, b, total.copy(), noise, peak


def _decode_axis_tile(
    tile: np.ndarray,
    plan: _AxisPlan,
    opts: CodecDecodeOptions,
    out: dict[str, np.ndarray],
    integer: bool,
    white_black: np.ndarray | None,
    white_black_half: np.ndarray | None,
    white_black_mid: np.ndarray | None,
    scratch: Any,
) -> None:
    h, w = tile.shape[1:]
    shape = (h, w)
    reason = out["reason"]
    reason.fill(REASON_VALID)
    assert opts.min_modulation is not None and opts.saturation_level is not None
    assert opts.min_inverse_contrast is not None and opts.consistency_periods is not None
    dark = np.zeros(shape, bool)
    saturated = np.zeros(shape, bool)
    fracs: dict[int, np.ndarray] = {}
    mods: dict[int, np.ndarray] = {}
    noise: np.ndarray | None = None
    first_total: np.ndarray | None = None
    first_index = 0
    for i in plan.used:
        seq = plan.sequences[i]
        frac, b, total, n_est, peak = _phase_tile(tile, seq, bool(opts.exact_phase), scratch, "")
        fracs[i] = frac
        mods[i] = b
        dark |= b < np.float32(opts.min_modulation)
        saturated |= peak >= np.float32(opts.saturation_level)
        if n_est is not None:
            noise = n_est
        if i == first_index:
            first_total = total
    mean = out["mean"]
    if plan.axis.phase and 0 not in fracs:
        # the gray threshold (or the mean output) needs the first sequence even if the chain skips it
        _, _, first_total, _, _ = _phase_tile(tile, plan.sequences[0], bool(opts.exact_phase), scratch, "")
    if first_total is not None:
        np.multiply(first_total, np.float32(1 / plan.sequences[0].steps), out=mean)
    elif white_black_mid is not None:
        mean[...] = white_black_mid
    else:
        mean.fill(np.nan)

    # gray code
    centre: np.ndarray | None = None
    low_contrast = np.zeros(shape, bool)
    g = plan.axis.gray
    if g is not None:
        assert plan.gray_lut is not None
        word_dtype = np.uint8 if g.bits <= 8 else np.uint16
        word = np.zeros(shape, word_dtype)
        threshold: np.ndarray | None = None
        if g.inverse_frames is None:
            if white_black is not None:
                threshold = white_black
            else:
                assert first_total is not None
                n0 = plan.sequences[0].steps
                if integer:
                    threshold = np.floor((first_total + np.float32(0.5)) / np.float32(n0)).astype(tile.dtype)
                else:
                    threshold = first_total / np.float32(n0)
        min_contrast_half = np.full(shape, np.inf, np.float32) if g.inverse_frames is not None else None
        bit = np.empty(shape, bool)
        for i, f in enumerate(g.frames):
            frame = tile[f]
            if g.inverse_frames is not None:
                inverse = tile[g.inverse_frames[i]]
                np.greater(frame, inverse, out=bit)
                contrast = cv2.absdiff(frame, inverse)
                low_contrast |= contrast < opts.min_inverse_contrast
                assert min_contrast_half is not None
                np.minimum(min_contrast_half, contrast, out=min_contrast_half)
            else:
                assert threshold is not None
                np.greater(frame, threshold, out=bit)
            word |= np.left_shift(bit.view(np.uint8).astype(word_dtype), plan.gray_positions[i], dtype=word_dtype)
        if g.bits <= 8 and plan.gray_lut.size <= 256:
            lut = np.zeros(256, np.float32)
            lut[: plan.gray_lut.size] = plan.gray_lut
            centre = cv2.LUT(word, lut).reshape(shape)
        else:
            centre = plan.gray_lut[word]
        if not plan.axis.phase or not plan.used:
            # gray-only axis: modulation from white/black or the inverse contrast
            if white_black_half is not None:
                modulation = white_black_half
            elif min_contrast_half is not None:
                modulation = min_contrast_half * np.float32(0.5)
            else:
                modulation = np.full(shape, np.nan, np.float32)
            out["modulation"][...] = modulation
            dark |= ~(modulation >= np.float32(opts.min_modulation))

    # unwrapping chain
    x: np.ndarray | None = None
    inconsistent = np.zeros(shape, bool)
    previous: Stage | None = None
    for stage in plan.chain:
        if stage.kind == "gray":
            x = centre
            previous = stage
            continue
        if stage.kind == "phase":
            frac = fracs[stage.indices[0]]
        else:
            i, j = stage.indices
            s_i, l_i = (i, j) if plan.sequences[i].period < plan.sequences[j].period else (j, i)
            frac = fracs[s_i] - fracs[l_i]
            frac[frac < 0] += np.float32(1)
        period = np.float32(stage.period)
        xw = frac * period + np.float32(stage.origin)
        coarse = x if x is not None else np.float32((plan.extent - 1) / 2)
        k = np.rint((coarse - xw) / period)
        x_new = xw + period * k
        if previous is not None and previous.kind == "gray":
            assert centre is not None and g is not None
            tolerance = np.float32(g.word / 2 + opts.consistency_periods * stage.period)
            inconsistent |= np.abs(x_new - centre) > tolerance
        x = x_new
        previous = stage
    assert x is not None
    if plan.axis.phase and plan.used:
        mod = mods[plan.final[0]] if len(plan.final) == 1 else np.minimum(mods[plan.final[0]], mods[plan.final[1]])
        out["modulation"][...] = mod
    noise_out = out["noise"]
    if noise is not None:
        noise_out[...] = noise
    else:
        noise_out.fill(np.nan)

    outside = ~((x >= np.float32(-0.5)) & (x <= np.float32(plan.extent - 0.5)))
    # reasons, lowest priority first so that the first applicable one wins
    reason[outside] = REASON_OUTSIDE
    reason[inconsistent] = REASON_INCONSISTENT
    reason[low_contrast] = REASON_LOW_INVERSE_CONTRAST
    reason[saturated] = REASON_SATURATED
    reason[dark] = REASON_TOO_DARK
    coordinate = out["coordinate"]
    np.copyto(coordinate, x)
    coordinate[reason != REASON_VALID] = np.nan


def repair_slips(coordinate: np.ndarray, reason: np.ndarray, slip_period: float, final_period: float) -> int:
    """Repair whole-period slips against the 5x5 median, in place; returns the number repaired.

    Candidates are valid pixels differing by more than ``slip_period / 2`` from a valid
    4-neighbour. A candidate whose 5x5 neighbourhood holds at least 13 valid coordinates and
    lies more than ``slip_period / 2`` from their median ``m`` is moved to
    ``x + P_f round(P round((m - x) / P) / P_f)`` (P the slip period, P_f the final stage's)
    and given reason 6.
    """
    x = coordinate
    half = np.float32(slip_period / 2)
    jump = np.zeros(x.shape, bool)
    with np.errstate(invalid="ignore"):
        dx = np.abs(np.diff(x, axis=1)) > half
        dy = np.abs(np.diff(x, axis=0)) > half
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:, :] |= dy
    jump[:-1, :] |= dy
    rows, cols = np.nonzero(jump)
    if rows.size == 0:
        return 0
    padded = np.pad(x, 2, mode="constant", constant_values=np.nan)
    offsets = np.arange(-2, 3)
    row_index = rows[:, None, None] + 2 + offsets[None, :, None]
    col_index = cols[:, None, None] + 2 + offsets[None, None, :]
    window = padded[row_index, col_index]
    window = window.reshape(rows.size, 25)
    enough = np.count_nonzero(np.isfinite(window), axis=1) >= 13
    med = np.full(rows.size, np.nan, np.float32)
    if enough.any():
        med[enough] = np.nanmedian(window[enough], axis=1)
    values = x[rows, cols]
    with np.errstate(invalid="ignore"):
        slipped = enough & (np.abs(values - med) > half)
    if not slipped.any():
        return 0
    r, c = rows[slipped], cols[slipped]
    shift = slip_period * np.rint((med[slipped] - values[slipped]) / slip_period)
    snapped = final_period * np.rint(shift / final_period)
    x[r, c] = values[slipped] + snapped.astype(np.float32)
    reason[r, c] = REASON_SLIP_REPAIRED
    return int(slipped.sum())
