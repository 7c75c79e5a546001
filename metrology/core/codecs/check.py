"""The codec self-check: does the decoding agree with its description? (docs/codecs.md, "Self-check")

For every axis with a gray code and a phase, each pixel's unwrapped coordinate ``x`` (before
the gray/phase tolerance refuses anything) is compared with the centre ``c = origin + (n + 0.5)
word`` of the gray word ``n`` it read, over the pixels that tolerance judges (not too dark, not
saturated, not of low inverse contrast: reasons 0, 3, 4 and 6). With the right description the
differences ``d = x - c`` fill each word's cell ``[-word / 2, word / 2)`` evenly, and the
coordinate is continuous across the word boundaries. A wrong phase origin shifts the fill, a
reversed shift or a wrong bit order makes the coordinate jump at the word boundaries (or
spreads ``d`` beyond the cell), a word too wide fills a part of the cell only, swapped axes
send coordinates outside the projector.

Statistics (codec units, i.e. projector pixels, unless said):

* ``offset_px``: the median of ``d``, signed (pooled), and per value of the least significant
  gray digit (``digit_offsets_px``);
* ``outside_share``: the fraction of pixels outside their word's cell by more than
  ``word / 8`` (the gray bits' own edge blur), or outside the projector ``[-0.5, extent - 0.5]``;
  ``outside_projector_share`` the latter alone;
* ``imbalance``: per word ``w`` with ``n_w`` pixels inside its cell, ``a_w = |n_above - n_below|``,
  as an excess over what an even fill gives for that many pixels:
  ``(sum a_w - sum E[a_w]) / (sum n_w - sum E[a_w])``, with ``E[a_w] = E|2B - n_w|`` for
  ``B ~ Binomial(n_w, 1/2)`` (:func:`expected_binomial_imbalance`). 0: both halves filled as an
  even fill would; 1: every word filled on one side only. A word seen by one pixel is one-sided
  whatever the description, so it adds nothing (a camera that sees each word with a pixel or
  two, e.g. gcps-v1 on a small sensor, is judged by the other statistics); 0 when no word has
  more than one pixel; not judged (null) where the camera sees fewer than
  :data:`MIN_PIXELS_PER_WORD` pixels across a word (``pixels_per_word``: the word over the
  coordinate's median step between neighbouring pixels of one word);
* ``spread``: the interquartile range of ``d`` over the word (0.5 for a uniform fill of the cell);
* ``jump_ratio``: 4-neighbour pairs of judged pixels whose coordinates differ by more than half
  the chain's finest period, over the pairs whose gray words differ (a right description jumps
  at depth edges only; a wrong one at most word boundaries, or inside the words).

Status: ``inconsistent`` when ``|offset| >= word / 4`` (pooled or for a digit value),
``outside_share >= 0.2``, ``outside_projector_share > 0.05``, ``imbalance >= 0.8`` (one side
only), ``spread <= 0.3`` (a fraction of the cell) or ``jump_ratio >= 0.6``; ``consistent`` when
``|offset| <= max(1, word / 8)``, ``outside_share <= 0.05``, ``imbalance <= 0.25``, ``0.35 <=
spread <= 0.65`` and ``jump_ratio <= 0.35``; ``undetermined`` otherwise, or on fewer than
:data:`MIN_PIXELS` pixels, the message saying why.

The message of an ``inconsistent`` axis names the likely correction: :func:`with_suggestion`
decodes 32 pairs of rows of the stack under descriptions that differ by one likely mistake
(reversed shift, bit order, inversion, word twice too wide or narrow, a phase origin off by
eighths of its period, all origins off by twelfths, the gray origin off by quarters of a word,
swapped axes), group by group, and names the best ``consistent`` one of the first group that has
one; else a hint from the statistics. Statistics of images above :data:`SAMPLE_PIXELS` pixels
are computed on every s-th row (and the row after each, for the vertical neighbour pairs).

Contract (``"codec_check"`` in ``gcps decode``'s summary, measurements, the capture API):
``{axis: {"status", "offset_px", "outside_share", "message", ...}}`` (:meth:`AxisCheck.to_dict`).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from metrology.core.codecs.model import Axis, Codec, CodecError, codec_from_dict

CONSISTENT = "consistent"
INCONSISTENT = "inconsistent"
UNDETERMINED = "undetermined"
STATUSES: tuple[str, ...] = (CONSISTENT, UNDETERMINED, INCONSISTENT)
"""Statuses, from the best to the worst."""

MIN_PIXELS = 1000
"""Fewest judged pixels for a status other than ``undetermined``."""
MIN_WORD_CHANGES = 50
"""Fewest neighbour pairs with different gray words for the jump ratio to count."""
CELL_MARGIN_WORDS = 1 / 8
"""How far outside its cell (in words) a pixel still counts as inside: the gray bits' edge blur."""


