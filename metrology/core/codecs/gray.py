"""Multi-level (base-L) reflected gray codes: encoding, level centres estimated from the data, decoding.

Word n of a code of D digits and L levels (2..8, ``L**D <= 65536``) has the base-L digits
``b_{D-1} .. b_0`` (most significant first) and the gray digits, from the most significant down,

    g_i = b_i              when the higher gray digits g_{j > i} sum to an even number,
    g_i = L - 1 - b_i      otherwise,

so two neighbouring words differ in one digit by one level; for L = 2 this is ``n ^ (n >> 1)``.
Digit d is shown as the grey level ``d / (L - 1)``.

A camera rarely sees the levels where the projector put them (projector gamma, camera response,
ambient light), so the decoder does not threshold at ``(d + 1/2) / (L - 1)``. Each pixel's value
is normalised against its own dark and bright references, ``t = (I - lo) / (hi - lo)`` with
``lo, hi`` the black and white frames or the first phase sequence's ``A -+ B``; the level
centres in t are estimated from the data (:func:`estimate_levels`: an optimal 1-D k-means of
the pooled digit frames, then refined per frame), and a pixel's digit is the number of
thresholds (midpoints between adjacent centres) below its t. A pixel within
``LEVEL_MARGIN`` of the gap between two centres from their threshold cannot be classified and
is refused with a reason. When the frames do not show L separable levels, or show more than
L, the description is wrong and the whole axis is refused, saying so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import GrayCode, PhaseSequence

LEVEL_MARGIN = 0.05
"""A pixel closer to a level threshold than this fraction of the gap between the two adjacent
level centres is refused (its digit is ambiguous)."""
SEPARATION = 4.0
"""Adjacent level clusters are separable when their centres are at least this many combined
robust spreads apart: ``(c_b - c_a) / hypot(s_a, s_b) >= 4``."""
MIN_SHARE = 0.2
"""A level must hold at least ``MIN_SHARE / L`` of the pooled samples (each level holds about 1/L
of them over a view of a few words) to count as shown."""
SPREAD_FLOOR = 0.0015
"""Smallest robust spread of a level cluster, in t (normalised) units: about the histogram's bin
width over sqrt(12) (noise-free renders put a level in one bin)."""
SAMPLES = 65536
"""Largest number of pixels sampled (on a regular grid) to estimate the level centres."""
HISTOGRAM = (-0.5, 1.5, 400)
"""Range and bin count of the histogram of t the clustering runs on."""


def gray_digits(words: npt.ArrayLike, levels: int, digits: int) -> npt.NDArray[np.int64]:
    """``(..., digits)`` int64: the gray digits of ``words`` (int array), most significant first."""
    n = np.asarray(words, dtype=np.int64)
    base = np.stack([(n // levels ** (digits - 1 - i)) % levels for i in range(digits)], axis=-1)
    out = np.empty_like(base)
    parity = np.zeros(n.shape, np.int64)
    for i in range(digits):
        out[..., i] = np.where(parity % 2 == 0, base[..., i], levels - 1 - base[..., i])
        parity += out[..., i]
    return out


def words_from_gray(gray: npt.ArrayLike, levels: int) -> npt.NDArray[np.int64]:
    """Inverse of :func:`gray_digits`: ``(...,)`` int64 words of ``(..., digits)`` gray digits (MSB first)."""
    g = np.asarray(gray, dtype=np.int64)
    words = np.zeros(g.shape[:-1], np.int64)
    parity = np.zeros(g.shape[:-1], np.int64)
    for i in range(g.shape[-1]):
        digit = np.where(parity % 2 == 0, g[..., i], levels - 1 - g[..., i])
        words = words * levels + digit
        parity += g[..., i]
    return words


def centre_lut(gray: GrayCode) -> npt.NDArray[np.float32]:
    """``(L**D,)`` float32: the centre ``origin + (n + 0.5) word`` of the word whose gray digits,
    read as a base-L number (most significant first), are the index."""
    levels, digits = gray.levels, gray.bits
    index = np.arange(levels**digits, dtype=np.int64)
    as_digits = np.stack([(index // levels ** (digits - 1 - i)) % levels for i in range(digits)], axis=-1)
    words = words_from_gray(as_digits, levels)
    return (gray.origin + (words + 0.5) * gray.word).astype(np.float32)


def digit_positions(gray: GrayCode) -> tuple[int, ...]:
    """Place value exponent of each frame's digit (0 = least significant), in frame order."""
    d = gray.bits
    return tuple(d - 1 - i if gray.order == "msb_first" else i for i in range(d))


