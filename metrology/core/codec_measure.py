"""Heights on a crossed-axes rig from captures of any codec that codes the projector's u axis.

The gcps-v1 stacks keep their fused decoder (:mod:`metrology.core.measure`); a stack of any
other codec (docs/codecs.md) is decoded by :func:`~metrology.core.codecs.decode.decode_codec`
to projector columns ``u``, which become the paper's light codes of the rig,

    l = (u + 0.5) nlp / width          (code units; width = the codec's projector width)

and then go through the same filters and the same geometry as gcps-v1 codes:

* the coded field's margin (``field_margin_codes``: codes closer than that to 0 or nlp refused);
* the mixed-pixel filter (:func:`~metrology.core.measure.unreliable_mask`: depth steps,
  a band around invalid pixels, visibility dips with the visibility ``V = B / 2A`` of the
  codec's final phase sequence, creases of the blur bias) on the object and the reference;
* the camera blur's phase bias ``s2/2 laplacian(l)`` removed (:mod:`metrology.core.blur`),
  ``s2`` estimated from the reference's visibility against its local fringe frequency
  ``k = 2 pi / P_l * dl/dx`` (``P_l`` the final phase period in code units): the estimator
  is written for ``phi = pi/2 l``, so it is given the codes ``4 l / P_l``;
* Eqs. 14, 16, 17 through the crossed-axes geometry seam
  (:meth:`~metrology.core.geometry.base.PreparedGeometry.triangulate_rows`).

The codec decoder's validity rules (modulation, saturation, gray/phase consistency, outside
the projector, slips) replace gcps-v1's modulation and consistency tests; ``min_modulation``
(grey levels) is passed on to it when set. ``smoothing_px`` and ``consistency_codes`` are
gcps-v1 options (a codec states its waveform; its consistency is in periods).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from metrology.core.blur import correct_blur_bias, estimate_blur_variance
from metrology.core.codecs.decode import CodecDecodeOptions, CodecDecoding, decode_codec, validate_codec_stack
from metrology.core.codecs.model import Codec
from metrology.core.decode import set_nan_where_false
from metrology.core.geometry.base import ReferenceSurface, triangulate_frame
from metrology.core.measure import DecodeOptions, unreliable_mask
from metrology.core.rig import Rig


def is_gcps_v1(codec: Codec | None) -> bool:
    """True for no codec or the built-in gcps-v1 (measured by the paper's fused decoder)."""
    return codec is None or codec.name == "gcps-v1"


def check_codec_for_rig(codec: Codec) -> None:
    """ValueError unless ``codec`` codes the u axis (a crossed-axes rig triangulates projector columns)."""
    if "u" not in codec.axes:
        raise ValueError(
            "the codec does not code the projector's u axis (columns): a crossed-axes rig triangulates "
            f"projector columns; the codec codes {', '.join(sorted(codec.axes)) or 'no axis'}"
        )


def codec_decode_options(options: DecodeOptions) -> CodecDecodeOptions:
    """The codec decoder's validity rules for measure options: ``min_modulation`` passed on, the
    rest the codec decoder's defaults (docs/codecs.md)."""
    if options.smoothing_px:
        raise ValueError(
            f"smoothing_px applies to gcps-v1 stacks only (a codec states its waveform), got {options.smoothing_px!r}"
        )
    return CodecDecodeOptions(min_modulation=options.min_modulation)


def final_period_codes(rig: Rig, codec: Codec) -> float | None:
    """Period of the u axis's final unwrapping stage in light codes (``P nlp / width``), or None
    when the chain ends on a gray code (no fringes)."""
    stage = codec.axes["u"].chain()[-1]
    if stage.kind == "gray":
        return None
    return float(stage.period) * rig.nlp / codec.projector_width


@dataclass(frozen=True)
class CodecCodes:
    """Light codes of a decoded capture.

    Attributes
    ----------
    codes : (H, W) float32 array
        ``l = (u + 0.5) nlp / width``, code units, NaN where not decoded or within
        ``field_margin_codes`` of 0 or nlp.
    visibility : (H, W) float32 array
        ``B / 2A`` of the u axis (modulation over twice the mean), NaN where undefined.
    decoding : CodecDecoding
        The codec decoder's output (u, v maps, modulation, reasons...).
    """

    codes: np.ndarray
    visibility: np.ndarray
    decoding: CodecDecoding


def codec_codes(
    rig: Rig,
    images: npt.ArrayLike,
    codec: Codec,
    options: DecodeOptions,
    *,
    what: str,
    with_noise: bool = False,
    threads: int | None = None,
) -> CodecCodes:
    """Decode a stack of ``codec`` and map its u to the rig's light codes (module docstring).

    Raises
    ------
    ValueError
        If the codec does not code u, the stack does not match the codec, or its frames are
        not the rig's size (the message names ``what``: reference, object...).
    """
    check_codec_for_rig(codec)
    stack = validate_codec_stack(np.asarray(images), codec)
    if tuple(stack.shape[1:]) != rig.shape:
        h, w = stack.shape[1:]
        raise ValueError(f"{what} images are {w}x{h} px but the rig is {rig.width_px}x{rig.height_px} px")
    decoding = decode_codec(stack, codec, codec_decode_options(options), with_noise=with_noise, threads=threads)
    axis = decoding.axes["u"]
    codes = axis.coordinate + np.float32(0.5)
    codes *= np.float32(rig.nlp / codec.projector_width)
    margin = np.float32(options.field_margin_codes)
    with np.errstate(invalid="ignore"):
        outside = (codes < margin) | (codes > np.float32(rig.nlp) - margin)
    codes[outside] = np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        visibility = (axis.modulation / (np.float32(2) * axis.mean)).astype(np.float32, copy=False)
    visibility[~np.isfinite(visibility)] = np.nan
    return CodecCodes(codes=codes, visibility=visibility, decoding=decoding)


@dataclass(frozen=True)
class CodecReference:
    """A reference plane captured with a codec, decoded once and kept for many measurements.

    Attributes
    ----------
    codec : Codec
    decoded : CodecCodes
        Its light codes (REF of Eq. 16), visibility and decoding.
    surface : ReferenceSurface
        The crossed-axes reference surface of those codes.
    unreliable : (H, W) bool array
        Valid reference pixels dropped as possibly mixed.
    blur_variance_px2 : float
        The camera blur's variance used to correct object codes, px^2 (0: no correction).
    """

    codec: Codec
    decoded: CodecCodes
    surface: ReferenceSurface
    unreliable: np.ndarray
    blur_variance_px2: float = 0.0


def prepare_codec_reference(
    rig: Rig, images: npt.ArrayLike, codec: Codec, options: DecodeOptions | None = None, threads: int | None = None
) -> CodecReference:
    """Decode a reference capture of ``codec`` and prepare it (surface, mixed pixels, blur variance)."""
    options = options or DecodeOptions()
    options.check_nlp(rig.nlp)
    decoded = codec_codes(rig, images, codec, options, what="reference", threads=threads)
    surface = rig.prepare().reference(decoded.codes, None, threads)
    unreliable = unreliable_mask(decoded.codes, options.discontinuity_codes, options.edge_band_px)
    blur = options.blur_variance_px2
    if blur is None:
        period = final_period_codes(rig, codec)
        blur = 0.0
        if period is not None:
            try:  # the estimator reads phi = pi/2 l: codes of a 4-code period
                blur = estimate_blur_variance(decoded.codes * np.float32(4.0 / period), decoded.visibility)
            except ValueError:
                blur = 0.0  # too small a field to tell: no correction
    return CodecReference(
        codec=codec, decoded=decoded, surface=surface, unreliable=unreliable, blur_variance_px2=float(blur)
    )


@dataclass(frozen=True)
class CodecHeightResult:
    """Output of :func:`measure_codec_height`.

    Attributes
    ----------
    z_mm : (H, W) float32 array
        Height above R, mm, NaN where not measured.
    obj_codes : (H, W) float32 array
        The object's light codes after the filters and the blur correction, code units.
    decoding : CodecDecoding
        The object's decoding (u/v maps, modulation, reasons).
    reference : CodecReference
    timings_s : dict
    """

    z_mm: np.ndarray
    obj_codes: np.ndarray
    decoding: CodecDecoding
    reference: CodecReference
    timings_s: dict[str, float] = field(default_factory=dict)


def measure_codec_height(
    rig: Rig,
    reference: npt.ArrayLike | CodecReference,
    obj: npt.ArrayLike,
    codec: Codec,
    options: DecodeOptions | None = None,
    *,
    with_noise: bool = False,
    threads: int | None = None,
) -> CodecHeightResult:
    """Height map of an object captured with ``codec`` (module docstring), Eqs. 14, 16, 17.

    Parameters
    ----------
    rig : Rig
    reference : (frames, H, W) image stack of ``codec``, or a :class:`CodecReference`
    obj : (frames, H, W) image stack of ``codec``, uint8, uint16 or float
    codec : Codec
        Must code the u axis; the reference kept in a :class:`CodecReference` must have the same codec.
    options : DecodeOptions, optional
    with_noise : bool
        Compute the object's noise maps (for the per-point uncertainty).

    Raises
    ------
    ValueError
        On a codec without u, a stack that does not match the codec or the rig, a bad option.
    """
    options = options or DecodeOptions()
    if not isinstance(options, DecodeOptions):
        raise TypeError(f"options must be DecodeOptions, got {type(options).__name__}")
    options.check_nlp(rig.nlp)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    if not isinstance(reference, CodecReference):
        reference = prepare_codec_reference(rig, reference, codec, options, threads)
        timings["reference_decode_s"] = time.perf_counter() - start
    elif reference.codec != codec:
        raise ValueError("the kept reference was captured with another codec than the object")
    start = time.perf_counter()
    decoded = codec_codes(rig, obj, codec, options, what="object", with_noise=with_noise, threads=threads)
    codes = decoded.codes
    timings["object_decode_s"] = time.perf_counter() - start
    start = time.perf_counter()
    if options.edge_band_px > 0:
        drop = unreliable_mask(
            codes,
            options.discontinuity_codes,
            options.edge_band_px,
            decoded.visibility,
            options.min_visibility_ratio,
            threads,
            blur_variance_px2=reference.blur_variance_px2,
            max_blur_bias_codes=options.max_blur_bias_codes,
        )
        drop |= reference.unreliable
        set_nan_where_false(codes, np.logical_not(drop, out=drop), threads)
    if reference.blur_variance_px2 > 0:
        correct_blur_bias(codes, reference.blur_variance_px2)
    z_mm = triangulate_frame(
        rig.prepare(), codes, None, reference=reference.surface, points=False, threads=threads
    ).height_mm
    assert z_mm is not None
    timings["object_triangulate_s"] = time.perf_counter() - start
    return CodecHeightResult(
        z_mm=z_mm, obj_codes=codes, decoding=decoded.decoding, reference=reference, timings_s=timings
    )