@dataclass(frozen=True)
class AxisCheck:
    """The self-check of one axis (module docstring).

    ``status``, ``offset_px``, ``outside_share`` and ``message`` are the contract of
    ``"codec_check"``; ``findings`` is what the statistics found wrong (the message's second part)
    and the other attributes say what they were computed from.
    """

    status: str
    offset_px: float | None
    outside_share: float | None
    message: str
    findings: str = ""
    pixels: int = 0
    word_px: float = 0.0
    outside_projector_share: float | None = None
    digit_offsets_px: tuple[float | None, ...] = ()
    imbalance: float | None = None
    spread: float | None = None
    jump_ratio: float | None = None
    pixels_per_word: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the contract keys first, then the statistics behind them."""
        return {
            "status": self.status,
            "offset_px": _rounded(self.offset_px),
            "outside_share": _rounded(self.outside_share),
            "message": self.message,
            "pixels": self.pixels,
            "word_px": self.word_px,
            "outside_projector_share": _rounded(self.outside_projector_share),
            "digit_offsets_px": [_rounded(v) for v in self.digit_offsets_px],
            "imbalance": _rounded(self.imbalance),
            "spread": _rounded(self.spread),
            "jump_ratio": _rounded(self.jump_ratio),
            "pixels_per_word": _rounded(self.pixels_per_word),
        }


def _rounded(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), 4)


def checkable(axis: Axis) -> bool:
    """True for an axis with a gray code and a phase stage in its chain (what the check judges)."""
    return axis.gray is not None and any(stage.kind != "gray" for stage in axis.chain())


@dataclass(frozen=True)
class _Stats:
    pixels: int  # sampled
    offset: float
    digit_offsets: tuple[float | None, ...]
    outside: float
    outside_projector: float
    imbalance: float | None  # None: words seen by too few pixels across to judge their halves
    spread: float
    jump_ratio: float | None
    pixels_per_word: float | None


MIN_PIXELS_PER_WORD = 4.0
"""Camera pixels across a gray word below which its halves are not compared: a word seen by a pixel
or two is sampled at the same few places in every row (a plane seen by a small camera), so its
halves are unevenly filled whatever the description; the other statistics still judge it."""

SAMPLE_PIXELS = 100_000
"""About how many pixels the statistics read: every ``s``-th row of a larger image (and the row
after each, for the vertical neighbour pairs)."""


DISTRIBUTION_PIXELS = 10_000
"""At most about this many of the sampled pixels (every k-th) give the quantiles of ``d``."""


def check_row_step(shape: tuple[int, ...]) -> int:
    """Every how many rows the statistics of an ``(H, W)`` image read (:data:`SAMPLE_PIXELS`)."""
    return max(1, math.ceil(shape[0] * shape[1] / SAMPLE_PIXELS))


def check_rows(height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of an ``(height, width)`` image the self-check reads: ``(rows, top, under)``.

    ``rows``: sorted unique row indices (intp) to keep; ``top``: positions in ``rows`` of every
    :func:`check_row_step`-th row (whose statistics and horizontal pairs count); ``under``:
    positions in ``rows`` of the row after each of the first ``under.size`` top rows (their
    vertical pairs). A decoder keeps these rows only (:func:`check_axis_rows`)."""
    step = check_row_step((height, width))
    tops = np.arange(0, height, step, dtype=np.intp)
    unders = tops[tops + 1 < height] + 1
    rows = np.union1d(tops, unders)
    return rows, np.searchsorted(rows, tops), np.searchsorted(rows, unders)


