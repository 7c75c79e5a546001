"""Code-space filters: what a decoded coordinate must pass before it is triangulated.

The filters read a decoded projector coordinate in *code units* ``c = (x + 0.5) * s`` (``x`` in
projector units, ``s`` codes per projector unit): the paper's light codes on a crossed-axes rig
(``s = nlp / width``), else a quarter of the codec's finest phase period (gcps-v1's ratio of codes
to periods), so one set of thresholds means the same on every model and codec:

- the coded field's margin (:attr:`FilterOptions.field_margin_codes`): codes closer than that to
  either end of the projector, ``0`` or ``extent * s``, are refused (the projector's blur
  biases the phase at the edges of its image);
- the mixed-pixel filter (:func:`unreliable_mask`): depth steps, a band around invalid pixels,
  visibility dips and creases of the camera blur's bias;
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
    below this fraction of the highest visibility in their 3x3 neighbourhood are
    mixed pixels (two phases averaged across a depth step lower the visibility,
    whatever the albedo); 0 disables the test.
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
        Pixels whose visibility is below this fraction of the maximum of their 3x3
        neighbourhood are seeds too: a pixel straddling a depth step averages two
        phases, which lowers its visibility whatever the albedo (a 50/50 mix across
        a 10 mm step keeps ~77 % of it).
    threads : int, optional
        Threads over row tiles.
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
