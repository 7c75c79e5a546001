"""One measurement: capture stacks of any codec to heights or depths, points and sigma, on any
geometric model.

Every measurement takes the same three steps::

    decode (the codec's decoder)  ->  code-space filters (:mod:`metrology.core.filters`)
        ->  the model, prepared (:mod:`metrology.core.geometry`): reference(), triangulate_rows()

1. **Decode.** A stack of any codec goes through the codec decoder
   (:func:`~metrology.core.codecs.decode.decode_codec`) to projector coordinates ``(u, v)``
   with their modulation, mean and noise maps.
2. **Filter.** On each axis the prepared model reads (:meth:`PreparedGeometry.used_axes`), the
   coordinate in code units ``c = (x + 0.5) s`` (``s``: :meth:`PreparedGeometry.code_scale`, else
   :data:`CODES_PER_PERIOD` per finest phase period) loses its coded field's margin and its
   possibly mixed pixels (:func:`~metrology.core.filters.unreliable_mask`), the reference's
   unreliable pixels where the reference surface is per pixel, and the camera blur's bias
   (:func:`~metrology.core.blur.correct_blur_bias`, ``s2`` estimated from the reference).
3. **Triangulate** against the reference surface (:meth:`PreparedGeometry.reference`, a kept
   :class:`Reference`): heights above it; without a reference the model's own result (heights
   above its model plane, or depths: :attr:`GeometryModel.unreferenced_result`). With
   ``sigma``, each point's standard uncertainty from the decoder's noise
   (:func:`~metrology.core.uncertainty.stage_coordinate_sigma`) through the triangulation.

**The fast path.** gcps-v1 stacks on a model that reads the paper's light codes
(:attr:`GeometryModel.light_codes`) take the paper's fused decoder instead (Eqs. 1-3,
:func:`~metrology.core.decode.decode_rows`), which decodes and triangulates each tile of rows in
one pass without full-size temporaries, and also gives the gray-code-only comparison heights.
:func:`uses_fused_gcps_v1` is the one place that chooses it; the filters and the geometry are the
same.

**Multi-exposure captures.** An :class:`~metrology.core.codecs.stack.ExposureStack` (object,
reference or both; the other may be a single stack) is decoded exposure by exposure and fused per
pixel (:func:`~metrology.core.codecs.exposures.decode_exposures`, docs/exposures.md) in step 1;
both captures then take the codec path (gcps-v1 as its codec), steps 2 and 3 unchanged.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import numpy.typing as npt

from metrology.core.blur import correct_blur_bias, estimate_blur_variance
from metrology.core.codecs.check import (
    INCONSISTENT,
    AxisCheck,
    check_axis,
    inconsistent_message,
    sampled_rows,
    with_suggestion,
)
from metrology.core.codecs.model import Codec, gcps_v1_codec, is_gcps_v1
from metrology.core.codecs.stack import ExposureStack
from metrology.core.decode import (
    GcpsV1Options,
    decode_sampled_rows,
    decode_stack,
    decode_tile,
    default_min_modulation,
    set_nan_where_false,
    smooth_fringes,
    use_compiled,
    validate_stack,
)
from metrology.core.filters import (
    FilterOptions,
    noise_by_intensity,
    refuse_outside_field,
    unreliable_mask,
    visibility_sigma,
)
from metrology.core.geometry.base import (
    GeometryModel,
    GeometryOptions,
    PreparedGeometry,
    ReferenceSurface,
    triangulate_frame,
)
from metrology.core.option_checks import check_bool, check_keys, check_positive
from metrology.core.patterns import N_GRAY_BITS
from metrology.core.tiling import run_tiled, thread_scratch
from metrology.core.uncertainty import stage_coordinate_sigma

if TYPE_CHECKING:  # the codec decoder is imported where a codec's stack is decoded: a gcps-v1 measurement never is
    from metrology.core.codecs.decode import AxisDecoding, CodecDecodeOptions, CodecDecoding

CODES_PER_PERIOD = 4.0
"""Code units per finest phase period on a model without codes of its own: gcps-v1's ratio (its
phase period is four light codes), so the filters' thresholds mean the same fraction of a fringe."""
GCPS_V1_NLP = 128
"""Light codes across the built-in gcps-v1 codec's projector (its phase period is 4 of them)."""


# --------------------------------------------------------------------------- options
def decode_block(filters: FilterOptions, gcps_v1: GcpsV1Options) -> dict[str, Any]:
    """The ``decode`` object of the options' JSON form: the filter thresholds and the gcps-v1
    settings side by side, as stored since gcps-v1 (``min_modulation`` ... ``max_blur_bias_codes``)."""
    data = filters.to_dict()
    data.update(gcps_v1.to_dict())
    return {key: data[key] for key in DECODE_KEYS}


DECODE_KEYS: tuple[str, ...] = (
    "min_modulation",
    "consistency_codes",
    "smoothing_px",
    "discontinuity_codes",
    "edge_band_px",
    "field_margin_codes",
    "min_visibility_ratio",
    "blur_variance_px2",
    "max_blur_bias_codes",
)
"""Keys of the ``decode`` object (:func:`decode_block`), in its order."""


def split_decode_block(data: Any) -> tuple[FilterOptions, GcpsV1Options]:
    """The :class:`FilterOptions` and :class:`GcpsV1Options` of a ``decode`` object (None: the
    defaults); unknown keys are refused, naming them."""
    if data is None:
        return FilterOptions(), GcpsV1Options()
    if not isinstance(data, Mapping):
        raise ValueError(f"decode must be an object of decode options, got {data!r}")
    unknown = sorted(set(data) - set(DECODE_KEYS))
    if unknown:
        raise ValueError(f"unknown decode option(s): {', '.join(unknown)}")
    gcps_keys = set(GcpsV1Options.keys())
    filters = FilterOptions(**{k: v for k, v in data.items() if k not in gcps_keys})
    gcps_v1 = GcpsV1Options(**{k: v for k, v in data.items() if k in gcps_keys})
    return filters, gcps_v1


SETTINGS_KEYS: tuple[str, ...] = ("decode", "triangulate", "method", "match")
"""Keys of the measurement settings in an options object's JSON form (:func:`settings_to_dict`)."""


def settings_to_dict(filters: FilterOptions, gcps_v1: GcpsV1Options, geometry: GeometryOptions) -> dict[str, Any]:
    """``{"decode": {...}, "triangulate", "method"[, "match"]}``: how an options object that measures
    (measure, characterize, acceptance, calibrate) writes its filters, gcps-v1 settings and
    geometry options."""
    return {"decode": decode_block(filters, gcps_v1), **geometry.to_dict()}


def settings_from_dict(data: Mapping[str, Any]) -> dict[str, Any]:
    """The ``filters``, ``gcps_v1`` and ``geometry`` keyword arguments of the settings in ``data``
    (its keys among :data:`SETTINGS_KEYS`; the others are the caller's)."""
    filters, gcps_v1 = split_decode_block(data.get("decode"))
    geometry = GeometryOptions.from_dict({k: data[k] for k in ("triangulate", "method", "match") if k in data})
    return {"filters": filters, "gcps_v1": gcps_v1, "geometry": geometry}


