"""Code-space filters: what a decoded coordinate must pass before it is triangulated.

The filters read a decoded projector coordinate in *code units* ``c = (x + 0.5) * s`` (``x`` in
projector units, ``s`` codes per projector unit): the paper's light codes on a crossed-axes rig
(``s = nlp / width``), else a quarter of the codec's finest phase period (gcps-v1's ratio of codes
to periods), so one set of thresholds means the same on every model and codec:

- the coded field's margin (:attr:`FilterOptions.field_margin_codes`): codes closer than that to
  either end of the projector, ``0`` or ``extent * s``, are refused (the projector's blur
  biases the phase at the edges of its image);
- the mixed-pixel filter (:func:`unreliable_mask`): depth steps, a band around invalid pixels,
  visibility dips (beyond the visibility's own noise: :func:`visibility_sigma`) and creases of
  the camera blur's bias;
- the camera blur's phase bias ``s2/2 laplacian(c)`` is removed (:mod:`metrology.core.blur`).

The decoder's own validity rules (modulation, saturation, gray/phase consistency) come first;
``min_modulation`` is passed on to it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np

from metrology.core.blur import blur_bias_exceeds
from metrology.core.option_checks import check_number
from metrology.core.tiling import run_tiled, thread_scratch

MAX_FIELD_MARGIN_CODES = 64.0
"""Largest field margin accepted, code units (half the paper's 128 light codes)."""


@dataclass(frozen=True)
class FilterOptions:
    """The code-space filters' thresholds, shared by every codec and model (module docstring).

    ``min_modulation`` in grey levels (None: the decoder's default, 4 % of full scale for gcps-v1),
    ``discontinuity_codes``: neighbouring codes differing by more than this many code units
    mark a depth discontinuity; 0 disables the filter.
    ``field_margin_codes``: codes closer than this to either end of the coded field are refused
    (the projector's blur biases the phase at the edges of the coded field).
    ``min_visibility_ratio``: object pixels whose fringe visibility ``B / 2A`` falls
    below this fraction of the highest visibility in their 3x3 neighbourhood, by more than
    :data:`DIP_NOISE_SIGMAS` standard deviations of their visibility's noise
    (:func:`visibility_sigma`), are mixed pixels (two phases averaged across a depth step
    lower the visibility, whatever the albedo); 0 disables the test.
    ``blur_variance_px2``: variance of the camera's blur (defocus and pixel area), px^2,
    whose phase bias ``s2/2 laplacian(l)`` is removed from the object's codes
    (:mod:`metrology.core.blur`); None estimates it from the reference capture, 0 turns
    the correction off.
    ``edge_band_px``: valid pixels closer than this (4-connected steps) to an
    invalid pixel or a discontinuity are dropped as possibly mixed (shadow edges,
    the coded field's edges, depth steps); 0 keeps them.
    ``max_blur_bias_codes``: object pixels where the camera blur's first-order bias
    ``|s2/2 laplacian(l)|`` exceeds this many code units sit at a crease of the code
    surface (a riser seen edge-on) or beside a depth step too small for
    ``discontinuity_codes``, where the blur correction cannot hold: they are dropped with
    their 4-neighbours (:func:`unreliable_mask`, :func:`~metrology.core.blur.blur_bias_exceeds`).
    0 disables the test, as do a blur variance of 0 and ``edge_band_px = 0``. The default,
    0.015 code (about 0.2 mm of height on the paper's rig), is twice the largest bias on
    smooth surfaces at 1.5 grey levels of noise and half the bias beside a 10 mm riser.
    """

    min_modulation: float | None = None
    discontinuity_codes: float = 1.0
    edge_band_px: int = 2
    field_margin_codes: float = 0.25
    min_visibility_ratio: float = 0.85
    blur_variance_px2: float | None = None
    max_blur_bias_codes: float = 0.015

    def __post_init__(self) -> None:
        check_number("min_modulation", self.min_modulation, allow_none=True)
        check_number("discontinuity_codes", self.discontinuity_codes)
        edge_band = self.edge_band_px
        if isinstance(edge_band, bool) or not isinstance(edge_band, (int, np.integer)) or not 0 <= edge_band <= 100:
            raise ValueError(f"edge_band_px must be an integer in [0, 100], got {edge_band!r}")
        object.__setattr__(self, "edge_band_px", int(edge_band))
        check_number("field_margin_codes", self.field_margin_codes, upper=MAX_FIELD_MARGIN_CODES)
        check_number("min_visibility_ratio", self.min_visibility_ratio, upper=1.0)
        check_number("blur_variance_px2", self.blur_variance_px2, allow_none=True, upper=100.0)
        check_number("max_blur_bias_codes", self.max_blur_bias_codes, upper=1.0)

    def check_field(self, extent_codes: float) -> None:
        """Raise ValueError when ``field_margin_codes`` leaves no coded field of ``extent_codes``
        code units (the margin must be below half of it)."""
        if not self.field_margin_codes < extent_codes / 2:
            raise ValueError(
                f"field_margin_codes must be below half the coded field, {extent_codes / 2:g} codes "
                f"(a wider margin leaves no coded field), got {self.field_margin_codes!r}"
            )

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """The option names, in the order of :meth:`to_dict`."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FilterOptions:
        """Options from :meth:`to_dict`'s object; unknown keys are refused, naming them."""
        unknown = sorted(set(data) - set(cls.keys()))
        if unknown:
            raise ValueError(f"unknown filter option(s): {', '.join(unknown)}")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.keys()}


