"""Measure: reference and object capture stacks to a height map (the ``gcps measure`` command and
the measurement job).

gcps-v1 stacks (no codec, or the built-in ``gcps-v1``) take the paper's fused decoder
(:func:`metrology.core.measure.measure_height`), unchanged; a stack of any other codec that
codes the projector's u axis is decoded by the codec decoder, mapped to light codes
``l = (u + 0.5) nlp / width`` and triangulated through the same crossed-axes geometry with the
same filters (:mod:`metrology.core.codec_measure`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import measure as core_measure
from metrology.core.codec_measure import CodecReference, is_gcps_v1, measure_codec_height
from metrology.core.codecs.decode import CodecDecoding, decode_codec
from metrology.core.codecs.model import Codec, gcps_v1_codec
from metrology.core.decode import DecodedStack
from metrology.core.measure import DecodeOptions, Reference, height_statistics
from metrology.core.rig import Rig
from metrology.core.uncertainty import axis_coordinate_sigma, height_sigma
from metrology.pipeline.common import PhaseTimer, check_bool, check_keys, decode_options
from metrology.version import software_version

GCPS_V1_NLP = 128
"""Light codes across the built-in gcps-v1 codec's projector (its phase period is 4 of them)."""


@dataclass(frozen=True)
class MeasureOptions:
    """Options of :func:`measure`.

    Attributes
    ----------
    decode : DecodeOptions
        Decoding and mixed-pixel options (:class:`~metrology.core.measure.DecodeOptions`).
    gray_only : bool
        Also compute the gray-code-only comparison heights (default True).
    sigma : bool
        Also compute each height's standard uncertainty from the object's phase noise
        (default False; :mod:`metrology.core.uncertainty`); needs a final phase sequence of
        N >= 4 steps.
    """

    decode: DecodeOptions = field(default_factory=DecodeOptions)
    gray_only: bool = True
    sigma: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "decode", decode_options(self.decode))
        check_bool("gray_only", self.gray_only)
        check_bool("sigma", self.sigma)

    def to_dict(self) -> dict[str, Any]:
        return {"decode": self.decode.to_dict(), "gray_only": self.gray_only, "sigma": self.sigma}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MeasureOptions:
        check_keys("measure", data, {"decode", "gray_only", "sigma"})
        return cls(**data)


@dataclass(frozen=True)
class MeasureResult:
    """Output of :func:`measure`.

    Attributes
    ----------
    z_mm : (H, W) float32 array
        Height above the reference plane, mm, NaN where not measured.
    gray_z_mm : (H, W) float32 array or None
        Gray-code-only heights, mm (when ``options.gray_only``).
    obj_codes : (H, W) float32 array
        The object's light codes after the filters (and the blur correction), code units.
    options : MeasureOptions
    software_version : str
    timings_s : dict
        Seconds per phase: ``measure`` (the whole call) and the core's sub-phases.
    codec : str
        ``"gcps-v1"``, or ``"gcps-codec/1"`` for a codec file's stacks.
    decoding : CodecDecoding or None
        The object's codec decoding (u/v maps, modulation, reasons) for a non-gcps-v1 codec.
    sigma_mm : (H, W) float32 array or None
        Per-point standard uncertainty of the heights, mm (``MeasureOptions(sigma=True)``;
        :mod:`metrology.core.uncertainty`), NaN where not measured.
    """

    z_mm: np.ndarray
    gray_z_mm: np.ndarray | None
    obj_codes: np.ndarray
    options: MeasureOptions
    software_version: str
    timings_s: dict[str, float]
    codec: str = "gcps-v1"
    decoding: CodecDecoding | None = None
    sigma_mm: np.ndarray | None = None

    def points_mm(self, rig: Rig) -> np.ndarray:
        """``(H, W, 3)`` float32 points, mm, in the paper's frame ``(X_H, Y_H, z)``; NaN where not measured."""
        return rig.prepare().points_from_heights(self.z_mm).astype(np.float32)

    def statistics(self) -> dict[str, Any]:
        """Valid pixels and min/max/mean/std of the heights (and of the gray-code-only heights)."""
        stats: dict[str, Any] = dict(height_statistics(self.z_mm))
        if self.gray_z_mm is not None:
            stats["gray_only"] = height_statistics(self.gray_z_mm)
        return stats

    def to_dict(self) -> dict[str, Any]:
        """Statistics, options, software version and timings (JSON-ready); the codec, and for a
        codec other than gcps-v1 the decoding summary (pixels per reason, slips, validity rules)."""
        data: dict[str, Any] = {
            "statistics": self.statistics(),
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
            "codec": self.codec,
        }
        if self.decoding is not None:
            data["decoding"] = self.decoding.summary()
        return data


