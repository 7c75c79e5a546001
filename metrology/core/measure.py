"""Measurement pipeline: reference + object capture stacks to a height map.

The reference plane is shared by many measurements, so it is decoded once into a
:class:`Reference` (its codes, prepared as the rig model's reference surface) and kept.
Each object stack is then decoded and triangulated tile by tile (Eqs. 1-3 here; the
geometry, Eqs. 14, 16, 17, is the rig model's: :mod:`metrology.core.geometry`) without
materialising full-size temporaries.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.blur import blur_bias_exceeds, correct_blur_bias, estimate_blur_variance
from metrology.core.decode import (
    DecodedStack,
    decode_rows,
    decode_stack,
    default_min_modulation,
    set_nan_where_false,
    smooth_fringes,
    validate_stack,
)
from metrology.core.geometry.base import PreparedGeometry, ReferenceSurface, triangulate_frame
from metrology.core.patterns import N_GRAY_BITS
from metrology.core.rig import Rig
from metrology.core.tiling import run_tiled, thread_scratch

MAX_NLP = 128
"""Most light codes a gcps-v1 rig may have (7-bit gray code)."""
MAX_SMOOTHING_PX = 50.0
"""Largest Gaussian smoothing sigma accepted, px."""


def _check_number(name: str, value: Any, *, allow_none: bool = False, upper: float | None = None) -> None:
    """ValueError naming ``name`` and ``value`` unless ``value`` is a finite number in [0, upper) (or None)."""
    if value is None and allow_none:
        return
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and value >= 0 and (upper is None or value < upper)
    if not ok:
        bound = f"[0, {upper:g})" if upper is not None else "[0, inf)"
        extra = " or None" if allow_none else ""
        raise ValueError(f"{name} must be a finite number in {bound}{extra}, got {value!r}")


@dataclass(frozen=True)
class DecodeOptions:
    """Decoding parameters shared by reference and object (see :func:`decode_stack`).

    ``min_modulation`` in grey levels (None: 4 % of full scale),
    ``consistency_codes`` in code units, ``smoothing_px`` in pixels,
    ``discontinuity_codes``: neighbouring codes differing by more than this many
    code units mark a depth discontinuity; 0 disables the filter.
    ``field_margin_codes``: codes closer than this to 0 or nlp are refused (the
    projector's blur biases the phase at the edges of the coded field).
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
    consistency_codes: float = 0.35
    smoothing_px: float = 0.0
    discontinuity_codes: float = 1.0
    edge_band_px: int = 2
    field_margin_codes: float = 0.25
    min_visibility_ratio: float = 0.85
    blur_variance_px2: float | None = None
    max_blur_bias_codes: float = 0.015

    def __post_init__(self) -> None:
        _check_number("min_modulation", self.min_modulation, allow_none=True)
        _check_number("consistency_codes", self.consistency_codes)
        _check_number("smoothing_px", self.smoothing_px, upper=MAX_SMOOTHING_PX)
        _check_number("discontinuity_codes", self.discontinuity_codes)
        edge_band = self.edge_band_px
        if isinstance(edge_band, bool) or not isinstance(edge_band, (int, np.integer)) or not 0 <= edge_band <= 100:
            raise ValueError(f"edge_band_px must be an integer in [0, 100], got {edge_band!r}")
        object.__setattr__(self, "edge_band_px", int(edge_band))
        _check_number("field_margin_codes", self.field_margin_codes, upper=MAX_NLP / 2)
        _check_number("min_visibility_ratio", self.min_visibility_ratio, upper=1.0)
        _check_number("blur_variance_px2", self.blur_variance_px2, allow_none=True, upper=100.0)
        _check_number("max_blur_bias_codes", self.max_blur_bias_codes, upper=1.0)

    def check_nlp(self, nlp: int) -> None:
        """Raise ValueError when ``field_margin_codes`` leaves no coded field for ``nlp`` light codes
        (the margin must be below ``nlp / 2``)."""
        if not self.field_margin_codes < nlp / 2:
            raise ValueError(
                f"field_margin_codes must be below nlp/2 = {nlp / 2:g} (a wider margin leaves no coded field), "
                f"got {self.field_margin_codes!r}"
            )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DecodeOptions:
        """Options from :meth:`to_dict`'s object; unknown keys are refused, naming them."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown decode option(s): {', '.join(unknown)}")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return {
            "min_modulation": self.min_modulation,
            "consistency_codes": self.consistency_codes,
            "smoothing_px": self.smoothing_px,
            "discontinuity_codes": self.discontinuity_codes,
            "edge_band_px": self.edge_band_px,
            "field_margin_codes": self.field_margin_codes,
            "min_visibility_ratio": self.min_visibility_ratio,
            "blur_variance_px2": self.blur_variance_px2,
            "max_blur_bias_codes": self.max_blur_bias_codes,
        }


@dataclass(frozen=True)
class Reference:
    """A decoded reference plane, kept for many measurements.

    Attributes
    ----------
    decoded : DecodedStack
        Codes of the reference plane (REF of Eq. 16).
    surface : ReferenceSurface
        The rig model's reference surface prepared from ``decoded.codes``
        (:meth:`~metrology.core.geometry.base.PreparedGeometry.reference`).
    gray_surface : ReferenceSurface
        The same for the gray-code-only codes (the comparison heights).
    unreliable : (H, W) bool array
        Valid reference pixels dropped as possibly mixed (:func:`unreliable_mask`).
    blur_variance_px2 : float
        The camera blur's variance used to correct object codes, px^2 (0: no correction).
    """

    decoded: DecodedStack
    surface: ReferenceSurface
    gray_surface: ReferenceSurface
    unreliable: np.ndarray
    blur_variance_px2: float = 0.0


@dataclass(frozen=True)
class HeightResult:
    """Output of :func:`measure_height`.

    Attributes
    ----------
    z_mm : (H, W) float32 array
        GCPS height above R, mm, NaN where not measured.
    gray_z_mm : (H, W) float32 array or None
        Gray-code-only height (codes at the centre of each gray word's cell), mm.
    obj_codes : (H, W) float32 array
        Object codes (OBJ of Eq. 16), code units, NaN where invalid.
    timings_s : dict
        Seconds spent per phase.
    """

    z_mm: np.ndarray
    gray_z_mm: np.ndarray | None
    obj_codes: np.ndarray
    timings_s: dict[str, float] = field(default_factory=dict)

    def statistics(self) -> dict[str, float | int | None]:
        """Summary of the valid heights: count, fraction, min/max/mean/std in mm."""
        return height_statistics(self.z_mm)


def height_statistics(z_mm: np.ndarray) -> dict[str, float | int | None]:
    """Count, valid fraction, and min/max/mean/std (mm) of the finite values of ``z_mm``."""
    valid = np.isfinite(z_mm)
    n = int(valid.sum())
    summary: dict[str, float | int | None] = {"valid_pixels": n, "valid_fraction": n / max(1, z_mm.size)}
    if n:
        values = z_mm[valid].astype(np.float64)
        summary.update(
            min_mm=float(values.min()),
            max_mm=float(values.max()),
            mean_mm=float(values.mean()),
            std_mm=float(values.std()),
        )
    else:
        summary.update(min_mm=None, max_mm=None, mean_mm=None, std_mm=None)
    return summary


def prepare_reference(
    rig: Rig, reference: npt.ArrayLike | DecodedStack, options: DecodeOptions | None = None
) -> Reference:
    """Decode (if needed) a reference stack and precompute its abscissae.

    Parameters
    ----------
    rig : Rig
    reference : (11, H, W) image stack or DecodedStack
        Capture of the reference plane R, shape equal to ``rig.shape``.
    options : DecodeOptions, optional

    Returns
    -------
    Reference
    """
    options = options or DecodeOptions()
    options.check_nlp(rig.nlp)
    decoded = reference if isinstance(reference, DecodedStack) else _decode(rig, reference, options)
    _check_shape(rig, decoded.codes.shape, "reference")
    prepared = rig.prepare()
    surface = prepared.reference(decoded.codes, None)
    gray_surface = prepared.reference(decoded.gray_codes, None)
    unreliable = unreliable_mask(decoded.codes, options.discontinuity_codes, options.edge_band_px)
    blur = options.blur_variance_px2
    if blur is None:
        try:
            blur = estimate_blur_variance(decoded.codes, decoded.visibility)
        except ValueError:
            blur = 0.0  # too small a field to tell: no correction
    return Reference(
        decoded=decoded, surface=surface, gray_surface=gray_surface, unreliable=unreliable, blur_variance_px2=blur
    )


def measure_height(
    rig: Rig,
    reference: npt.ArrayLike | DecodedStack | Reference,
    obj: npt.ArrayLike,
    options: DecodeOptions | None = None,
    *,
    gray_only: bool = True,
    threads: int | None = None,
) -> HeightResult:
    """Height map of an object from its capture stack and the reference's (Eqs. 1-17).

    Parameters
    ----------
    rig : Rig
        Geometry; ``rig.shape`` must equal the images' shape.
    reference : (11, H, W) image stack, DecodedStack or Reference
        The reference plane; pass a :class:`Reference` to reuse its decoding.
    obj : (11, H, W) image stack, uint8, uint16 or float
        The object's capture stack.
    options : DecodeOptions, optional
    gray_only : bool
        Also compute the gray-code-only height map (the paper's comparison).
    threads : int, optional
        Threads over row tiles; default :data:`~metrology.core.tiling.DEFAULT_THREADS`.

    Returns
    -------
    HeightResult

    Raises
    ------
    ValueError
        If a stack is malformed or its shape differs from the rig's.
    """
    options = options or DecodeOptions()
    if not isinstance(options, DecodeOptions):
        raise TypeError(f"options must be DecodeOptions, got {type(options).__name__}")
    options.check_nlp(rig.nlp)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    if not isinstance(reference, Reference):
        reference = prepare_reference(rig, reference, options)
        timings["reference_decode_s"] = time.perf_counter() - start
    stack = validate_stack(obj)
    _check_shape(rig, stack.shape[1:], "object")

    start = time.perf_counter()
    correct_blur = reference.blur_variance_px2 > 0  # then heights come from the corrected codes
    fused = _fused_height(rig, reference, stack, options, threads, triangulate=not correct_blur, gray_words=gray_only)
    z_mm, obj_codes, visibility, gray_codes = fused.z_mm, fused.codes, fused.visibility, fused.gray_codes
    del fused  # the visibility map goes once the mixed-pixel filter has read it
    if options.edge_band_px > 0:
        drop = unreliable_mask(
            obj_codes,
            options.discontinuity_codes,
            options.edge_band_px,
            visibility,
            options.min_visibility_ratio,
            threads,
            blur_variance_px2=reference.blur_variance_px2,
            max_blur_bias_codes=options.max_blur_bias_codes,
        )
        del visibility
        drop |= reference.unreliable
        keep = np.logical_not(drop, out=drop)
        set_nan_where_false(obj_codes, keep, threads)
        if z_mm is not None:
            set_nan_where_false(z_mm, keep, threads)
        del drop, keep
    if correct_blur:
        correct_blur_bias(obj_codes, reference.blur_variance_px2)
        z_mm = _height_map(rig.prepare(), obj_codes, reference.surface, threads)
    assert z_mm is not None
    timings["object_decode_triangulate_s"] = time.perf_counter() - start

    gray_z = None
    if gray_codes is not None:
        start = time.perf_counter()
        gray_z = _height_map(rig.prepare(), gray_codes, reference.gray_surface, threads)
        timings["gray_only_s"] = time.perf_counter() - start
    return HeightResult(z_mm=z_mm, gray_z_mm=gray_z, obj_codes=obj_codes, timings_s=timings)


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


def _decode(rig: Rig, images: npt.ArrayLike | DecodedStack, options: DecodeOptions) -> DecodedStack:
    if isinstance(images, DecodedStack):
        return images
    stack = validate_stack(images)
    _check_shape(rig, stack.shape[1:], "capture")
    return decode_stack(
        stack,
        rig.nlp,
        min_modulation=options.min_modulation,
        consistency_codes=options.consistency_codes,
        smoothing_px=options.smoothing_px,
        field_margin_codes=options.field_margin_codes,
    )


def _check_shape(rig: Rig, shape: tuple[int, ...], what: str) -> None:
    if tuple(shape) != rig.shape:
        raise ValueError(f"{what} images are {shape[1]}x{shape[0]} px but the rig is {rig.width_px}x{rig.height_px} px")


@dataclass(frozen=True)
class _FusedPass:
    codes: np.ndarray
    z_mm: np.ndarray | None
    visibility: np.ndarray | None
    gray_codes: np.ndarray | None


def _fused_height(
    rig: Rig,
    reference: Reference,
    stack: np.ndarray,
    options: DecodeOptions,
    threads: int | None,
    *,
    triangulate: bool,
    gray_words: bool,
) -> _FusedPass:
    """Decode the object tile by tile (the fast path), triangulating against ``reference`` in the
    same pass when ``triangulate``, and keeping the gray-code-only codes when ``gray_words``."""
    _, height, width = stack.shape
    phase = stack[N_GRAY_BITS:]
    if options.smoothing_px > 0:
        phase = smooth_fringes(phase, options.smoothing_px)
    min_modulation = options.min_modulation
    if min_modulation is None:
        min_modulation = default_min_modulation(stack.dtype)
    codes = np.empty((height, width), np.float32)
    z_mm = np.empty((height, width), np.float32) if triangulate else None
    gray_codes = np.empty((height, width), np.float32) if gray_words else None
    # read by the mixed-pixel pass only
    needs_visibility = options.edge_band_px > 0 and options.min_visibility_ratio > 0
    visibility = np.empty((height, width), np.float32) if needs_visibility else None

    prepared = rig.prepare()
    surface = reference.surface

    def run(rows: slice) -> None:
        l = codes[rows]
        decode_rows(
            stack[:N_GRAY_BITS, rows],
            phase[:, rows],
            rig.nlp,
            min_modulation,
            options.consistency_codes,
            options.field_margin_codes,
            l,
            gray_out=None if gray_codes is None else gray_codes[rows],
            visibility_out=None if visibility is None else visibility[rows],
        )
        if z_mm is not None:
            prepared.triangulate_rows(rows, l, None, reference=surface, height_out=z_mm[rows])

    run_tiled(run, height, width, threads)
    return _FusedPass(codes=codes, z_mm=z_mm, visibility=visibility, gray_codes=gray_codes)


def _height_map(
    prepared: PreparedGeometry, codes: np.ndarray, surface: ReferenceSurface, threads: int | None
) -> np.ndarray:
    """Heights (H, W) float32 mm of light codes against a reference surface, tile by tile."""
    z_mm = triangulate_frame(prepared, codes, None, reference=surface, points=False, threads=threads).height_mm
    assert z_mm is not None
    return z_mm