def refuse_outside_field(codes: np.ndarray, margin_codes: float, extent_codes: float) -> None:
    """Set ``codes`` ((H, W) float32, code units) to NaN where closer than ``margin_codes`` to 0 or
    ``extent_codes`` (or beyond them), in place."""
    margin = np.float32(margin_codes)
    with np.errstate(invalid="ignore"):
        outside = (codes < margin) | (codes > np.float32(extent_codes) - margin)
    codes[outside] = np.nan


DIP_NOISE_SIGMAS = 3.0
"""How far below ``ratio * max3x3(V)`` a pixel's visibility must fall, in standard deviations of
its own visibility's noise, to be a mixed pixel (:func:`unreliable_mask`). The largest of nine
noisy neighbours sits about 1.5 sigma above their mean, so a pixel of a smooth surface is a seed
only ``1.7 + 0.15 V / sigma_V`` sigma below its mean: 3.7 sigma (1 pixel in 10^4) at the dark
end of an 8-bit bracket (``V / sigma_V ~ 13``, a modulation of 10 grey levels at 1.5 of noise),
fewer above. A 50/50 mix across a depth step (77 % of the visibility, 8 % of it under 0.85) is
found wherever ``sigma_V < 0.027 V``: with 8 steps and ``V ~ 0.4``, a modulation of 21 times
the noise or more (32 grey levels at 1.5)."""


NOISE_SAMPLE_PX = 1 << 16
"""Pixels sampled (evenly) by :func:`noise_by_intensity`."""

NOISE_BINS = 16
"""Intensity bins (equally populated) of :func:`noise_by_intensity`."""