def measure(
    rig: Rig,
    reference: npt.ArrayLike | DecodedStack | Reference | CodecReference,
    obj: npt.ArrayLike,
    options: MeasureOptions | None = None,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> MeasureResult:
    """Height map of an object (Eqs. 1-17): decode, filter, correct the blur bias, triangulate.

    Parameters
    ----------
    rig : Rig
    reference : image stack, DecodedStack, Reference or CodecReference
        The reference plane: ``(11, H, W)`` for gcps-v1 (a :class:`~metrology.core.measure.Reference`
        is reused as is), ``(frames, H, W)`` of ``codec`` otherwise (or a kept
        :class:`~metrology.core.codec_measure.CodecReference`).
    obj : (11, H, W) or (frames, H, W) image stack
    options : MeasureOptions, optional
    codec : Codec, optional
        The stacks' codec; None or the built-in gcps-v1: the paper's decoder, as before. Any
        other codec must code the u axis (no gray-code-only comparison heights then).
    threads : int, optional
        Threads over row tiles (does not change the result).

    Raises
    ------
    ValueError
        On a malformed stack, a stack that does not match its codec, a codec without u, a shape
        that differs from the rig's, or a bad option.
    """
    options = options or MeasureOptions()
    sigma = options.sigma
    timer = PhaseTimer()
    start = time.perf_counter()
    if not is_gcps_v1(codec):
        assert codec is not None
        if isinstance(reference, (DecodedStack, Reference)):
            raise ValueError("a gcps-v1 reference cannot serve a stack of another codec")
        codec_result = measure_codec_height(
            rig, reference, obj, codec, options.decode, with_noise=sigma, threads=threads
        )
        sigma_mm = None
        if sigma:
            with timer.phase("measure.sigma_s"):
                sigma_u = axis_coordinate_sigma(codec, "u", codec_result.decoding.axes["u"])
                sigma_mm = height_sigma(
                    rig.prepare(),
                    codec_result.obj_codes,
                    sigma_u * np.float32(rig.nlp / codec.projector_width),
                    codec_result.reference.surface,
                    threads,
                )
        timer.timings_s["measure"] = time.perf_counter() - start
        timer.add(codec_result.timings_s, "measure.")
        return MeasureResult(
            z_mm=codec_result.z_mm,
            gray_z_mm=None,
            obj_codes=codec_result.obj_codes,
            options=options,
            software_version=software_version(),
            timings_s=timer.timings_s,
            codec="gcps-codec/1",
            decoding=codec_result.decoding,
            sigma_mm=sigma_mm,
        )
    if isinstance(reference, CodecReference):
        raise ValueError("a reference decoded with a codec cannot serve a gcps-v1 stack")
    if sigma and not isinstance(reference, Reference):  # kept for the uncertainty's dz/dl
        reference = core_measure.prepare_reference(rig, reference, options.decode)
    result = core_measure.measure_height(
        rig, reference, obj, options.decode, gray_only=options.gray_only, threads=threads
    )
    sigma_mm = None
    if sigma:
        assert isinstance(reference, Reference)
        with timer.phase("measure.sigma_s"):
            sigma_mm = _gcps_v1_sigma(rig, reference, obj, result.obj_codes, threads)
    timer.timings_s["measure"] = time.perf_counter() - start
    timer.add(result.timings_s, "measure.")
    return MeasureResult(
        z_mm=result.z_mm,
        gray_z_mm=result.gray_z_mm,
        obj_codes=result.obj_codes,
        options=options,
        software_version=software_version(),
        timings_s=timer.timings_s,
        sigma_mm=sigma_mm,
    )


def _gcps_v1_sigma(
    rig: Rig, reference: Reference, obj: npt.ArrayLike, codes: np.ndarray, threads: int | None
) -> np.ndarray:
    """Height uncertainty of a gcps-v1 measurement: the object's noise and modulation from the codec
    decoder's built-in gcps-v1 (4-step phase, period 4 codes), then |dz/dl| sigma_l."""
    codec = gcps_v1_codec()
    decoding = decode_codec(np.asarray(obj), codec, with_noise=True, threads=threads)
    sigma_u = axis_coordinate_sigma(codec, "u", decoding.axes["u"])
    sigma_l = sigma_u * np.float32(GCPS_V1_NLP / codec.projector_width)  # period 4 codes whatever the rig's nlp
    return height_sigma(rig.prepare(), codes, sigma_l, reference.surface, threads)