def check_settings(options: Any) -> None:
    """ValueError unless ``options.filters``, ``.gcps_v1`` and ``.geometry`` have their types."""
    for name, kind in (("filters", FilterOptions), ("gcps_v1", GcpsV1Options), ("geometry", GeometryOptions)):
        if not isinstance(getattr(options, name), kind):
            raise ValueError(f"{name} must be {kind.__name__}, got {getattr(options, name)!r}")


@dataclass(frozen=True)
class MeasureOptions:
    """Options of :func:`measure` (and of the ``gcps measure`` command and the measurement job).

    Attributes
    ----------
    filters : FilterOptions
        The code-space filters' thresholds (every codec and model).
    gcps_v1 : GcpsV1Options
        The paper's decoder's own settings (gcps-v1 stacks).
    geometry : GeometryOptions
        Which projector axis the model triangulates, and how.
    gray_only : bool
        Also the gray-code-only comparison heights of the paper (gcps-v1 stacks on a model with
        light codes; default True).
    sigma : bool
        Also each point's standard uncertainty from the object's phase noise (default False;
        needs a final phase sequence of N >= 4 steps on the triangulated axis).
    max_sigma_mm : float or None
        Drop the points whose uncertainty exceeds this, mm (implies ``sigma``).
    allow_inconsistent_codec : bool
        Measure even when the codec self-check (:mod:`metrology.core.codecs.check`) finds the
        object capture ``inconsistent`` with its codec (default False: the measurement fails
        with the check's message).

    JSON form (:meth:`to_dict`): ``{"decode": {...}, "gray_only", "sigma", "triangulate",
    "method", "max_sigma_mm", "allow_inconsistent_codec"}``, the filter and gcps-v1 settings together under ``decode``
    (:func:`decode_block`). :meth:`from_dict` reads any subset of it.
    """

    filters: FilterOptions = field(default_factory=FilterOptions)
    gcps_v1: GcpsV1Options = field(default_factory=GcpsV1Options)
    geometry: GeometryOptions = field(default_factory=GeometryOptions)
    gray_only: bool = True
    sigma: bool = False
    max_sigma_mm: float | None = None
    allow_inconsistent_codec: bool = False

    def __post_init__(self) -> None:
        check_settings(self)
        check_bool("gray_only", self.gray_only)
        check_bool("sigma", self.sigma)
        check_bool("allow_inconsistent_codec", self.allow_inconsistent_codec)
        if self.max_sigma_mm is not None:
            try:
                check_positive("max_sigma_mm", self.max_sigma_mm)
            except ValueError:
                raise ValueError(f"max_sigma_mm must be a positive number of mm, got {self.max_sigma_mm!r}") from None

    def with_sigma(self) -> MeasureOptions:
        """These options, computing sigma too."""
        return replace(self, sigma=True)

    @property
    def wants_sigma(self) -> bool:
        """Sigma is computed: asked for, or needed by ``max_sigma_mm``."""
        return self.sigma or self.max_sigma_mm is not None

    def to_dict(self) -> dict[str, Any]:
        return {
            **settings_to_dict(self.filters, self.gcps_v1, self.geometry),
            "gray_only": self.gray_only,
            "sigma": self.sigma,
            "max_sigma_mm": self.max_sigma_mm,
            "allow_inconsistent_codec": self.allow_inconsistent_codec,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MeasureOptions:
        own = ("gray_only", "sigma", "max_sigma_mm", "allow_inconsistent_codec")
        check_keys("measure", data, {*SETTINGS_KEYS, *own})
        return cls(**settings_from_dict(data), **{k: data[k] for k in own if k in data})

    @classmethod
    def of(cls, settings: Any, **changes: Any) -> MeasureOptions:
        """The measure options of another options object's settings (``filters``, ``gcps_v1``,
        ``geometry``), no gray-code-only heights unless ``changes`` say so."""
        values: dict[str, Any] = {"gray_only": False, **changes}
        return cls(filters=settings.filters, gcps_v1=settings.gcps_v1, geometry=settings.geometry, **values)


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Reference:
    """A capture of the reference plane, decoded once, filtered and prepared for a model: kept for
    many measurements (:func:`prepare_reference`).

    Attributes
    ----------
    model : GeometryModel
    codec : Codec or None
        The capture's codec (None: the paper's gcps-v1 through the fused decoder).
    geometry : GeometryOptions
    surface : ReferenceSurface
        The model's reference surface (:meth:`~PreparedGeometry.reference`).
    codes : (H, W) float32 array
        The reference's code of the triangulated axis, code units (the paper's light codes REF of
        Eq. 16 on a crossed-axes rig), NaN where not decoded or filtered out.
    unreliable : (H, W) bool array or None
        Valid reference pixels dropped as possibly mixed, where the surface is per pixel (the
        object's pixels there are dropped too); None for a fitted surface.
    blur_variance_px2 : float
        The camera blur's variance used to correct object codes, px^2 (0: no correction).
    gray_surface : ReferenceSurface or None
        The surface of the gray-code-only codes (the fused gcps-v1 path's comparison heights).
    """

    model: GeometryModel
    codec: Codec | None
    geometry: GeometryOptions
    surface: ReferenceSurface
    codes: np.ndarray
    unreliable: np.ndarray | None
    blur_variance_px2: float = 0.0
    gray_surface: ReferenceSurface | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.surface.shape

    def prepared_geometry(self) -> PreparedGeometry:
        """The model prepared as it was for this reference (cached by the model: no tables rebuilt)."""
        if self.codec is None:  # the fused gcps-v1 path reads light codes
            return self.model.prepare(None, None, self.geometry)
        return _prepared(self.model, self.codec, self.geometry)


@dataclass(frozen=True)
class Measurement:
    """Output of :func:`measure`.

    Attributes
    ----------
    z_mm : (H, W) float32 array
        Heights above the reference plane (with a reference), else what the model gives alone
        (:attr:`z_kind`), mm; NaN where not measured.
    z_kind : {'height', 'depth'}
        What ``z_mm`` is: a height above the reference (or model) plane, or a depth (camera Z).
    codes : (H, W) float32 array
        The object's code of the triangulated axis after the filters and the blur correction,
        code units (light codes on a crossed-axes rig), NaN where not measured.
    prepared : PreparedGeometry
        The model as it triangulated (its ``axis``, ``method``, :meth:`~PreparedGeometry.points_from_heights`).
    reference : Reference or None
    gray_z_mm : (H, W) float32 array or None
        The paper's gray-code-only heights (fused gcps-v1 path with ``gray_only``), mm.
    sigma_mm : (H, W) float32 array or None
        Each point's standard uncertainty, mm (``options.sigma``), NaN where not measured.
    decoding : CodecDecoding or None
        The codec decoder's output (u/v maps, modulation, reasons); None on the fused path.
    off_ray_points_mm : (H, W, 3) float32 array or None
        The triangulated points when the method moves them off the camera rays (a midpoint).
    dropped_by_max_sigma : int
        Points dropped by ``options.max_sigma_mm``.
    timings_s : dict
        Seconds per phase.
    codec_check : mapping of str to AxisCheck
        The codec self-check of the object capture per checked axis (on the fused gcps-v1 path,
        of 8 pairs of rows decoded by the codec decoder: :func:`check_gcps_v1_sample`).
    pairs : (H, W) uint8 array or None
        For a model of several devices (:meth:`PreparedGeometry.combine`), the pairs that measured
        each pixel (a stereo rig's bits: :mod:`metrology.core.geometry.stereo_fusion`); None for one
        camera. :meth:`pairs_map` zeroes it where ``z_mm`` is not finite.
    camera_decodings : tuple of CodecDecoding
        For a model of several cameras, each camera's decoding, camera 0 first (camera 0's is
        :attr:`decoding`): per-pixel maps on that camera's own grid, among them the exposure each
        of its pixels used (:meth:`camera_exposure_map`). Empty for one camera.
    """

    z_mm: np.ndarray
    z_kind: str
    codes: np.ndarray
    prepared: PreparedGeometry
    reference: Reference | None
    gray_z_mm: np.ndarray | None = None
    sigma_mm: np.ndarray | None = None
    decoding: CodecDecoding | None = None
    off_ray_points_mm: np.ndarray | None = None
    dropped_by_max_sigma: int = 0
    timings_s: dict[str, float] = field(default_factory=dict)
    codec_check: Mapping[str, AxisCheck] = field(default_factory=dict)
    pairs: np.ndarray | None = None
    camera_decodings: tuple[CodecDecoding, ...] = ()

    @property
    def model(self) -> GeometryModel:
        return self.prepared.model

    @property
    def z_meaning(self) -> str:
        """``z_mm`` in words: "height above the reference plane", "depth (camera Z)"..."""
        if self.reference is not None:
            return "height above the reference plane"
        return "depth (camera Z)" if self.z_kind == "depth" else "height above the model plane"

    @property
    def points_follow_from_heights(self) -> bool:
        """True when the points are a function of ``z_mm`` alone: on the camera rays of a model with
        a plane of its own (:meth:`PreparedGeometry.points_from_heights` without a reference gives
        them exactly), so that storing the heights stores the points too."""
        return self.off_ray_points_mm is None and self.prepared.has_model_plane and self.z_kind == "height"

    def exposure_map(self) -> np.ndarray | None:
        """Which exposure of a multi-exposure object capture measured each point (docs/exposures.md).

        Returns
        -------
        (H, W) uint8 array or None
            Per pixel, the index of the exposure (0 the least exposed, as in
            ``decoding.exposure_names``) whose decoding gave the triangulated axis's coordinate;
            where the model reads two axes (:meth:`PreparedGeometry.used_axes`), the more exposed of
            their two exposures. :data:`~metrology.core.codecs.exposures.NO_EXPOSURE` (255) where
            ``z_mm`` is not finite. None when the object was not decoded as a multi-exposure capture.
        """
        decoding = self.decoding
        if decoding is None or not decoding.exposure_names:
            return None
        axes = [axis for axis in self.prepared.used_axes(tuple(decoding.exposure)) if axis in decoding.exposure]
        if not axes:
            axes = [self.prepared.axis]
        used = np.maximum.reduce([np.asarray(decoding.exposure[axis], np.uint8) for axis in axes])
        from metrology.core.codecs.exposures import NO_EXPOSURE

        return np.where(np.isfinite(self.z_mm), used, np.uint8(NO_EXPOSURE)).astype(np.uint8)

    def points_per_exposure(self) -> dict[str, int] | None:
        """The measured points per exposure name of :meth:`exposure_map` (None for a single capture)."""
        used = self.exposure_map()
        if used is None:
            return None
        assert self.decoding is not None
        from metrology.core.codecs.exposures import NO_EXPOSURE

        counts = np.bincount(used.ravel(), minlength=NO_EXPOSURE + 1)
        return {name: int(counts[index]) for index, name in enumerate(self.decoding.exposure_names)}

    def camera_exposure_map(self, camera: int) -> np.ndarray | None:
        """Which exposure camera ``camera`` of a model of several cameras used at each of its own
        pixels (docs/exposures.md, "Stereo rigs").

        Returns
        -------
        (H_c, W_c) uint8 array or None
            On camera ``camera``'s pixel grid: the exposure index (0 the least exposed) of the
            coordinate the model read there (the more exposed of the used axes' exposures),
            :data:`~metrology.core.codecs.exposures.NO_EXPOSURE` (255) where none decoded. The map
            of the decoding, before matching: a pixel of camera 1 counts whether or not a point of
            camera 0 was matched to it. None for one camera or a single-exposure capture.
        """
        if not self.camera_decodings:
            return None
        decoding = self.camera_decodings[camera]
        if not decoding.exposure_names:
            return None
        axes = [axis for axis in self.prepared.used_axes(tuple(decoding.exposure)) if axis in decoding.exposure]
        # NO_EXPOSURE (255) is the largest uint8: a pixel no exposure decoded on one axis stays 255
        maps = [np.asarray(decoding.exposure[axis], np.uint8) for axis in axes or [self.prepared.axis]]
        return np.maximum.reduce(maps)

    def camera_pixels_per_exposure(self, camera: int) -> dict[str, int] | None:
        """The pixels of camera ``camera`` per exposure name of :meth:`camera_exposure_map`, and
        ``"none"``; None for one camera or a single-exposure capture."""
        used = self.camera_exposure_map(camera)
        if used is None:
            return None
        names = self.camera_decodings[camera].exposure_names
        from metrology.core.codecs.exposures import NO_EXPOSURE

        counts = np.bincount(used.ravel(), minlength=NO_EXPOSURE + 1)
        return {**{name: int(counts[index]) for index, name in enumerate(names)}, "none": int(counts[NO_EXPOSURE])}

    def pairs_map(self) -> np.ndarray | None:
        """Which pairs of a model of several devices measured each point (docs/stereo.md).

        Returns
        -------
        (H, W) uint8 array or None
            :attr:`pairs` (bit 0 camera 0 - camera 1, bit 1 camera 0 - projector, bit 2 camera 1 -
            projector), 0 where ``z_mm`` is not finite (a point dropped by a later filter too); None
            for a model of one camera.
        """
        if self.pairs is None:
            return None
        return np.where(np.isfinite(self.z_mm), self.pairs, np.uint8(0)).astype(np.uint8)

    def points_per_pairs(self) -> dict[str, int] | None:
        """The measured points per pair combination of :meth:`pairs_map`
        (:func:`~metrology.core.geometry.stereo_fusion.points_per_pairs`), None for one camera."""
        pairs = self.pairs_map()
        if pairs is None:
            return None
        from metrology.core.geometry.stereo_fusion import points_per_pairs  # its kernels: numba, on demand

        return points_per_pairs(pairs)

    def points_mm(self, dtype: npt.DTypeLike = np.float32) -> np.ndarray:
        """``(H, W, 3)`` points of ``dtype``, mm, in the model frame (:attr:`GeometryModel.frame`);
        NaN where not measured. On the camera rays they are computed from ``z_mm`` in float64
        (:meth:`PreparedGeometry.points_from_heights`), else they are the triangulated ones."""
        if self.off_ray_points_mm is not None:
            return self.off_ray_points_mm.astype(dtype, copy=False)
        surface = None if self.reference is None else self.reference.surface
        if self.z_kind == "depth":
            surface = None  # points_from_heights reads a depth when given no reference
        return self.prepared.points_from_heights(self.z_mm, surface).astype(dtype, copy=False)


def height_statistics(z_mm: np.ndarray) -> dict[str, float | int | None]:
    """Count, valid fraction, and min/max/mean/std (mm) of the finite values of ``z_mm``."""
    valid = np.isfinite(z_mm)
    n = int(np.count_nonzero(valid))
    summary: dict[str, float | int | None] = {"valid_pixels": n, "valid_fraction": n / max(1, z_mm.size)}
    if n:
        values = z_mm[valid].astype(np.float64)
        low, high = float(values.min()), float(values.max())
        # numpy's mean and std to the bit (the same pairwise sums, divisions and square root), with
        # the mean summed once and the deviations squared in place of a second float64 copy
        mean = np.add.reduce(values) / n
        values -= mean
        np.multiply(values, values, out=values)
        summary.update(min_mm=low, max_mm=high, mean_mm=float(mean), std_mm=float(np.sqrt(np.add.reduce(values) / n)))
    else:
        summary.update(min_mm=None, max_mm=None, mean_mm=None, std_mm=None)
    return summary


# --------------------------------------------------------------------------- the one choice
def uses_fused_gcps_v1(model: GeometryModel, codec: Codec | None, *, exposures: bool = False) -> bool:
    """True when a stack of ``codec`` on ``model`` takes the fused gcps-v1 kernel: gcps-v1 stacks
    on a model that triangulates the paper's light codes (module docstring), single-exposure
    captures only (``exposures``: a multi-exposure capture is involved, fused per pixel by the
    codec path, docs/exposures.md). The only place that chooses between the two decoders."""
    return is_gcps_v1(codec) and model.light_codes is not None and not exposures


# --------------------------------------------------------------------------- public entries
def prepare_reference(
    model: GeometryModel,
    images: npt.ArrayLike | ExposureStack,
    codec: Codec | None = None,
    options: MeasureOptions | None = None,
    *,
    threads: int | None = None,
) -> Reference:
    """Decode a capture of the reference plane, filter it and prepare the model's reference surface.

    Parameters
    ----------
    model : GeometryModel
    images : (frames, H, W) image stack of ``codec`` (``(11, H, W)`` for gcps-v1), or ExposureStack
        (a sequence of one stack per camera, camera 0 first, for a model of several cameras:
        :func:`camera_stacks`)
    codec : Codec, optional
        The capture's codec; None is the paper's gcps-v1.
    options : MeasureOptions, optional
        The filters (and the gcps-v1 settings and geometry options) the measurements will use.

    Raises
    ------
    ValueError
        On a malformed stack, a stack that does not match its codec or the model's camera, a
        codec lacking an axis the model needs, or a bad option.
    """
    options = options or MeasureOptions()
    multi = _has_exposures(images)
    if uses_fused_gcps_v1(model, codec, exposures=multi):
        assert not isinstance(images, ExposureStack)
        return _fused_reference(model, images, options, threads)
    codec = codec if codec is not None else gcps_v1_codec()
    prepared = _prepared(model, codec, options.geometry)
    cameras = [
        _decode_and_filter(
            prepared, stack, codec, options, None, "reference", with_noise=False, threads=threads, camera=index
        )
        for index, stack in enumerate(camera_stacks(model, images))
    ]
    coded = cameras[0]
    blur = options.filters.blur_variance_px2
    if blur is None:  # from the codes before the mixed-pixel filter drops any
        blur = _estimated_blur(coded.codes[prepared.axis], coded.visibility[prepared.axis], coded.periods_codes)
    for camera in cameras:
        camera.drop(threads)
    combined = prepared.combine([_coordinates(camera) for camera in cameras], None, threads)
    surface = prepared.reference(combined.u, combined.v, threads)
    unreliable = coded.dropped if surface.per_pixel else None
    return Reference(
        model=model,
        codec=codec,
        geometry=options.geometry,
        surface=surface,
        codes=coded.codes[prepared.axis],
        unreliable=unreliable,
        blur_variance_px2=float(blur),
    )


def measure(
    model: GeometryModel,
    obj: npt.ArrayLike | ExposureStack,
    codec: Codec | None = None,
    *,
    reference: Reference | ExposureStack | npt.ArrayLike | None = None,
    options: MeasureOptions | None = None,
    threads: int | None = None,
) -> Measurement:
    """Heights or depths, points and sigma of an object capture (module docstring).

    Parameters
    ----------
    model : GeometryModel
    obj : (frames, H, W) image stack of ``codec``, uint8, uint16 or float, or ExposureStack
        A multi-exposure capture (docs/exposures.md) is fused per pixel
        (:func:`~metrology.core.codecs.exposures.decode_exposures`); either capture may be one.
        For a model of several cameras (:attr:`~GeometryModel.cameras`), a sequence of one stack
        per camera, camera 0 first (:func:`camera_stacks`): each is decoded and filtered alike, and
        the prepared model combines their maps (:meth:`PreparedGeometry.combine`); the results lie
        on camera 0's pixel grid.
    codec : Codec, optional
        The stacks' codec; None is the paper's gcps-v1 (eleven named patterns).
    reference : Reference or (frames, H, W) image stack, optional
        The reference plane: a kept :class:`Reference` (prepared with the same codec, model and
        geometry options), or its stack (prepared now). Required by a model whose
        :attr:`~GeometryModel.requires_reference` is True.
    options : MeasureOptions, optional
    threads : int, optional
        Threads over row tiles (does not change the result).

    Raises
    ------
    ValueError
        On a malformed stack, a stack that does not match its codec or the model's camera, a
        codec lacking an axis the model needs, a missing or mismatched reference, sigma asked
        for without a noise estimate, or a bad option.
    """
    options = options or MeasureOptions()
    if not isinstance(options, MeasureOptions):
        raise TypeError(f"options must be MeasureOptions, got {type(options).__name__}")
    timings: dict[str, float] = {}
    if reference is None and model.requires_reference:
        raise ValueError(
            f"a {model.short_label} rig measures against a capture of the reference plane: give a reference"
        )
    obj, reference, codec = exposure_inputs(obj, reference, codec)
    multi = _has_exposures(obj)
    if reference is not None and not isinstance(reference, Reference):
        start = time.perf_counter()
        reference = prepare_reference(model, reference, codec, options, threads=threads)
        timings["reference_decode_s"] = time.perf_counter() - start
    if reference is not None:
        _check_reference(reference, model, codec, options, exposures=multi)
    if uses_fused_gcps_v1(model, codec, exposures=multi):
        assert not isinstance(obj, ExposureStack)
        return _fused_measure(model, reference, obj, codec, options, timings, threads)
    assert codec is not None
    return _codec_measure(model, reference, obj, codec, options, timings, threads)


_Obj = TypeVar("_Obj")
_Ref = TypeVar("_Ref")


def exposure_inputs(
    obj: _Obj, reference: _Ref, codec: Codec | None
) -> tuple[_Obj | ExposureStack, _Ref | ExposureStack, Codec | None]:
    """``(obj, reference, codec)`` as :func:`measure` takes them on: when either capture is a
    multi-exposure one, both go through the codec path, fused per pixel (docs/exposures.md): the
    codec None becomes gcps-v1's codec and a single stack (object or reference) an
    :class:`ExposureStack` of one exposure. Otherwise they are returned as given. A caller that
    prepares the reference itself (the command line's kept references) calls this first, so that
    the reference is prepared as :func:`measure` would prepare it.

    A capture of several cameras (a tuple or list of one capture per camera, camera 0 first) is
    multi-exposure when any camera's is; each single stack of it then becomes an exposure stack of
    one, camera by camera, the sequence kept."""
    if not (_has_exposures(obj) or _has_exposures(reference)):
        return obj, reference, codec
    codec = codec if codec is not None else gcps_v1_codec()
    fused_obj: Any = as_exposures(obj)
    fused_reference: Any = reference
    if reference is not None and not isinstance(reference, Reference):
        fused_reference = as_exposures(reference)
    return fused_obj, fused_reference, codec


def _has_exposures(capture: Any) -> bool:
    """True for an :class:`ExposureStack`, or a sequence of per-camera captures holding one."""
    if isinstance(capture, (tuple, list)):
        return any(isinstance(stack, ExposureStack) for stack in capture)
    return isinstance(capture, ExposureStack)


def as_exposures(capture: Any) -> Any:
    """``capture`` with every single stack an :class:`ExposureStack` of one exposure (per camera for
    a sequence of per-camera captures, a tuple of them): how a single capture is measured beside a
    multi-exposure one (docs/exposures.md)."""
    if isinstance(capture, (tuple, list)):
        return tuple(as_exposures(stack) for stack in capture)
    return capture if isinstance(capture, ExposureStack) else ExposureStack.single(np.asarray(capture))


# --------------------------------------------------------------------------- shared steps
def _check_reference(
    reference: Reference, model: GeometryModel, codec: Codec | None, options: MeasureOptions, *, exposures: bool = False
) -> None:
    expected = None if uses_fused_gcps_v1(model, codec, exposures=exposures) else codec
    if reference.codec != expected:
        raise ValueError("the kept reference was captured with another codec than the object")
    if reference.model != model:
        raise ValueError("the kept reference was prepared for another rig than the object's")
    if reference.geometry != options.geometry:
        raise ValueError("the kept reference was prepared with other triangulation options than the measurement's")


def _frames_shape(model: GeometryModel, shape: tuple[int, ...], what: str, camera: int = 0) -> None:
    expected = model.camera_shapes[camera]
    if tuple(shape) != tuple(expected):
        h, w = shape
        mh, mw = expected
        if model.cameras > 1:
            raise ValueError(
                f"camera {camera}'s {what} frames are {w}x{h} px but the rig's camera {camera} is {mw}x{mh} px"
            )
        raise ValueError(f"the {what} frames are {w}x{h} px but the rig's camera is {mw}x{mh} px")


def camera_stacks(model: GeometryModel, images: Any) -> tuple[Any, ...]:
    """One capture per camera of ``model``, camera 0 first: ``(images,)`` for a model of one camera;
    for a model of several (:attr:`GeometryModel.cameras`), ``images`` must be a sequence of that
    many stacks (ValueError saying so otherwise), each a single stack or an :class:`ExposureStack`
    (docs/exposures.md: each camera is fused per pixel over its own exposures)."""
    count = model.cameras
    if count == 1:
        return (images,)
    if isinstance(images, ExposureStack) or not isinstance(images, (tuple, list)) or len(images) != count:
        got = f"a sequence of {len(images)}" if isinstance(images, (tuple, list)) else f"a {type(images).__name__}"
        raise ValueError(
            f"a {model.short_label} rig's capture is one stack per camera ({count}, camera 0 first), got {got}"
        )
    return tuple(images)


def _coordinates(coded: _Coded) -> dict[str, np.ndarray | None]:
    """A decoded camera's projector coordinates per used axis (projector units)."""
    return {axis: coded.axis_map(axis) for axis in coded.codes}


def _prepared(model: GeometryModel, codec: Codec, geometry: GeometryOptions) -> PreparedGeometry:
    return model.prepare(model.shape, (codec.projector_width, codec.projector_height), geometry)


def _estimated_blur(codes: np.ndarray, visibility: np.ndarray, period_codes: float | None) -> float:
    """The camera blur's variance from a reference's codes and visibility (0 when it cannot be told:
    no phase, or too small a field). The estimator reads ``phi = pi/2 l``: codes of a 4-code period."""
    if period_codes is None:
        return 0.0
    try:
        return estimate_blur_variance(codes * np.float32(4.0 / period_codes), visibility)
    except ValueError:
        return 0.0


def _drop_sigma_above(
    max_sigma_mm: float | None, sigma: np.ndarray | None, arrays: list[np.ndarray], z: np.ndarray
) -> int:
    """NaN in every array (z, codes, points...) where sigma exceeds ``max_sigma_mm`` (or is unknown);
    the count of points dropped."""
    if max_sigma_mm is None or sigma is None:
        return 0
    drop = ~(sigma <= np.float32(max_sigma_mm)) & np.isfinite(z)
    for array in (*arrays, z, sigma):
        array[drop] = np.nan
    return int(drop.sum())


def _sigma_of(codec: Codec, axis: str, decoding: CodecDecoding) -> np.ndarray:
    """The coordinate sigma (projector units) of ``axis`` from the decoder's noise
    (:func:`~metrology.core.uncertainty.stage_coordinate_sigma`); ValueError when the chain gives
    no noise estimate (it ends on a gray code or a 3-step phase)."""
    decoded = decoding.axes[axis]
    return stage_coordinate_sigma(codec, axis, decoded.noise, decoded.modulation)


def _other_sigmas(
    codec: Codec, prepared: PreparedGeometry, decodings: Sequence[CodecDecoding]
) -> list[np.ndarray] | None:
    """Each camera's coordinate sigma of the second of the model's :attr:`~PreparedGeometry.noise_axes`
    (the 2-D stereo match reads both axes' noise); None for a model that reads one, or when that
    axis's chain gives no noise estimate (the model then takes its noise equal to the first's)."""
    if len(prepared.noise_axes) < 2:
        return None
    try:
        return [_sigma_of(codec, prepared.noise_axes[1], decoding) for decoding in decodings]
    except ValueError:
        return None


# --------------------------------------------------------------------------- the codec path
def finest_period(codec: Codec, axis: str) -> float | None:
    """Period (projector units) of ``axis``'s last unwrapping stage, or None when it ends on a gray code."""
    stage = codec.axes[axis].chain()[-1]
    return None if stage.kind == "gray" else float(stage.period)


@dataclass(frozen=True)
class _Coded:
    """A decoded capture in code units, filtered: per used axis its code map, scale and visibility."""

    decoding: CodecDecoding
    codes: dict[str, np.ndarray]
    scales: dict[str, float]
    visibility: dict[str, np.ndarray]
    dropped: np.ndarray
    periods_codes: float | None

    def drop(self, threads: int | None) -> None:
        """Set every used axis's codes to NaN where :attr:`dropped`, in place."""
        keep = ~self.dropped
        for codes in self.codes.values():
            set_nan_where_false(codes, keep, threads)

    def axis_map(self, axis: str) -> np.ndarray | None:
        """Projector coordinates of ``axis`` (projector units), or None when the axis is not used."""
        if axis not in self.codes:
            return None
        return _from_codes(self.codes[axis], self.scales[axis])


def _from_codes(codes: np.ndarray, scale: float, out: np.ndarray | None = None) -> np.ndarray:
    """``x = c / s - 0.5``: code units back to projector units, float32."""
    x = np.multiply(codes, np.float32(1.0 / scale), out=out)
    x -= np.float32(0.5)
    return x


def _codec_decode_options(codec: Codec, options: MeasureOptions) -> CodecDecodeOptions:
    if options.gcps_v1.smoothing_px:
        raise ValueError(
            "smoothing_px applies to the paper's fused gcps-v1 decoder only (a codec states its waveform), "
            f"got {options.gcps_v1.smoothing_px!r}"
        )
    from metrology.core.codecs.decode import CodecDecodeOptions

    return CodecDecodeOptions(min_modulation=options.filters.min_modulation)


def _decode_and_filter(
    prepared: PreparedGeometry,
    images: npt.ArrayLike | ExposureStack,
    codec: Codec,
    options: MeasureOptions,
    reference: Reference | None,
    what: str,
    *,
    with_noise: bool,
    threads: int | None,
    camera: int = 0,
) -> _Coded:
    """Decode a stack of ``codec`` and apply the code-space filters on the axes the model reads
    (module docstring, step 2); ``camera``: which of the model's cameras took it.

    ``what`` is ``"reference"`` or ``"object"``. A reference capture gets the field margin and
    the mixed-pixel band (steps, invalid neighbours) marked in ``dropped``, not yet applied (its
    blur is estimated first: :meth:`_Coded.drop`). An object also gets the visibility and crease
    tests, the ``reference``'s unreliable pixels and its blur correction, all applied."""
    missing = [axis for axis in prepared.required_axes if axis not in codec.axes]
    if missing:
        raise ValueError(
            f"the codec does not code the projector's {missing[0]} axis, which the "
            f"{prepared.model.short_label} rig triangulates; the codec codes "
            f"{', '.join(sorted(codec.axes)) or 'no axis'}"
        )
    decode_options = _codec_decode_options(codec, options)
    from metrology.core.codecs.decode import decode_codec, validate_codec_stack
    from metrology.core.codecs.exposures import decode_exposures

    if isinstance(images, ExposureStack):
        _frames_shape(prepared.model, images.frame_shape, what, camera)
        decoding = decode_exposures(images, codec, decode_options, with_noise=with_noise, threads=threads)
    else:
        stack = validate_codec_stack(np.asarray(images), codec)
        _frames_shape(prepared.model, stack.shape[1:], what, camera)
        decoding = decode_codec(stack, codec, decode_options, with_noise=with_noise, threads=threads)
    filters = options.filters
    axes = prepared.used_axes(tuple(codec.axes))
    codes: dict[str, np.ndarray] = {}
    scales: dict[str, float] = {}
    visibility: dict[str, np.ndarray] = {}
    dropped = np.zeros(prepared.model.camera_shapes[camera], bool)
    for axis in axes:
        decoded = decoding.axes[axis]
        period = finest_period(codec, axis)
        model_scale = prepared.code_scale(axis)
        if model_scale is not None:
            scale = model_scale
        else:
            unit = period if period is not None else float(codec.axes[axis].gray.word)  # type: ignore[union-attr]
            scale = CODES_PER_PERIOD / unit
        extent_codes = codec.extent(axis) * scale
        filters.check_field(extent_codes)
        c = decoded.coordinate + np.float32(0.5)
        c *= np.float32(scale)
        refuse_outside_field(c, filters.field_margin_codes, extent_codes)
        with np.errstate(divide="ignore", invalid="ignore"):
            vis = (decoded.modulation / (np.float32(2) * decoded.mean)).astype(np.float32, copy=False)
        vis[~np.isfinite(vis)] = np.nan
        if filters.edge_band_px > 0:
            obj = what == "object"
            tests_dips = obj and filters.min_visibility_ratio > 0
            dropped |= unreliable_mask(
                c,
                filters.discontinuity_codes,
                filters.edge_band_px,
                vis if obj else None,
                filters.min_visibility_ratio if obj else 0.0,
                threads,
                visibility_noise=_codec_visibility_noise(codec, axis, decoded, vis) if tests_dips else None,
                blur_variance_px2=0.0 if reference is None else reference.blur_variance_px2,
                max_blur_bias_codes=filters.max_blur_bias_codes if obj else 0.0,
            )
        codes[axis], scales[axis], visibility[axis] = c, scale, vis
    if len(axes) > 1:  # a pixel the model cannot triangulate is dropped on every axis it reads
        decoded_everywhere = np.logical_and.reduce([np.isfinite(codes[a]) for a in axes])
        dropped |= ~decoded_everywhere & np.logical_or.reduce([np.isfinite(codes[a]) for a in axes])
    if reference is not None and reference.unreliable is not None and camera == 0:
        dropped |= reference.unreliable
    period = finest_period(codec, prepared.axis)
    coded = _Coded(
        decoding=decoding,
        codes=codes,
        scales=scales,
        visibility=visibility,
        dropped=dropped,
        periods_codes=None if period is None else period * scales[prepared.axis],
    )
    if what == "object":
        coded.drop(threads)
        if reference is not None and reference.blur_variance_px2 > 0:
            for c in codes.values():
                correct_blur_bias(c, reference.blur_variance_px2, threads)
    return coded


def _codec_visibility_noise(codec: Codec, axis: str, decoded: AxisDecoding, vis: np.ndarray) -> np.ndarray | None:
    """``sigma_V`` of an axis's visibility (:func:`~metrology.core.filters.visibility_sigma`) from
    its decoder's noise, pooled by intensity (:func:`~metrology.core.filters.noise_by_intensity`):
    ``B`` and the noise come from the finest sequence of the final stage, ``A`` from the first
    sequence (else the white and black frames). None when no noise was estimated (N = 3)."""
    phase = codec.axes[axis].phase
    final = codec.axes[axis].chain()[-1].indices
    if not phase or not final:
        return None
    steps_b = phase[min(final, key=lambda j: phase[j].period)].steps
    if steps_b < 4:
        return None
    steps_a = phase[0].steps
    sigma = noise_by_intensity(decoded.mean, decoded.noise, steps_b - 3)
    return visibility_sigma(vis, decoded.mean, sigma, steps_b, steps_a)


def _codec_measure(
    model: GeometryModel,
    reference: Reference | None,
    obj: npt.ArrayLike | ExposureStack,
    codec: Codec,
    options: MeasureOptions,
    timings: dict[str, float],
    threads: int | None,
) -> Measurement:
    start = time.perf_counter()
    prepared = _prepared(model, codec, options.geometry)
    cameras = [
        _decode_and_filter(
            prepared,
            stack,
            codec,
            options,
            reference if index == 0 else None,
            "object",
            with_noise=options.wants_sigma,
            threads=threads,
            camera=index,
        )
        for index, stack in enumerate(camera_stacks(model, obj))
    ]
    coded = cameras[0]
    timings["object_decode_s"] = time.perf_counter() - start
    for camera in cameras:
        refuse_inconsistent(camera.decoding.codec_check, options)
    start = time.perf_counter()
    sigmas = [_sigma_of(codec, prepared.axis, c.decoding) for c in cameras] if options.wants_sigma else None
    sigma_in = None if sigmas is None else sigmas[0]
    combined = None
    if len(cameras) > 1:  # the model makes camera 0's inputs of every camera's maps
        other = _other_sigmas(codec, prepared, [c.decoding for c in cameras]) if options.wants_sigma else None
        combined = prepared.combine([_coordinates(c) for c in cameras], sigmas, threads, other_sigma=other)
        sigma_in = combined.sigma
        timings["object_combine_s"] = time.perf_counter() - start
    surface = None if reference is None else reference.surface
    h, w = prepared.shape
    z = np.empty((h, w), np.float32)
    sigma_mm = np.empty((h, w), np.float32) if sigma_in is not None else None
    points = None if prepared.points_on_rays else np.empty((h, w, 3), np.float32)
    heights = surface is not None or prepared.has_model_plane
    z_kind = "height" if heights else "depth"

    def run(rows: slice) -> None:
        scratch = thread_scratch()
        coords: dict[str, np.ndarray | None] = {"u": None, "v": None}
        if combined is not None:
            coords = {"u": _rows_of(combined.u, rows), "v": _rows_of(combined.v, rows)}
        else:
            for axis, c in coded.codes.items():
                tile = c[rows]
                coords[axis] = _from_codes(
                    tile, coded.scales[axis], out=scratch.get(f"coord_{axis}", tile.shape, np.float32)
                )
        tile_points = points[rows] if points is not None else None
        if tile_points is None and not heights:  # depths: the points' Z
            tile_points = scratch.get("points", (*z[rows].shape, 3), np.float32)
        prepared.triangulate_rows(
            rows,
            coords["u"],
            coords["v"],
            reference=surface,
            points_out=tile_points,
            height_out=z[rows] if heights else None,
            sigma_in=None if sigma_in is None else sigma_in[rows],
            sigma_out=None if sigma_mm is None else sigma_mm[rows],
        )
        if not heights:
            assert tile_points is not None
            z[rows] = tile_points[..., 2]

    run_tiled(run, h, w, threads)
    codes = coded.codes[prepared.axis]
    if combined is not None:  # camera 0's codes where the model measured
        codes[~np.isfinite(z)] = np.nan
    if sigma_mm is not None:
        sigma_mm[~np.isfinite(z)] = np.nan
    dropped = _drop_sigma_above(options.max_sigma_mm, sigma_mm, [codes] + ([] if points is None else [points]), z)
    timings["object_triangulate_s"] = time.perf_counter() - start
    return Measurement(
        z_mm=z,
        z_kind=z_kind,
        codes=codes,
        prepared=prepared,
        reference=reference,
        sigma_mm=sigma_mm,
        decoding=coded.decoding,
        off_ray_points_mm=points,
        dropped_by_max_sigma=dropped,
        timings_s=timings,
        codec_check=coded.decoding.codec_check,
        pairs=None if combined is None else combined.pairs,
        camera_decodings=tuple(c.decoding for c in cameras) if len(cameras) > 1 else (),
    )


def _rows_of(array: np.ndarray | None, rows: slice) -> np.ndarray | None:
    return None if array is None else array[rows]


def refuse_inconsistent(checks: Mapping[str, AxisCheck], options: MeasureOptions) -> None:
    """ValueError with the self-check's message when an axis is ``inconsistent`` with its codec,
    unless ``options.allow_inconsistent_codec``."""
    message = inconsistent_message(checks)
    if message is not None and not options.allow_inconsistent_codec:
        raise ValueError(
            f"the capture does not match its codec ({message}) Correct the codec, or measure anyway with "
            "allow_inconsistent_codec (--allow-inconsistent-codec)."
        )


def check_gcps_v1_sample(
    stack: np.ndarray, codec: Codec | None, nlp: int, min_modulation: float | None = None
) -> Mapping[str, AxisCheck]:
    """The codec self-check of a gcps-v1 stack measured on the fused path, from the fused kernel's
    own intermediate values on 8 evenly spaced pairs of neighbouring rows
    (:func:`~metrology.core.codecs.check.sampled_rows`): the combined code within the gray word,
    ``l - l^`` (NaN where gray and phase disagree by two codes: counted outside the cell), and the
    word ``l^``, as projector coordinates ``x = (l^ + (l - l^)) w - 0.5`` and word centres
    ``c = (l^ + 0.5) w - 0.5`` (``w = width / nlp``), judged where the modulation reaches
    ``min_modulation``. The full-size kernel is untouched; an ``inconsistent`` check names its
    likely correction with the codec decoder (:func:`~metrology.core.codecs.check.with_suggestion`).

    ``stack``: (11, H, W) gcps-v1 images; ``codec``: the stacks' codec (None: gcps-v1 1024x768).
    """
    width = codec.projector_width if codec is not None else 1024
    height = codec.projector_height if codec is not None else 768
    v1 = gcps_v1_codec(width, height, nlp)
    if min_modulation is None:
        min_modulation = default_min_modulation(stack.dtype)
    rows = sampled_rows(stack.shape[1], pairs=8)
    shape = (rows.size, stack.shape[2])
    fraction, word, modulation = (np.empty(shape, np.float32) for _ in range(3))
    decode_sampled_rows(stack, rows, nlp, min_modulation, fraction, word, modulation)
    w = np.float32(width / nlp)
    centre = (word + np.float32(0.5)) * w - np.float32(0.5)
    x = np.where(np.isfinite(fraction), (word + fraction) * w - np.float32(0.5), centre + 2 * w)
    judged = modulation >= np.float32(min_modulation)
    check = check_axis(x, centre, judged, v1.axes["u"], width, paired_rows=True)
    if check.status == INCONSISTENT:
        from metrology.core.codecs.decode import decode_codec

        check = with_suggestion(check, stack, v1, "u", decode_codec)
    return {"u": check}


# --------------------------------------------------------------------------- the fused gcps-v1 path
def _light_code_model(model: GeometryModel) -> int:
    nlp = model.light_codes
    assert nlp is not None
    return nlp


def _fused_reference(
    model: GeometryModel, images: npt.ArrayLike, options: MeasureOptions, threads: int | None
) -> Reference:
    nlp = _light_code_model(model)
    filters, gcps = options.filters, options.gcps_v1
    filters.check_field(nlp)
    stack = validate_stack(images)
    _frames_shape(model, stack.shape[1:], "reference")
    decoded = decode_stack(
        stack,
        nlp,
        min_modulation=filters.min_modulation,
        consistency_codes=gcps.consistency_codes,
        smoothing_px=gcps.smoothing_px,
        field_margin_codes=filters.field_margin_codes,
        threads=threads,
    )
    prepared = model.prepare(None, None, options.geometry)
    surface = prepared.reference(decoded.codes, None)
    gray_surface = prepared.reference(decoded.gray_codes, None)
    unreliable = unreliable_mask(decoded.codes, filters.discontinuity_codes, filters.edge_band_px)
    blur = filters.blur_variance_px2
    if blur is None:
        blur = _estimated_blur(decoded.codes, decoded.visibility, 4.0)
    return Reference(
        model=model,
        codec=None,  # the fused decoder reads any gcps-v1 stack the same way
        geometry=options.geometry,
        surface=surface,
        codes=decoded.codes,
        unreliable=unreliable,
        blur_variance_px2=float(blur),
        gray_surface=gray_surface,
    )


def _fused_measure(
    model: GeometryModel,
    reference: Reference | None,
    obj: npt.ArrayLike,
    codec: Codec | None,
    options: MeasureOptions,
    timings: dict[str, float],
    threads: int | None,
) -> Measurement:
    nlp = _light_code_model(model)
    filters = options.filters
    filters.check_field(nlp)
    stack = validate_stack(obj)
    _frames_shape(model, stack.shape[1:], "object")
    prepared = model.prepare(None, None, options.geometry)
    surface = None if reference is None else reference.surface
    blur_variance = 0.0 if reference is None else reference.blur_variance_px2

    checks: list[Mapping[str, AxisCheck]] = []

    def checked_sample() -> None:
        start = time.perf_counter()
        checks.append(check_gcps_v1_sample(stack, codec, nlp, filters.min_modulation))
        timings["codec_check_s"] = time.perf_counter() - start

    # the self-check (its own 8 row pairs) is the fused pass's first task: one thread takes it while
    # the others start on the tiles; an inconsistent capture is refused before the filters
    start = time.perf_counter()
    correct_blur = blur_variance > 0  # then heights come from the corrected codes
    gray_surface = None if reference is None else reference.gray_surface
    gray_words = options.gray_only and (reference is None or gray_surface is not None)
    fused = _fused_pass(
        prepared,
        nlp,
        surface,
        stack,
        options,
        threads,
        triangulate=not correct_blur,
        gray_words=gray_words,
        first=checked_sample,
    )
    codec_check = checks[0]
    refuse_inconsistent(codec_check, options)
    z_mm, codes, visibility, gray_codes = fused.z_mm, fused.codes, fused.visibility, fused.gray_codes
    del fused  # the visibility map goes once the mixed-pixel filter has read it
    if filters.edge_band_px > 0:
        drop = unreliable_mask(
            codes,
            filters.discontinuity_codes,
            filters.edge_band_px,
            visibility,
            filters.min_visibility_ratio,
            threads,
            blur_variance_px2=blur_variance,
            max_blur_bias_codes=filters.max_blur_bias_codes,
        )
        del visibility
        if reference is not None and reference.unreliable is not None:
            drop |= reference.unreliable
        keep = np.logical_not(drop, out=drop)
        set_nan_where_false(codes, keep, threads)
        if z_mm is not None:
            set_nan_where_false(z_mm, keep, threads)
        del drop, keep
    if correct_blur:
        correct_blur_bias(codes, blur_variance, threads)
        z_mm = _heights(prepared, codes, surface, threads)
    assert z_mm is not None
    timings["object_decode_triangulate_s"] = time.perf_counter() - start

    gray_z = None
    if gray_codes is not None:
        start = time.perf_counter()
        gray_z = _heights(prepared, gray_codes, gray_surface, threads)
        timings["gray_only_s"] = time.perf_counter() - start
    sigma_mm = None
    if options.wants_sigma:
        start = time.perf_counter()
        sigma_mm = _fused_sigma(prepared, stack, codes, surface, threads)
        timings["sigma_s"] = time.perf_counter() - start
    dropped = _drop_sigma_above(options.max_sigma_mm, sigma_mm, [codes], z_mm)
    return Measurement(
        z_mm=z_mm,
        z_kind="height",
        codes=codes,
        prepared=prepared,
        reference=reference,
        gray_z_mm=gray_z,
        sigma_mm=sigma_mm,
        dropped_by_max_sigma=dropped,
        timings_s=timings,
        codec_check=codec_check,
    )


@dataclass(frozen=True)
class _FusedPass:
    codes: np.ndarray
    z_mm: np.ndarray | None
    visibility: np.ndarray | None
    gray_codes: np.ndarray | None


def _fused_pass(
    prepared: PreparedGeometry,
    nlp: int,
    surface: ReferenceSurface | None,
    stack: np.ndarray,
    options: MeasureOptions,
    threads: int | None,
    *,
    triangulate: bool,
    gray_words: bool,
    first: Callable[[], object] | None = None,
) -> _FusedPass:
    """Decode the object tile by tile (the fast path), triangulating against ``surface`` in the
    same pass when ``triangulate``, and keeping the gray-code-only codes when ``gray_words``;
    ``first``: a task run before the tiles, on one of the pass's threads (:func:`run_tiled`)."""
    filters, gcps = options.filters, options.gcps_v1
    _, height, width = stack.shape
    phase = stack[N_GRAY_BITS:]
    if gcps.smoothing_px > 0:
        phase = smooth_fringes(phase, gcps.smoothing_px)
    min_modulation = filters.min_modulation
    if min_modulation is None:
        min_modulation = default_min_modulation(stack.dtype)
    codes = np.empty((height, width), np.float32)
    z_mm = np.empty((height, width), np.float32) if triangulate else None
    gray_codes = np.empty((height, width), np.float32) if gray_words else None
    # read by the mixed-pixel pass only
    needs_visibility = filters.edge_band_px > 0 and filters.min_visibility_ratio > 0
    visibility = np.empty((height, width), np.float32) if needs_visibility else None

    compiled = use_compiled(stack.dtype, height * width) and phase.dtype == np.uint8
    terms = prepared.height_terms(surface) if compiled and z_mm is not None else None

    def run(rows: slice) -> None:
        done = decode_tile(
            stack,
            phase,
            rows,
            nlp,
            min_modulation,
            gcps.consistency_codes,
            filters.field_margin_codes,
            codes,
            compiled=compiled,
            gray_codes=gray_codes,
            visibility=visibility,
            heights=terms,
            z_mm=z_mm,
        )
        if z_mm is not None and not done:
            prepared.triangulate_rows(rows, codes[rows], None, reference=surface, height_out=z_mm[rows])

    run_tiled(run, height, width, threads, first=first)
    return _FusedPass(codes=codes, z_mm=z_mm, visibility=visibility, gray_codes=gray_codes)


def _heights(
    prepared: PreparedGeometry, codes: np.ndarray, surface: ReferenceSurface | None, threads: int | None
) -> np.ndarray:
    """Heights (H, W) float32 mm of light codes against a reference surface, tile by tile."""
    z_mm = triangulate_frame(prepared, codes, None, reference=surface, points=False, threads=threads).height_mm
    assert z_mm is not None
    return z_mm


def _fused_sigma(
    prepared: PreparedGeometry,
    stack: np.ndarray,
    codes: np.ndarray,
    surface: ReferenceSurface | None,
    threads: int | None,
) -> np.ndarray:
    """Height uncertainty on the fused path: the object's noise and modulation from the codec
    decoder's built-in gcps-v1 (4-step phase, period 4 codes), then the model's propagation."""
    from metrology.core.codecs.decode import decode_codec

    codec = gcps_v1_codec()
    decoding = decode_codec(stack, codec, with_noise=True, threads=threads)
    sigma_u = _sigma_of(codec, "u", decoding)
    sigma_l = sigma_u * np.float32(GCPS_V1_NLP / codec.projector_width)  # period 4 codes whatever the rig's nlp
    sigma = triangulate_frame(
        prepared, codes, None, reference=surface, points=False, heights=False, sigma=sigma_l, threads=threads
    ).sigma_mm
    assert sigma is not None
    sigma[~np.isfinite(codes)] = np.nan
    return sigma


__all__ = [
    "CODES_PER_PERIOD",
    "DECODE_KEYS",
    "MeasureOptions",
    "Measurement",
    "Reference",
    "as_exposures",
    "camera_stacks",
    "check_gcps_v1_sample",
    "decode_block",
    "finest_period",
    "height_statistics",
    "measure",
    "prepare_reference",
    "refuse_inconsistent",
    "split_decode_block",
    "uses_fused_gcps_v1",
]
