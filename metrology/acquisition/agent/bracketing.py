"""Automatic exposure bracketing for multi-exposure captures (docs/exposures.md).

The camera is taken as linear: a pixel's grey level under a white (``W``) and a black (``K``)
projector frame grows in proportion to the exposure time ``e`` until it saturates at the full
scale ``F``. From flat frames grabbed at a few *probe* exposures (a factor ``probe_step`` apart)
each lit pixel gets two rates, from the longest probe in which its white frame is below ``F``:

    w = W / e          (white level per ms: what saturates)
    m = (W - K) / e    (white-black contrast per ms: twice the fringe modulation B per ms)

A pixel is *lit* when ``W - K >= lit_level * F`` in some probe. Probes go down from the start
exposure until at most ``max_saturated`` of the pixels saturate, and up (by ``probe_step``) until
the longest probe reaches ``e_long`` below and the lit set grew by at most ``darkest_quantile``
of itself at the last step (no darker lit pixels left to find), or the longest exposure allowed.
Then

    e_short = saturation * F / quantile(w, brightest_quantile)      the brightest lit pixels stay
                                                                     below saturation
    e_long  = 2 * margin * B_min / quantile(m, darkest_quantile)     the darkest reach the
                                                                     modulation minimum B_min
                                                                     (with a margin against noise)

and a pixel can use any exposure in ``[2 margin B_min / m, saturation F / w]``, a window of ratio
``r = saturation F m / (2 margin B_min w)``. Exposures spaced geometrically by at most the
``darkest_quantile`` of ``r`` leave no pixel between two exposures, so the bracket is

    n = 1 + ceil(log(e_long / e_short) / log(r_q))      exposures, capped at ``max_exposures``

geometrically spaced from ``e_short`` to ``e_long`` (one exposure, ``e_short``, when
``e_long <= e_short``). With fewer exposures than ``n`` allowed, the same span is covered with a
wider step and :attr:`Bracket.complete` is False.

Several cameras (a stereo rig, both grabbed at every probe): the quantiles are taken per camera,
``e_short`` from the brightest camera's (the smallest ``e_short``), ``e_long`` from the darkest
camera's (the largest) and ``r_q`` the smallest of the cameras' windows, so every camera's lit
pixels are covered as one camera's are.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from metrology.acquisition.agent.checks import full_scale

GrabFlats = Callable[[float], tuple[Any, Any]]
"""``grab_flats(exposure_ms)``: the ``(white, black)`` frames grabbed at that exposure; on a rig of
several cameras a tuple of frames each, one per camera."""

MAX_REQUESTED_EXPOSURES = 8
"""Most exposures an acquisition request may ask for (a list, or ``max_exposures`` of ``"auto"``)."""

ExposureChoice = str | tuple[float, ...]
"""How a multi-exposure capture chooses its exposures: ``"auto"`` (:func:`bracket_exposures`) or the
exposure times, ms, shortest first."""


def parse_exposures(value: object, limit: int = MAX_REQUESTED_EXPOSURES) -> ExposureChoice | None:
    """An exposure choice as a person or a request gives it: None or ``""`` (one exposure),
    ``"auto"``, exposure times in ms as text (``"1,10,100"``) or a list of numbers.

    Times must be finite numbers in (0, 60000] ms, distinct, at most ``limit`` of them; they are
    returned sorted, shortest first (the order given does not matter). Raises :class:`ValueError`
    whose message starts with ``exposures`` and says what was wrong.
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    items: list[object]
    if isinstance(value, str):
        items = [part.strip() for part in value.split(",")]
    elif isinstance(value, list | tuple):
        items = list(value)
    else:
        raise ValueError(f"exposures must be 'auto' or a list of exposure times in ms, got {value!r}")
    if not items:
        raise ValueError("exposures must list at least one exposure time in ms")
    if len(items) > limit:
        raise ValueError(f"exposures may list at most {limit} exposure times, got {len(items)}")
    times: list[float] = []
    for item in items:
        if isinstance(item, bool) or not isinstance(item, str | int | float):
            raise ValueError(f"exposures must be exposure times in ms, got {item!r}")
        try:
            time_ms = float(item)
        except (ValueError, OverflowError):
            raise ValueError(
                f"exposures must be 'auto' or exposure times in ms such as 1,10,100, got {value!r}"
            ) from None
        if not (math.isfinite(time_ms) and 0 < time_ms <= 60_000):
            raise ValueError(f"exposures must be finite exposure times in (0, 60000] ms, got {item!r}")
        times.append(time_ms)
    if len(set(times)) != len(times):
        raise ValueError(f"exposures must be distinct exposure times, got {sorted(times)} with a repeated one")
    return tuple(sorted(times))