# ----------------------------------------------------------------------------- level centres
@dataclass(frozen=True)
class LevelModel:
    """The level centres of one axis's multi-level gray frames, in normalised units t.

    Attributes
    ----------
    levels : int
        L, as described.
    centres : (D, L) float64
        Level centres of each digit frame (frame order), t units.
    thresholds : (D, L - 1) float32
        Midpoints between adjacent centres.
    margins : (D, L - 1) float32
        ``LEVEL_MARGIN`` times the gap between the adjacent centres: the refused band about each
        threshold.
    status : {"estimated", "nominal", "refused"}
        Estimated from the data; nominal (``d / (L - 1)``, too few usable pixels); refused (the
        frames do not show L separable levels, or show more: every pixel is refused).
    message : str
        Why, when not estimated; names the field.
    shown : int
        Separable levels found in the pooled frames: L when estimated, fewer (or L + 1: at least
        that many) when refused, 0 when nominal.
    separations : tuple of float
        Distances between adjacent pooled centres in combined robust spreads (when estimated).
    """

    levels: int
    centres: np.ndarray
    thresholds: np.ndarray
    margins: np.ndarray
    status: str
    message: str = ""
    shown: int = 0
    separations: tuple[float, ...] = field(default=())

    @property
    def refused(self) -> bool:
        return self.status == "refused"

    def summary(self) -> dict[str, Any]:
        """JSON-ready: levels, status, message, the separable levels shown and the mean centres."""
        return {
            "levels": self.levels,
            "status": self.status,
            "message": self.message,
            "levels_shown": self.shown,
            "centres": [round(float(c), 4) for c in self.centres.mean(axis=0)],
        }


def _model(levels: int, centres: np.ndarray, status: str, message: str = "", shown: int = 0) -> LevelModel:
    thresholds = 0.5 * (centres[:, 1:] + centres[:, :-1])
    margins = LEVEL_MARGIN * (centres[:, 1:] - centres[:, :-1])
    return LevelModel(
        levels, centres, thresholds.astype(np.float32), margins.astype(np.float32), status, message, shown
    )


def nominal_levels(levels: int, digits: int, status: str = "nominal", message: str = "", shown: int = 0) -> LevelModel:
    """Centres ``d / (L - 1)`` for every frame (the projector's levels, as if seen linearly)."""
    centres = np.tile(np.arange(levels, dtype=np.float64) / (levels - 1), (digits, 1))
    return _model(levels, centres, status, message, shown)


