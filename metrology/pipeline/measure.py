"""Measure: capture stacks of any codec to heights or depths, points and sigma on any geometric
model (the ``gcps measure`` command and the measurement job).

The core's one measurement (:func:`metrology.core.measure.measure`: decode, code-space filters,
the model's triangulation; the fused gcps-v1 kernel where it applies) with its options, the
software version and per-phase timings, and the statistics every caller stores.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from metrology.core import measure as core
from metrology.core.codecs.check import summary_of
from metrology.core.codecs.model import CODEC_FORMAT, GCPS_V1, Codec, is_gcps_v1
from metrology.core.codecs.stack import ExposureStack
from metrology.core.geometry.base import GeometryModel
from metrology.core.measure import Measurement, MeasureOptions, Reference, height_statistics
from metrology.pipeline.common import PhaseTimer
from metrology.version import software_version

if TYPE_CHECKING:
    from metrology.core.codecs.decode import CodecDecoding

__all__ = ["MeasureOptions", "MeasureResult", "measure", "prepare_reference"]


@dataclass(frozen=True)
class MeasureResult:
    """Output of :func:`measure`.

    Attributes
    ----------
    measurement : Measurement
        The core's result: ``z_mm`` (heights above the reference, or the model's own ``z``),
        ``codes``, the gray-code-only heights, ``sigma_mm``, the decoding, the points.
    options : MeasureOptions
    codec : Codec or None
        The stacks' codec (None: the paper's gcps-v1).
    software_version : str
    timings_s : dict
        Seconds per phase: ``measure`` (the whole call) and the core's sub-phases (``measure.*``).
    """

    measurement: Measurement
    options: MeasureOptions
    codec: Codec | None
    software_version: str
    timings_s: dict[str, float]

    @property
    def z_mm(self) -> np.ndarray:
        """``(H, W)`` float32: heights above the reference plane, or depths (:attr:`Measurement.z_kind`), mm."""
        return self.measurement.z_mm

    @property
    def gray_z_mm(self) -> np.ndarray | None:
        return self.measurement.gray_z_mm

    @property
    def sigma_mm(self) -> np.ndarray | None:
        return self.measurement.sigma_mm

    @property
    def codes(self) -> np.ndarray:
        """The object's codes of the triangulated axis after the filters (light codes on a crossed-axes rig)."""
        return self.measurement.codes

    @property
    def decoding(self) -> CodecDecoding | None:
        return self.measurement.decoding

    @property
    def reference(self) -> Reference | None:
        return self.measurement.reference

    def points_mm(self, dtype: npt.DTypeLike = np.float32) -> np.ndarray:
        """``(H, W, 3)`` points, mm, model frame (the paper's ``(X_H, Y_H, z)``, or the camera
        frame), NaN where not measured."""
        return self.measurement.points_mm(dtype)

    @property
    def codec_name(self) -> str:
        """``"gcps-v1"`` for the built-in codec, else ``"gcps-codec/1"`` (a codec file's)."""
        return GCPS_V1 if is_gcps_v1(self.codec) else CODEC_FORMAT

    def statistics(self) -> dict[str, Any]:
        """Valid pixels and min/max/mean/std of ``z``, what ``z`` is, the rig's model, the axis and
        method triangulated, the points dropped by ``max_sigma_mm`` and the median sigma (and the
        gray-code-only heights' figures where computed; for a multi-exposure object,
        ``points_per_exposure``: the measured points of each exposure by name; for a stereo rig,
        ``points_per_pairs``: the measured points of each combination of pairs, docs/stereo.md; for a
        stereo multi-exposure object, ``camera_pixels_per_exposure``: ``{"cam0": {name: pixels, ...,
        "none": ...}, "cam1": ...}``, the pixels of each camera's own grid each exposure decoded,
        docs/exposures.md "Stereo rigs")."""
        m = self.measurement
        stats: dict[str, Any] = dict(height_statistics(m.z_mm))
        if m.gray_z_mm is not None:
            stats["gray_only"] = height_statistics(m.gray_z_mm)
        stats.update(
            model=m.model.model,
            z=m.z_meaning,
            triangulate=m.prepared.axis,
            method=m.prepared.method,
            dropped_by_max_sigma=m.dropped_by_max_sigma,
        )
        if m.sigma_mm is not None:
            finite = m.sigma_mm[np.isfinite(m.sigma_mm)]
            stats["sigma_mm_median"] = float(np.median(finite)) if finite.size else None
        per_exposure = m.points_per_exposure()
        if per_exposure is not None:  # a multi-exposure object: the points each exposure measured
            stats["points_per_exposure"] = per_exposure
        per_pairs = m.points_per_pairs()
        if per_pairs is not None:  # a stereo rig: the points each combination of pairs measured
            stats["points_per_pairs"] = per_pairs
        per_camera = {f"cam{i}": m.camera_pixels_per_exposure(i) for i in range(len(m.camera_decodings))}
        if any(counts is not None for counts in per_camera.values()):  # a stereo multi-exposure object
            stats["camera_pixels_per_exposure"] = per_camera
        return stats

    def to_dict(self) -> dict[str, Any]:
        """Statistics, options, software version, timings, the codec, the reference plane (a
        fitted one; null for a per-pixel reference or none), the decoding summary of a codec
        decoding and the object's codec self-check (``codec_check``; JSON-ready)."""
        reference = self.measurement.reference
        data: dict[str, Any] = {
            "statistics": self.statistics(),
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
            "codec": self.codec_name,
            "reference_plane": None if reference is None else reference.surface.describe(),
        }
        if self.measurement.decoding is not None:
            data["decoding"] = self.measurement.decoding.summary()
        data["codec_check"] = summary_of(self.measurement.codec_check)
        return data