def noise_by_intensity(mean: np.ndarray, noise: np.ndarray, dof: int) -> np.ndarray:
    """The camera noise per pixel as a function of intensity, from a noisy per-pixel estimate.

    A phase fit of N steps leaves ``dof = N - 3`` degrees of freedom for its residual noise
    estimate ``s`` (:mod:`metrology.core.codecs.decode`), so ``s^2`` scatters as
    ``sigma^2 chi2(dof) / dof``: with 4 steps a single pixel's estimate is off by a factor of
    two half the time. The camera's noise depends on the pixel's intensity (read noise, shot
    noise), so the pixels with a finite ``s`` (at most :data:`NOISE_SAMPLE_PX`, sampled evenly)
    are sorted into :data:`NOISE_BINS` equally populated bins of their mean ``A``; each bin's
    noise is ``sigma_j = sqrt(median(s^2) / m(dof))``, with ``m(dof)`` the median of
    ``chi2(dof) / dof`` (0.455 for one degree of freedom), which outliers (saturated or mixed
    pixels' residuals) do not move; ``sigma(A)`` is interpolated linearly between the bins'
    median ``A`` (constant beyond them).

    Parameters
    ----------
    mean : (H, W) float32 array
        Each pixel's mean intensity ``A``, grey levels (NaN: no estimate).
    noise : (H, W) float32 array
        Each pixel's residual noise estimate ``s``, grey levels (NaN: none).
    dof : int
        Degrees of freedom of ``s``, >= 1.

    Returns
    -------
    (H, W) float32 array
        ``sigma(A)``, grey levels; NaN where ``A`` is NaN, and everywhere when fewer than
        ``NOISE_BINS`` pixels carry an estimate.
    """
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof!r}")
    a_all = mean.reshape(-1)
    s_all = noise.reshape(-1)
    stride = max(1, a_all.size // NOISE_SAMPLE_PX)
    a, s = a_all[::stride], s_all[::stride]
    known = np.isfinite(a) & np.isfinite(s)
    out = np.full(mean.shape, np.nan, np.float32)
    if np.count_nonzero(known) < NOISE_BINS:
        return out
    a, s = a[known].astype(np.float64), s[known].astype(np.float64)
    order = np.argsort(a, kind="stable")
    a_bins = np.array_split(a[order], NOISE_BINS)
    s2_bins = np.array_split(s[order] ** 2, NOISE_BINS)
    centres = np.array([np.median(b) for b in a_bins])
    from scipy.special import gammaincinv  # here: SciPy's special functions cost 0.15 s to import

    chi2_median = 2.0 * float(gammaincinv(dof / 2, 0.5)) / dof  # median of chi2(dof) / dof
    sigmas = np.sqrt(np.array([np.median(b) for b in s2_bins]) / chi2_median)
    finite = np.isfinite(mean)
    out[finite] = np.interp(mean[finite], centres, sigmas)
    return out


def visibility_sigma(
    visibility: np.ndarray, mean: np.ndarray, noise_grey: np.ndarray, steps_b: int, steps_a: int
) -> np.ndarray:
    """Standard deviation of the fringe visibility ``V = B / 2A`` from the camera noise.

    With independent noise ``sigma`` (grey levels) on each frame, the least-squares amplitude
    ``B`` of an ``N_B``-step sequence has ``sigma_B = sigma sqrt(2 / N_B)`` and the mean ``A`` of an
    ``N_A``-step one ``sigma_A = sigma / sqrt(N_A)``; to first order

        ``sigma_V^2 = sigma_B^2 / (2A)^2 + V^2 sigma_A^2 / A^2 = (sigma / A)^2 (1 / (2 N_B) + V^2 / N_A)``.

    Parameters
    ----------
    visibility, mean, noise_grey : (H, W) float32 arrays
        ``V``, ``A`` (grey levels) and ``sigma`` (grey levels, e.g. :func:`noise_by_intensity`).
    steps_b, steps_a : int
        ``N_B`` and ``N_A``, >= 1.

    Returns
    -------
    (H, W) float32 array
        ``sigma_V``; NaN where an input is NaN or ``A <= 0``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        v2 = np.square(visibility, dtype=np.float32)
        v2 *= np.float32(1.0 / steps_a)
        v2 += np.float32(0.5 / steps_b)
        np.sqrt(v2, out=v2)
        v2 *= noise_grey
        v2 /= mean
    v2[~(mean > 0)] = np.nan
    return v2


_VISIBILITY_NEIGHBOURHOOD = np.ones((3, 3), np.uint8)
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def unreliable_mask(
    codes: np.ndarray,
    max_step_codes: float,
    band_px: int,
    visibility: np.ndarray | None = None,
    min_visibility_ratio: float = 0.0,
    threads: int | None = None,
    *,
    visibility_noise: np.ndarray | None = None,
    blur_variance_px2: float = 0.0,
    max_blur_bias_codes: float = 0.0,
) -> np.ndarray:
    """Valid pixels that may be mixed: near an invalid pixel, a depth step or a visibility dip,
    or at a crease of the codes.

    Parameters
    ----------
    codes : (H, W) float32 array
        Light codes, code units, NaN where invalid.
    max_step_codes : float
        Largest code difference between 4-neighbours on a continuous surface; both
        pixels of a pair that differ by more are discontinuity seeds (0: no seeds).
    band_px : int
        Width of the dropped band: valid pixels within ``band_px`` 4-connected steps
        of an invalid pixel or a seed are marked, and the seeds themselves; 0 marks
        nothing.
    visibility : (H, W) float32 array, optional
        Fringe visibility ``B / 2A`` of each pixel.
    min_visibility_ratio : float
        Pixels whose visibility is below this fraction ``r`` of the maximum of their 3x3
        neighbourhood are seeds too: a pixel straddling a depth step averages two
        phases, which lowers its visibility whatever the albedo (a 50/50 mix across
        a 10 mm step keeps ~77 % of it). With ``visibility_noise`` the dip must exceed the
        visibility's noise: a seed is a pixel where
        ``V < r max3x3(V) - k sigma_V``, ``k =`` :data:`DIP_NOISE_SIGMAS`.
    threads : int, optional
        Threads over row tiles.
    visibility_noise : (H, W) float32 array, optional
        ``sigma_V``, the standard deviation of each pixel's visibility
        (:func:`visibility_sigma`); NaN where unknown, which makes no seed. None: no margin
        (``V < r max3x3(V)``, right for noise-free captures only: on a dark pixel, with a
        modulation of 10 grey levels at 1.5 of noise, a third of the pixels dip for noise alone).
    blur_variance_px2, max_blur_bias_codes : float
        The camera blur's variance (px^2) and the largest first-order blur bias
        ``|s2/2 laplacian(l)|`` (code units) of a reported pixel: beyond it the pixel lies
        at a crease of the code surface, e.g. beside a riser seen edge-on, where the blur
        blends codes from both sides and no correction holds
        (:func:`~metrology.core.blur.blur_bias_exceeds`). The same bound finds small depth
        steps, whose code jump is below ``max_step_codes``: the Laplacian of a blurred step
        peaks about a pixel either side of it and vanishes on it. Such pixels are marked with
        their 4-neighbours (a band of one pixel, whatever ``band_px``), which covers the
        pixels on the step. 0 for either: no such test.

    Returns
    -------
    (H, W) bool array
        True where a valid code should not be reported. A camera pixel straddling a
        shadow edge, the edge of the coded field or a depth step integrates light from
        two surfaces and decodes to a code between them: such pixels are dropped, not
        reported wrong.
    """
    height, width = codes.shape
    if band_px <= 0:
        return np.zeros(codes.shape, bool)
    seeds = np.empty(codes.shape, np.uint8)
    limit = np.float32(max_step_codes)
    ratio = np.float32(min_visibility_ratio)
    # the visibility map when the visibility test runs, else None
    tested_visibility = visibility if min_visibility_ratio > 0 else None
    margin = np.float32(DIP_NOISE_SIGMAS)
    use_creases = blur_variance_px2 > 0 and max_blur_bias_codes > 0
    creases = np.empty(codes.shape, bool) if use_creases else None
    # rows of context: the code steps' reach, or the 5x5 Laplacian's plus the creases' band
    context = 3 if use_creases else 1

    def run(rows: slice) -> None:
        top, bottom = max(rows.start - context, 0), min(rows.stop + context, height)
        c = codes[top:bottom]
        scratch = thread_scratch()
        s = np.isfinite(c, out=scratch.get("seeds", c.shape, bool))
        np.logical_not(s, out=s)
        if max_step_codes > 0:
            for axis in (1, 0):
                ahead = c[:, 1:] if axis == 1 else c[1:]
                behind = c[:, :-1] if axis == 1 else c[:-1]
                step = np.subtract(ahead, behind, out=scratch.get("step", ahead.shape, np.float32))
                np.abs(step, out=step)
                jump = np.greater(step, limit, out=scratch.get("jump", ahead.shape, bool))
                (s[:, 1:] if axis == 1 else s[1:])[...] |= jump
                (s[:, :-1] if axis == 1 else s[:-1])[...] |= jump
        if tested_visibility is not None:
            v = tested_visibility[top:bottom]
            local_max: np.ndarray = cv2.dilate(
                v, _VISIBILITY_NEIGHBOURHOOD, dst=scratch.get("local_max", c.shape, np.float32)
            )
            local_max *= ratio
            if visibility_noise is not None:  # r max3x3(V) - k sigma_V
                noise = np.multiply(
                    visibility_noise[top:bottom], margin, out=scratch.get("dip_noise", c.shape, np.float32)
                )
                local_max -= noise
            s |= np.less(v, local_max, out=scratch.get("dip", c.shape, bool))
        if creases is not None:
            crease = blur_bias_exceeds(
                c,
                blur_variance_px2,
                max_blur_bias_codes,
                scratch.get("crease", c.shape, bool),
                scratch.get("laplacian", c.shape, np.float32),
            )
            band = cv2.dilate(crease.view(np.uint8), _CROSS, dst=scratch.get("crease_band", c.shape, np.uint8))
            creases[rows] = band[rows.start - top : rows.stop - top].view(bool)  # with their 4-neighbours
        seeds[rows] = s[rows.start - top : rows.stop - top].view(np.uint8)

    run_tiled(run, height, width, threads)
    dropped = cv2.dilate(seeds, _CROSS, iterations=band_px).view(bool)
    if creases is not None:
        dropped |= creases
    dropped &= np.isfinite(codes)
    return dropped