def optimal_partitions(values: npt.ArrayLike, max_clusters: int) -> list[np.ndarray]:
    """Optimal 1-D k-means on a histogram: for k = 1 .. ``max_clusters``, the ``k - 1`` cut points.

    ``values``: (n,) float64 in t units, histogrammed over :data:`HISTOGRAM`; dynamic programming
    on the within-cluster sum of squares ``sum_bins w (x - mean)^2`` of contiguous bin ranges
    (exact for the binned data). Returns a list whose entry ``k - 1`` holds the ``k - 1`` cut
    values (bin edges) between consecutive clusters, increasing.
    """
    lo, hi, bins = HISTOGRAM
    counts, edges = np.histogram(np.clip(values, lo, hi), bins=bins, range=(lo, hi))
    x = 0.5 * (edges[1:] + edges[:-1])
    w = counts.astype(np.float64)
    p0 = np.concatenate([[0.0], np.cumsum(w)])
    p1 = np.concatenate([[0.0], np.cumsum(w * x)])
    p2 = np.concatenate([[0.0], np.cumsum(w * x * x)])
    i = np.arange(bins)[:, None]  # first bin of a range
    j = np.arange(bins)[None, :]  # last bin
    s0 = p0[j + 1] - p0[i]
    s1 = p1[j + 1] - p1[i]
    s2 = p2[j + 1] - p2[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = np.where(s0 > 0, s2 - s1 * s1 / np.where(s0 > 0, s0, 1.0), 0.0)
    cost = np.where(i <= j, np.maximum(cost, 0.0), np.inf)
    best = cost[0].copy()  # best[j]: one cluster over bins 0..j
    starts: list[np.ndarray] = []
    results = [np.empty(0)]
    for _ in range(2, max_clusters + 1):
        # the last cluster starts at bin i >= 1; the others cover 0..i-1
        total = np.full((bins, bins), np.inf)
        total[1:] = best[:-1, None] + cost[1:]
        start = np.argmin(total, axis=0)
        best = total[start, np.arange(bins)]
        starts.append(start)
        cuts = []
        end = bins - 1
        for step in reversed(starts):
            first = int(step[end])
            cuts.append(edges[first])
            end = first - 1
        results.append(np.array(sorted(cuts)))
    return results


def _clusters(values: np.ndarray, cuts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shares, medians and robust spreads (1.4826 MAD, floored) of the clusters between ``cuts``."""
    label = np.searchsorted(cuts, values, side="right")
    k = cuts.size + 1
    shares = np.zeros(k)
    centres = np.full(k, np.nan)
    spreads = np.full(k, np.inf)
    for c in range(k):
        member = values[label == c]
        shares[c] = member.size / max(values.size, 1)
        if member.size:
            centres[c] = float(np.median(member))
            spreads[c] = max(1.4826 * float(np.median(np.abs(member - centres[c]))), SPREAD_FLOOR)
    return shares, centres, spreads


def _separable(shares: np.ndarray, centres: np.ndarray, spreads: np.ndarray) -> tuple[bool, np.ndarray]:
    """Whether every cluster holds ``MIN_SHARE / k`` of the samples and adjacent ones are ``SEPARATION`` apart."""
    k = shares.size
    with np.errstate(invalid="ignore"):
        separation = np.diff(centres) / np.hypot(spreads[1:], spreads[:-1])
    ok = bool((shares >= MIN_SHARE / k).all() and np.isfinite(separation).all() and (separation >= SEPARATION).all())
    return ok, separation


def estimate_levels(t: np.ndarray, levels: int, where: str) -> LevelModel:
    """Level centres of D digit frames from samples of their normalised values.

    Parameters
    ----------
    t : (D, n) float64
        ``(I - lo) / (hi - lo)`` of n usable sampled pixels in each digit frame (frame order).
    levels : int
        L, as described.
    where : str
        The gray code's field (``axes.u.gray``), named in the messages.

    The pooled values of all frames are clustered into L (and L + 1) clusters by
    :func:`optimal_partitions`. With L separable clusters (each holding ``MIN_SHARE / L`` of the
    samples, adjacent centres ``SEPARATION`` robust spreads apart) and not L + 1, each frame's
    centres are its own medians of the values nearest each pooled centre (the pooled centre where
    the frame holds fewer than ``max(20, MIN_SHARE / L n)`` such values, e.g. the most significant
    digit seen over few words). Otherwise the model is refused with a message.
    """
    digits = t.shape[0]
    pooled = t.ravel()
    partitions = optimal_partitions(pooled, levels + 1)
    shares, centres, spreads = _clusters(pooled, partitions[levels - 1])
    ok, separation = _separable(shares, centres, spreads)
    more, _ = _separable(*_clusters(pooled, partitions[levels]))
    shown = levels + 1 if more else 0
    if not ok:
        shown = max((k for k in range(1, levels) if _separable(*_clusters(pooled, partitions[k - 1]))[0]), default=1)
        weakest = float(np.nanmin(separation)) if separation.size and np.isfinite(separation).any() else 0.0
        seen = f"{shown} separable grey levels" if shown > 1 else "no separable grey levels"
        message = (
            f"codec field {where}.levels = {levels}, but the gray frames show {seen}, not {levels} (closest "
            f"levels {weakest:.1f} spreads apart, smallest share {shares.min():.3f}): check the level count, "
            "or the words are too narrow for the camera"
        )
        return nominal_levels(levels, digits, "refused", message, shown)
    if more:
        message = (
            f"codec field {where}.levels = {levels}, but the gray frames show at least {levels + 1} separable "
            "grey levels: check the level count"
        )
        return nominal_levels(levels, digits, "refused", message, shown)
    per_frame = np.tile(centres, (digits, 1))
    for d in range(digits):
        values = t[d]
        nearest = np.argmin(np.abs(values[:, None] - centres[None, :]), axis=1)
        enough = max(20, MIN_SHARE / levels * values.size)
        for c in range(levels):
            member = values[nearest == c]
            if member.size >= enough:
                per_frame[d, c] = float(np.median(member))
        if not (np.diff(per_frame[d]) > 0).all():
            per_frame[d] = centres
    return LevelModel(
        levels,
        per_frame,
        (0.5 * (per_frame[:, 1:] + per_frame[:, :-1])).astype(np.float32),
        (LEVEL_MARGIN * np.diff(per_frame, axis=1)).astype(np.float32),
        "estimated",
        shown=levels,
        separations=tuple(float(s) for s in separation),
    )


def sample_levels(
    stack: np.ndarray,
    gray: GrayCode,
    white: tuple[int, ...],
    black: tuple[int, ...],
    phase: PhaseSequence | None,
    min_modulation: float,
    where: str,
) -> LevelModel:
    """The :class:`LevelModel` of ``gray`` from a regular grid of at most :data:`SAMPLES` pixels.

    ``stack``: (frames, H, W) images. The references are the mean white and black frames when
    both exist, else the first phase sequence's ``A -+ B`` (``B = (2/N) hypot(C, S)``); pixels
    whose half range ``(hi - lo) / 2`` is below ``min_modulation`` (grey levels) are not used.
    With fewer than 100 usable pixels the centres are nominal.
    """
    _, height, width = stack.shape
    stride = max(1, math.ceil(math.sqrt(height * width / SAMPLES)))
    grid = stack[:, ::stride, ::stride]
    lo, span = references(grid, white, black, phase)
    usable = np.isfinite(span) & (span >= 2 * min_modulation)
    if usable.sum() < 100:
        message = f"codec field {where}: too few lit pixels to estimate the levels"
        return nominal_levels(gray.levels, gray.bits, message=message)
    t = np.stack([(grid[f][usable] - lo[usable]) / span[usable] for f in gray.frames]).astype(np.float64)
    return estimate_levels(t, gray.levels, where)


def references(
    images: np.ndarray, white: tuple[int, ...], black: tuple[int, ...], phase: PhaseSequence | None
) -> tuple[np.ndarray, np.ndarray]:
    """``lo`` and ``hi - lo`` (float64, images' shape without the frame axis) of (frames, ...) images."""
    if white and black:
        bright = np.stack([images[f] for f in white]).astype(np.float64).mean(axis=0)
        dark = np.stack([images[f] for f in black]).astype(np.float64).mean(axis=0)
        return dark, bright - dark
    assert phase is not None  # validation: a gray code has a threshold source
    frames = np.stack([images[f] for f in phase.frames]).astype(np.float64)
    delta = 2 * np.pi * phase.shift * np.arange(phase.steps) / phase.steps
    mean = frames.mean(axis=0)
    c = np.tensordot(np.cos(delta), frames, axes=1)
    s = np.tensordot(np.sin(delta), frames, axes=1)
    b = 2 / phase.steps * np.hypot(c, s)
    return mean - b, 2 * b


def classify_tile(
    tile: np.ndarray,
    gray: GrayCode,
    model: LevelModel,
    lo: np.ndarray,
    span: np.ndarray,
    scratch: Any,
    tag: str,
    *,
    resolve_adjacent: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The gray index (base-L number of the digits, (h, w) int32) and the ambiguous mask ((h, w) bool).

    ``tile``: (frames, h, w) images; ``lo``, ``span``: (h, w) float32 references (``span = hi -
    lo``, grey levels). Per digit frame ``t = (I - lo) / span``; the digit counts the thresholds
    below t; a pixel with ``|t - threshold| < margin`` for some threshold is ambiguous; every
    pixel is ambiguous when the model is refused.

    ``resolve_adjacent``: a pixel ambiguous in exactly one digit whose other reading (one level
    up below the threshold, down above it) is the neighbouring word, as at a blurred word edge,
    is kept: the caller's next stage (a phase of at least two words' period) unwraps either
    reading to the same coordinate.
    """
    shape = tile.shape[1:]
    levels = gray.levels
    index = scratch.get(f"mlindex{tag}", shape, np.int32)
    index.fill(0)
    ambiguous = scratch.get(f"mlambig{tag}", shape, bool)
    ambiguous.fill(model.refused)
    inverse = scratch.get(f"mlinv{tag}", shape, np.float32)
    with np.errstate(divide="ignore"):
        np.divide(np.float32(1), span, out=inverse)
    t = scratch.get(f"mlt{tag}", shape, np.float32)
    digit = scratch.get(f"mldigit{tag}", shape, np.int32)
    near = scratch.get(f"mlnear{tag}", shape, np.float32)
    above = scratch.get(f"mlabove{tag}", shape, bool)
    close = scratch.get(f"mlclose{tag}", shape, bool)
    resolve = resolve_adjacent and not model.refused
    if resolve:  # the other reading's index offset and the number of ambiguous digits
        offset = scratch.get(f"mloffset{tag}", shape, np.int32)
        offset.fill(0)
        count = scratch.get(f"mlcount{tag}", shape, np.int32)
        count.fill(0)
    for i, (f, position) in enumerate(zip(gray.frames, digit_positions(gray), strict=True)):
        np.subtract(tile[f], lo, out=t, casting="unsafe")
        with np.errstate(invalid="ignore"):  # 0 * inf where the span is 0: NaN, no digit, refused as dark
            t *= inverse
        digit.fill(0)
        place = np.int32(levels**position)
        for k in range(levels - 1):
            threshold = model.thresholds[i, k]
            np.greater(t, threshold, out=above)
            digit += above
            np.subtract(t, threshold, out=near)
            np.abs(near, out=near)
            np.less(near, model.margins[i, k], out=close)
            ambiguous |= close
            if resolve:
                # other reading: -place above the threshold, +place below it
                offset += close * (place - 2 * place * above)
                count += close
        index += digit * place
    if resolve:
        other = np.clip(index + offset, 0, levels**gray.bits - 1)
        lut = centre_lut(gray)
        adjacent = np.abs(lut[other] - lut[index]) <= np.float32(1.5 * gray.word)
        ambiguous &= ~((count == 1) & adjacent)
    return index, ambiguous