def prepare_reference(
    model: GeometryModel,
    reference: npt.ArrayLike | ExposureStack,
    options: MeasureOptions | None = None,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> Reference:
    """The reference plane decoded, filtered and prepared once for many measurements
    (:func:`metrology.core.measure.prepare_reference`): what the workers keep."""
    return core.prepare_reference(model, reference, codec, options, threads=threads)


def measure(
    model: GeometryModel,
    reference: npt.ArrayLike | ExposureStack | Reference | None,
    obj: npt.ArrayLike | ExposureStack,
    options: MeasureOptions | None = None,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> MeasureResult:
    """Heights or depths, points and sigma of an object capture (:func:`metrology.core.measure.measure`).

    Parameters
    ----------
    model : GeometryModel
        The rig's geometric model (any: :data:`metrology.core.geometry.MODELS`).
    reference : image stack, Reference or None
        The reference plane (a kept :class:`~metrology.core.measure.Reference` is reused as is);
        None where the model measures without one (depths).
    obj : (frames, H, W) image stack of ``codec``, or ExposureStack
        Either capture may be a multi-exposure capture (docs/exposures.md), fused per pixel.
    options : MeasureOptions, optional
    codec : Codec, optional
        The stacks' codec; None (or the built-in gcps-v1) the paper's eleven patterns.
    threads : int, optional
        Threads over row tiles (does not change the result).

    Raises
    ------
    ValueError
        On a malformed stack, a stack that does not match its codec or the rig, a codec lacking
        the axis the model triangulates, a missing reference, or a bad option.
    """
    options = options or MeasureOptions()
    timer = PhaseTimer()
    start = time.perf_counter()
    measurement = core.measure(model, obj, codec, reference=reference, options=options, threads=threads)
    timer.timings_s["measure"] = time.perf_counter() - start
    timer.add(measurement.timings_s, "measure.")
    return MeasureResult(
        measurement=measurement,
        options=options,
        codec=codec,
        software_version=software_version(),
        timings_s=timer.timings_s,
    )