MEDIAN_PAIRS = 40_000
"""At most about this many neighbour pairs inside one word (every k-th) give the median step per pixel."""


_Rows = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(x, centre, judged) of some rows: (h, W) float32, float32, bool."""


def _jumps(top: _Rows, vertical: tuple[_Rows, _Rows] | None, jump: float) -> tuple[int, int, float | None]:
    """(coordinate jumps, word changes, coordinate step per pixel) over 4-neighbour pairs of judged
    pixels: the horizontal pairs of the ``top`` rows, and the vertical pairs of ``vertical``
    (rows ``upper`` and the rows ``lower`` directly below them, same count).

    The step per pixel is ``hypot(median |dx_h|, median |dx_v|)`` over the pairs inside one word
    (codec units per camera pixel; None without such pairs; each median over at most about
    :data:`MEDIAN_PAIRS` evenly taken pairs): how finely the camera samples the coded direction.

    Each pair set costs an OpenCV difference, two comparisons and one gather of the pairs inside
    a word (judged pixels are finite, so ``|xa - xb|`` is compared only where both are judged)."""
    x, centre, judged = top
    pairs = [((x[:, 1:], centre[:, 1:], judged[:, 1:]), (x[:, :-1], centre[:, :-1], judged[:, :-1]))]
    if vertical is not None and vertical[0][0].shape[0]:
        pairs.append((vertical[1], vertical[0]))
    jumps = changes = 0
    medians: list[float] = []
    for (xa, ca, ja), (xb, cb, jb) in pairs:
        if xa.size == 0:
            medians.append(0.0)
            continue
        both = np.logical_and(ja, jb)
        difference = cv2.absdiff(xa, xb)  # NaN outside judged pixels
        with np.errstate(invalid="ignore"):
            jumps += int(np.count_nonzero(np.logical_and(both, difference > jump)))
        same_word = np.equal(ca, cb)
        both_changed = int(np.count_nonzero(both))
        np.logical_and(both, same_word, out=both)  # judged pairs inside one word
        changes += both_changed - int(np.count_nonzero(both))
        within = difference[both]
        within = within[:: max(1, math.ceil(within.size / MEDIAN_PAIRS))]
        medians.append(_median(within) if within.size else 0.0)
    per_pixel = math.hypot(*medians)
    return jumps, changes, (per_pixel if per_pixel > 0 else None)


def _median(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D float32 array (the mean of its two middle values in float32),
    by a partition at those two places (the same values as a full sort, about twice as fast on
    ~10^4 values on the reference VM)."""
    n = values.size
    ordered = np.partition(values, [(n - 1) // 2, n // 2])
    return float((ordered[(n - 1) // 2] + ordered[n // 2]) / np.float32(2))


def _quantiles(values: np.ndarray, quantiles: tuple[float, ...]) -> list[float]:
    """Quantiles of a non-empty 1-D array by numpy's default (``linear``) method: ``q (n - 1)``
    interpolated between its neighbours, in float64, from one partition at the places read (the
    values of a full sort)."""
    n = values.size
    places = [(math.floor(q * (n - 1)), min(math.floor(q * (n - 1)) + 1, n - 1)) for q in quantiles]
    ordered = np.partition(values, sorted({i for pair in places for i in pair}))
    out = []
    for q, (below, above) in zip(quantiles, places, strict=True):
        t = q * (n - 1) - below
        a, b = float(ordered[below]), float(ordered[above])
        out.append(b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t)
    return out


def expected_binomial_imbalance(count: np.ndarray) -> np.ndarray:
    """``E|2B - n|`` for ``B ~ Binomial(n, 1/2)``, per element of ``count``.

    Parameters
    ----------
    count : (K,) integer array, >= 0
        Pixels per word.

    Returns
    -------
    (K,) float64 array
        The mean absolute difference between the pixels above and below a word's centre when each
        pixel falls on either side with probability 1/2: ``n C(n - 1, floor((n - 1) / 2)) / 2^(n - 1)``
        (1 for n = 1, 1 for n = 2, 1.5 for n = 3, ...; about ``sqrt(2 n / pi)`` for large n),
        0 for n = 0. Exact up to n = 1024 (a table from log-gamma), the asymptote beyond.

    >>> expected_binomial_imbalance(np.array([0, 1, 2, 3, 4])).round(4).tolist()
    [0.0, 1.0, 1.0, 1.5, 1.5]
    """
    n = np.asarray(count, dtype=np.int64)
    table = _binomial_imbalance_table()
    exact = table[np.minimum(n, table.size - 1)]
    return np.where(n >= table.size, np.sqrt(2 * n / math.pi), exact)


@functools.cache
def _binomial_imbalance_table(size: int = 1025) -> np.ndarray:
    """``E|2B - n|`` for n = 0 .. size - 1 (:func:`expected_binomial_imbalance`), from log-gamma."""
    values = [0.0]
    for n in range(1, size):
        m = (n - 1) // 2
        log_c = math.lgamma(n) - math.lgamma(m + 1) - math.lgamma(n - m)
        values.append(n * math.exp(log_c - (n - 1) * math.log(2.0)))
    return np.array(values)


def _word_halves(word_index: np.ndarray, d: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per gray word from the smallest to the largest index of the pixels ``inside`` their cell:
    ``(count, above)`` (K,) float64, the pixels inside it and those with ``d > 0``.

    ``word_index`` (n,) float32 integral word indices, ``d`` (n,) float32, ``inside`` (n,) bool.
    One histogram of ``2 index + (d > 0)`` over the masked pixels (OpenCV's, which takes the mask
    instead of a gather; its float32 counts are exact below 2**24)."""
    mask = inside.view(np.uint8)
    low, high, _, _ = cv2.minMaxLoc(word_index, mask)
    side = np.add(word_index, word_index)
    side += d > 0
    bins = 2 * (int(high) - int(low) + 1)
    histogram = cv2.calcHist([side], [0], mask, [bins], [2 * low, 2 * low + bins]).reshape(-1, 2)
    halves = histogram.astype(np.float64)
    return halves.sum(axis=1), halves[:, 1]


def _statistics(
    top: _Rows,
    vertical: tuple[_Rows, _Rows] | None,
    axis: Axis,
    extent: int,
    jump: float,
) -> _Stats:
    g = axis.gray
    assert g is not None
    word = g.word
    x, centre, judged = top
    xs = x[judged]
    cs = centre[judged]
    d = np.subtract(xs, cs)
    # the word index n = rint((c - origin) / word - 0.5): exact, as the centres are origin + (n + 0.5) word
    t = np.subtract(cs, np.float32(g.origin), out=cs)
    t *= np.float32(1 / word)
    t -= np.float32(0.5)
    word_index = np.rint(t, out=t)  # float32, exact small integers
    # the quantiles from an even subsample of at most ~10,000 pixels, partitioned once
    every = max(1, math.ceil(d.size / DISTRIBUTION_PIXELS))
    ds, ns = d[::every], word_index[::every].astype(np.intp)
    q25, median, q75 = _quantiles(ds, (0.25, 0.5, 0.75))
    offset = median
    odd = ((ns ^ (ns >> 1)) & 1).astype(bool)  # the least significant digit of the word's gray code
    digit_offsets = tuple(_median(part) if part.size else None for part in (ds[~odd], ds[odd]))
    outside_projector = np.abs(xs - np.float32((extent - 1) / 2)) > np.float32(extent / 2)
    inside_cell = np.abs(d) <= np.float32(word * (0.5 + CELL_MARGIN_WORDS))
    n_outside_projector = int(np.count_nonzero(outside_projector))
    outside = 1.0 - np.count_nonzero(inside_cell & ~outside_projector) / xs.size
    jumps, changes, per_pixel = _jumps(top, vertical, jump)
    pixels_per_word = word / per_pixel if per_pixel else None
    imbalance: float | None = 1.0
    if pixels_per_word is not None and pixels_per_word < MIN_PIXELS_PER_WORD:
        imbalance = None  # the camera samples each word at a few fixed places: its halves cannot be told
    elif inside_cell.any():
        count, up = _word_halves(word_index, d, inside_cell)
        expected = expected_binomial_imbalance(count)
        informative = float(np.sum(count) - np.sum(expected))
        excess = float(np.sum(np.abs(2 * up - count)) - np.sum(expected))
        imbalance = min(1.0, max(0.0, excess / informative)) if informative > 1e-9 else 0.0
    spread = (q75 - q25) / word
    jump_ratio = jumps / changes if changes >= MIN_WORD_CHANGES else None
    return _Stats(
        pixels=int(xs.size),
        offset=offset,
        digit_offsets=digit_offsets,
        outside=outside,
        outside_projector=n_outside_projector / xs.size,
        imbalance=imbalance,
        spread=spread,
        jump_ratio=jump_ratio,
        pixels_per_word=pixels_per_word,
    )


def _verdict(s: _Stats, word: float) -> tuple[str, list[str], list[str]]:
    """(status, what is wrong, what is undecided) from the statistics."""
    offsets = [s.offset, *(v for v in s.digit_offsets if v is not None)]
    worst = max(offsets, key=abs)
    wrong: list[str] = []
    if abs(worst) >= word / 4:
        wrong.append(f"the coordinates lie {worst:+.3g} px from their words' centres (word {word:g} px)")
    if s.outside_projector > 0.05:
        wrong.append(f"{s.outside_projector:.1%} are decoded outside the projector")
    if s.outside >= 0.2:
        wrong.append(f"{s.outside:.1%} lie outside their word's cell")
    if s.imbalance is not None and s.imbalance >= 0.8:
        wrong.append("the words' cells are filled on one side only")
    if s.spread <= 0.3:
        wrong.append(f"the words' cells are filled over {2 * s.spread:.0%} of their width only")
    if s.jump_ratio is not None and s.jump_ratio >= 0.6:
        wrong.append(f"the coordinate jumps at {s.jump_ratio:.0%} of the gray word changes")
    undecided: list[str] = []
    if abs(worst) > max(1.0, word / 8):
        undecided.append(f"an offset of {worst:+.3g} px from the words' centres")
    if s.outside > 0.05:
        undecided.append(f"{s.outside:.1%} outside their word's cell")
    if s.imbalance is not None and s.imbalance > 0.25:
        undecided.append(f"the words' halves unevenly filled (imbalance {s.imbalance:.2f})")
    if not 0.35 <= s.spread <= 0.65:
        undecided.append(f"the cells' fill spread over {s.spread:.2f} words (0.5 expected)")
    if s.jump_ratio is not None and s.jump_ratio > 0.35:
        undecided.append(f"jumps at {s.jump_ratio:.0%} of the word changes")
    if wrong:
        return INCONSISTENT, wrong, undecided
    if undecided:
        return UNDETERMINED, wrong, undecided
    return CONSISTENT, wrong, undecided


def _likely_correction(axis: Axis, s: _Stats) -> str:
    """A hint read from the statistics (:func:`with_suggestion` replaces it by a tried correction)."""
    g = axis.gray
    assert g is not None
    word = g.word
    if s.outside_projector > 0.05:
        return "many coordinates fall outside the projector: are the axes swapped, or the word or origin wrong?"
    if s.spread <= 0.3 and s.outside < 0.2:
        factor = 0.5 / max(s.spread, 1e-6)
        return f"word looks {factor:.2g} times too wide ({g.word:g} px)"
    if abs(s.offset) >= word / 4 and s.imbalance is not None and s.imbalance >= 0.8:
        return (
            f"origin looks off by {s.offset:+.3g} px: the gray origin should be {g.origin + s.offset:.4g}, "
            f"not {g.origin:.4g} (or every phase origin should move by {-s.offset:+.3g} px)"
        )
    if s.jump_ratio is not None and s.jump_ratio >= 0.6:
        return (
            "the coordinate jumps at the gray word changes or inside the words: check the phase origins "
            f"and shifts, and the gray code's order ({g.order}), inversion and word"
        )
    return "the gray code and the phase disagree: check the origins, the word and the shift"


def check_axis(
    coordinate: np.ndarray,
    centre: np.ndarray,
    judged: np.ndarray,
    axis: Axis,
    extent: int,
    *,
    paired_rows: bool = False,
) -> AxisCheck:
    """The self-check of one axis.

    Parameters
    ----------
    coordinate : (H, W) float32
        Unwrapped coordinate before the gray/phase tolerance, projector units.
    centre : (H, W) float32
        Centre of the gray word each pixel read, projector units.
    judged : (H, W) bool
        Pixels the tolerance judges (reasons 0, 3, 4, 6).
    axis : Axis
        Its description (gray code and chain); :func:`checkable` must hold.
    extent : int
        The projector's size along the axis, px.
    paired_rows : bool
        The rows are samples of a larger image in neighbouring pairs (rows 2k and 2k + 1 are
        neighbours, 2k + 1 and 2k + 2 are not): :func:`sampled_rows`.
    """
    pixels = int(np.count_nonzero(judged))  # the decoder's coordinates and centres are finite there
    rows = (coordinate, centre, judged)
    if paired_rows:  # every row counts; vertical pairs (2k, 2k + 1)
        lower = tuple(a[1::2] for a in rows)
        upper = tuple(a[0 : 2 * lower[0].shape[0] : 2] for a in rows)
        return check_axis_rows(rows, (upper, lower), pixels, axis, extent)  # type: ignore[arg-type]
    _, top, under = check_rows(*coordinate.shape)
    return check_axis_rows(
        tuple(a[top] for a in rows),
        (tuple(a[top[: under.size]] for a in rows), tuple(a[under] for a in rows)),
        pixels,
        axis,
        extent,
    )


def check_axis_rows(
    top: tuple[np.ndarray, np.ndarray, np.ndarray],
    vertical: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]] | None,
    pixels: int,
    axis: Axis,
    extent: int,
) -> AxisCheck:
    """The self-check of one axis from the rows it reads (what :func:`check_axis` does on full images).

    Parameters
    ----------
    top : ((h, W) float32, (h, W) float32, (h, W) bool)
        Coordinate (before the gray/phase tolerance), gray word centre and judged mask of the rows
        whose statistics and horizontal neighbour pairs count (:func:`check_rows`: every s-th row).
    vertical : (upper, lower), optional
        The same three arrays of rows and of the rows directly below them (same count, each row of
        ``lower`` under the same row of ``upper``): the vertical neighbour pairs.
    pixels : int
        Judged pixels of the whole image (at least :data:`MIN_PIXELS` for a status).
    axis, extent
        As :func:`check_axis`.
    """
    g = axis.gray
    assert g is not None
    word = float(g.word)
    if pixels < MIN_PIXELS:
        return AxisCheck(
            status=UNDETERMINED,
            offset_px=None,
            outside_share=None,
            message=f"only {pixels} pixels are lit and modulated enough to check (at least {MIN_PIXELS} needed)",
            pixels=pixels,
            word_px=word,
        )
    jump = 0.5 * min(stage.period for stage in axis.chain() if stage.kind != "gray")
    s = _statistics(top, vertical, axis, extent, jump)
    status, wrong, undecided = _verdict(s, word)
    findings = "; ".join(wrong)
    if status == CONSISTENT:
        message = ""
    elif status == INCONSISTENT:
        message = _sentence(_likely_correction(axis, s), findings)
    else:
        message = _sentence("undetermined", "; ".join(undecided))
    return AxisCheck(
        status=status,
        offset_px=s.offset,
        outside_share=s.outside,
        message=message,
        findings=findings,
        pixels=pixels,
        word_px=word,
        outside_projector_share=s.outside_projector,
        digit_offsets_px=s.digit_offsets,
        imbalance=s.imbalance,
        spread=s.spread,
        jump_ratio=s.jump_ratio,
        pixels_per_word=s.pixels_per_word,
    )


def sampled_rows(height: int, pairs: int = 32) -> np.ndarray:
    """Row indices of about ``pairs`` evenly spaced pairs of neighbouring rows (``r``, ``r + 1``) of an
    image ``height`` rows high: what a check on a sample decodes (``paired_rows``)."""
    if height < 4 * pairs:
        return np.arange(height - height % 2)
    starts = np.linspace(0, height - 2, pairs).astype(np.intp)
    return np.stack([starts, starts + 1], axis=1).ravel()


def _sentence(hint: str, findings: str) -> str:
    return f"{hint[0].upper()}{hint[1:]}: {findings}."


def _variants(codec: Codec, name: str) -> list[tuple[str, str, dict[str, Any]]]:
    """Descriptions differing from ``codec`` by one likely mistake on axis ``name``: (group, the
    sentence naming the correction, the codec's dict), the simplest groups first."""
    base = codec.to_dict()
    where = f"axes.{name}"
    axis = base["axes"][name]
    out: list[tuple[str, str, dict[str, Any]]] = []

    def variant(group: str, label: str, change: Any) -> None:
        data = json.loads(json.dumps(base))
        change(data["axes"][name])
        out.append((group, label, data))

    def moved(origin: float, fraction: float, period: float) -> float:
        """``origin`` moved by ``fraction`` of ``period``, the move taken in [-period / 2, period / 2)."""
        return origin + ((fraction + 0.5) % 1.0 - 0.5) * period

    phases = axis.get("phase", [])
    shifts = [p["shift"] for p in phases]
    variant(
        "shift",
        f"shift looks reversed ({where}.phase[*].shift should be {[-v for v in shifts]}, not {shifts})",
        lambda a: [p.__setitem__("shift", -p["shift"]) for p in a["phase"]],
    )
    gray = axis["gray"]
    other = "lsb_first" if gray["order"] == "msb_first" else "msb_first"
    variant(
        "order",
        f"bit order looks wrong ({where}.gray.order should be {other})",
        lambda a: a["gray"].__setitem__("order", other),
    )
    variant(
        "inverted",
        f"bits look inverted ({where}.gray.inverted should be {str(not gray['inverted']).lower()})",
        lambda a: a["gray"].__setitem__("inverted", not gray["inverted"]),
    )
    for factor, words in ((0.5, "twice too wide"), (2.0, "twice too narrow")):
        word = gray["word"] * factor
        variant(
            "word",
            f"word looks {words} ({where}.gray.word should be {word:.4g}, not {gray['word']:.4g})",
            lambda a, word=word: a["gray"].__setitem__("word", word),
        )
    for k in range(1, 8):
        for i, p in enumerate(phases):
            origin = moved(p["origin"], k / 8, p["period"])
            variant(
                "origin",
                f"origin should be {origin:.6g}, not {p['origin']:.6g} ({where}.phase[{i}].origin)",
                lambda a, i=i, origin=origin: a["phase"][i].__setitem__("origin", origin),
            )
    if len(phases) > 1:
        olds = ", ".join(f"{p['origin']:.6g}" for p in phases)
        for k in range(1, 12):
            news = [moved(p["origin"], k / 12, p["period"]) for p in phases]
            variant(
                "origins",
                f"origins should be {', '.join(f'{v:.6g}' for v in news)}, not {olds} ({where}.phase[*].origin)",
                lambda a, news=news: [p.__setitem__("origin", v) for p, v in zip(a["phase"], news, strict=True)],
            )
    for k in range(1, 4):
        origin = moved(gray["origin"], k / 4, gray["word"])
        variant(
            "gray origin",
            f"gray origin should be {origin:.6g}, not {gray['origin']:.6g} ({where}.gray.origin)",
            lambda a, origin=origin: a["gray"].__setitem__("origin", origin),
        )
    if set(base["axes"]) == {"u", "v"}:
        data = json.loads(json.dumps(base))
        data["axes"]["u"], data["axes"]["v"] = data["axes"]["v"], data["axes"]["u"]
        out.append(("axes", "axes look swapped (the u description codes v, and the v description u)", data))
    return out


def suggest_correction(
    images: np.ndarray, codec: Codec, name: str, decode: Callable[..., Any], options: Any = None
) -> str | None:
    """The likely correction of an ``inconsistent`` axis ``name``, as a sentence: group by group of
    :func:`_variants`, the description under which 32 pairs of rows of ``images`` ((frames, H, W),
    the stack; :func:`sampled_rows`) are ``consistent`` with the smallest ``|offset| / word +
    outside_share``; None when no group has one. Each variant is one ``decode`` of the sample rows
    (:func:`~metrology.core.codecs.decode.decode_codec`, passed in: the decoder calls this module)
    with ``options`` (``CodecDecodeOptions`` or None)."""

    sample = np.ascontiguousarray(images[:, sampled_rows(images.shape[1])])
    best: tuple[float, str] | None = None
    variants = _variants(codec, name)
    for index, (group, label, data) in enumerate(variants):
        try:
            variant = codec_from_dict(data)
        except CodecError:
            variant = None  # e.g. a word wider than the period it unwraps
        if variant is not None:
            checks = decode(sample, variant, options, with_noise=False, threads=1, paired_rows=True).codec_check
            judged = list(checks.values()) if group == "axes" else [checks[name]]
            if judged and all(c.status == CONSISTENT for c in judged):
                score = sum(abs(c.offset_px or 0.0) / c.word_px + (c.outside_share or 0.0) for c in judged)
                if best is None or score < best[0]:
                    best = (score, label)
        last_of_group = index + 1 == len(variants) or variants[index + 1][0] != group
        if last_of_group and best is not None:
            return best[1]
    return None


def with_suggestion(
    check: AxisCheck, images: np.ndarray, codec: Codec, name: str, decode: Callable[..., Any], options: Any = None
) -> AxisCheck:
    """``check`` (inconsistent) with the message naming :func:`suggest_correction`'s correction when
    one is found (``decode``: :func:`~metrology.core.codecs.decode.decode_codec`)."""
    label = suggest_correction(images, codec, name, decode, options)
    return check if label is None else replace(check, message=_sentence(label, check.findings))


def summary_of(checks: Mapping[str, AxisCheck]) -> dict[str, dict[str, Any]]:
    """The ``codec_check`` object: ``{axis: {"status", "offset_px", "outside_share", "message", ...}}``."""
    return {name: check.to_dict() for name, check in checks.items()}


def worst_status(checks: Mapping[str, Any]) -> str | None:
    """The worst status of ``checks`` (AxisCheck objects or their dicts); None when nothing was checked."""
    statuses = [c.status if isinstance(c, AxisCheck) else c.get("status") for c in checks.values()]
    known = [s for s in statuses if s in STATUSES]
    return max(known, key=STATUSES.index) if known else None


def inconsistent_message(checks: Mapping[str, Any]) -> str | None:
    """One line naming each inconsistent axis and its message; None when none is inconsistent."""
    parts = []
    for name, c in checks.items():
        data = c.to_dict() if isinstance(c, AxisCheck) else c
        if data.get("status") == INCONSISTENT:
            parts.append(f"axis {name}: {data.get('message', '')}")
    return "; ".join(parts) if parts else None


def codec_axes_checked(codec: Codec) -> tuple[str, ...]:
    """The axes of ``codec`` the self-check judges."""
    return tuple(name for name, axis in codec.axes.items() if checkable(axis))