@dataclass(frozen=True)
class BracketOptions:
    """The bracketing's rules (module docstring); levels are fractions of the full scale.

    ``min_modulation`` is the decoders' default smallest modulation B (4 grey levels at 8 bits);
    ``margin`` multiplies it so that camera noise does not push the darkest pixels below it.
    """

    max_exposures: int = 3
    saturation: float = 0.9
    min_modulation: float = 4.0 / 255.0
    margin: float = 2.0
    lit_level: float = 8.0 / 255.0
    brightest_quantile: float = 0.999
    darkest_quantile: float = 0.001
    max_saturated: float = 1e-4
    probe_step: float = 4.0
    max_probes: int = 12
    limits_ms: tuple[float, float] = (0.01, 60_000.0)

    def __post_init__(self) -> None:
        if not 1 <= self.max_exposures <= 254:
            raise ValueError(f"max_exposures must be in 1..254, got {self.max_exposures!r}")
        for name in ("saturation", "min_modulation", "lit_level", "brightest_quantile", "darkest_quantile"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise ValueError(f"bracketing option {name} must be in (0, 1), got {value!r}")
        if not 0 <= self.max_saturated < 1:
            raise ValueError(f"bracketing option max_saturated must be in [0, 1), got {self.max_saturated!r}")
        if not (self.margin >= 1 and self.probe_step > 1 and self.max_probes >= 1):
            raise ValueError("bracketing needs margin >= 1, probe_step > 1 and max_probes >= 1")
        low, high = self.limits_ms
        if not 0 < low < high:
            raise ValueError(f"exposure limits must be 0 < low < high ms, got {self.limits_ms!r}")


@dataclass(frozen=True)
class Bracket:
    """The chosen exposures (ms, shortest first) and what they were chosen from.

    ``complete`` is False when ``max_exposures`` was too few for the step the scene needs (or the
    darkest lit pixels need more than the longest exposure allowed); ``probes`` lists each probe's
    exposure, saturated and lit fractions.
    """

    exposures_ms: tuple[float, ...]
    complete: bool
    needed: int
    e_short_ms: float
    e_long_ms: float
    window_ratio: float
    probes: list[dict[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Probe:
    exposure_ms: float
    white: np.ndarray
    black: np.ndarray
    full: int

    @property
    def saturated(self) -> np.ndarray:
        return self.white >= self.full

    @property
    def contrast(self) -> np.ndarray:
        return self.white.astype(np.float64) - self.black.astype(np.float64)

    def summary(self, lit_level: float) -> dict[str, float]:
        return {
            "exposure_ms": self.exposure_ms,
            "saturated_fraction": float(self.saturated.mean()),
            "lit_fraction": float((self.contrast >= lit_level * self.full).mean()),
        }


def bracket_exposures(grab_flats: GrabFlats, start_ms: float, options: BracketOptions | None = None) -> Bracket:
    """Choose a bracket of exposures from white and black frames (module docstring).

    Parameters
    ----------
    grab_flats : callable
        ``grab_flats(exposure_ms) -> (white, black)``, ``(H, W)`` uint8 or uint16 frames; or a
        tuple of ``(H_c, W_c)`` frames each, one per camera (module docstring).
    start_ms : float
        The first probe's exposure, ms, within ``options.limits_ms``.
    options : BracketOptions, optional

    Raises
    ------
    ValueError
        When no pixel is lit at any probe (the projector is not seen), or on a bad option.
    """
    opts = options or BracketOptions()
    low, high = opts.limits_ms
    if not low <= start_ms <= high:
        raise ValueError(f"start exposure {start_ms} ms is outside the camera's limits {opts.limits_ms}")
    probes: list[_Probe] = []
    cameras: list[np.ndarray] = []  # the camera of each pixel of the pooled frames

    def probe(e: float) -> _Probe:
        white, black = grab_flats(e)
        if isinstance(white, (tuple, list)):  # one frame per camera: pooled, each pixel's camera kept
            if not cameras:
                cameras.append(np.concatenate([np.full(np.asarray(w).size, i, np.int16) for i, w in enumerate(white)]))
            white = np.concatenate([np.asarray(w).ravel() for w in white])
            black = np.concatenate([np.asarray(b).ravel() for b in black])
        taken = _Probe(e, np.asarray(white), np.asarray(black), full_scale(np.asarray(white)))
        probes.append(taken)
        return taken

    first = probe(float(start_ms))
    e = first.exposure_ms
    while probes[-1].saturated.mean() > opts.max_saturated and e > low and len(probes) < opts.max_probes:
        e = max(low, e / opts.probe_step)
        probe(e)
    full = first.full
    target = 2 * opts.margin * opts.min_modulation * full  # the white-black contrast the darkest need
    e = max(p.exposure_ms for p in probes)
    lit_before = 0
    while True:
        lit = _lit(probes, opts.lit_level)
        grown = int(lit.sum()) - lit_before
        if lit.any():
            _white, contrast_rate = _rates(probes, lit)
            needed_long = max(target / q for q in _quantiles(contrast_rate, cameras, lit, opts.darkest_quantile))
            if e >= min(needed_long, high) and grown <= opts.darkest_quantile * lit.sum():
                break
        if e >= high or len(probes) >= opts.max_probes:
            break
        lit_before = int(lit.sum())
        e = min(high, e * opts.probe_step)
        probe(e)
    if not lit.any():
        raise ValueError("no pixel is lit by the projector at any probe exposure: is the projector seen?")
    white_rate, contrast_rate = _rates(probes, lit)
    # several cameras: the shortest exposure from the brightest camera, the longest from the darkest
    brightest = max(_quantiles(white_rate, cameras, lit, opts.brightest_quantile))
    e_short = min(high, max(low, opts.saturation * full / brightest))
    needed_long = max(target / q for q in _quantiles(contrast_rate, cameras, lit, opts.darkest_quantile))
    e_long = min(high, max(low, needed_long))
    window = opts.saturation * full * contrast_rate / (target * white_rate)
    ratio = min(_quantiles(window, cameras, lit, opts.darkest_quantile))
    if e_long <= e_short:
        exposures: tuple[float, ...] = (float(e_short),)
        needed = 1
    else:
        needed = 1 + math.ceil(math.log(e_long / e_short) / math.log(ratio)) if ratio > 1 else opts.max_exposures + 1
        n = min(max(needed, 2), opts.max_exposures)
        exposures = tuple(float(x) for x in np.geomspace(e_short, e_long, n)) if n > 1 else (float(e_short),)
    complete = needed <= opts.max_exposures and needed_long <= high
    return Bracket(
        exposures_ms=exposures,
        complete=bool(complete),
        needed=int(needed),
        e_short_ms=float(e_short),
        e_long_ms=float(e_long),
        window_ratio=ratio,
        probes=[p.summary(opts.lit_level) for p in sorted(probes, key=lambda p: p.exposure_ms)],
    )


def _quantiles(values: np.ndarray, cameras: list[np.ndarray], lit: np.ndarray, q: float) -> list[float]:
    """The ``q`` quantile of ``values`` (1-D, one per lit pixel) per camera with lit pixels (one
    camera when ``cameras`` is empty: the frames were one camera's)."""
    if not cameras:
        return [float(np.quantile(values, q))]
    of_lit = cameras[0][lit]
    return [float(np.quantile(values[of_lit == c], q)) for c in np.unique(of_lit)]


def _lit(probes: list[_Probe], lit_level: float) -> np.ndarray:
    """Pixels whose white-black contrast reaches ``lit_level`` of full scale in some probe."""
    return np.logical_or.reduce([p.contrast >= lit_level * p.full for p in probes])


def _rates(probes: list[_Probe], lit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per lit pixel (1-D, in ``lit`` order): white level and white-black contrast per ms, from the
    longest probe in which its white frame is unsaturated (the shortest probe where none is)."""
    ordered = sorted(probes, key=lambda p: p.exposure_ms)
    white_rate = ordered[0].white[lit].astype(np.float64) / ordered[0].exposure_ms
    contrast_rate = ordered[0].contrast[lit] / ordered[0].exposure_ms
    for p in ordered[1:]:
        usable = ~p.saturated[lit]
        white_rate = np.where(usable, p.white[lit] / p.exposure_ms, white_rate)
        contrast_rate = np.where(usable, p.contrast[lit] / p.exposure_ms, contrast_rate)
    return white_rate, np.maximum(contrast_rate, np.finfo(np.float64).tiny)
