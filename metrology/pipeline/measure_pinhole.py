"""Measure with a pinhole rig (docs/pinhole.md): capture stacks of any codec to points, depth or
heights, and per-point uncertainty (the ``gcps measure --rig PINHOLE.json`` command and the
measurement job).

Both captures are decoded with their codec (:func:`~metrology.core.codecs.decode.decode_codec`);
the object's projector coordinates are triangulated by the pinhole model
(:func:`~metrology.core.pinhole_measure.measure_pinhole`): points ``(H, W, 3)`` in the camera
frame; ``z_mm`` the depth (camera Z) without a reference capture, the signed distance to the
reference's fitted plane with one. With ``sigma``, each point's standard uncertainty along its
ray from the triangulated axis's phase noise; ``max_sigma_mm`` drops the points above it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.decode import CodecDecoding, decode_codec, validate_codec_stack
from metrology.core.codecs.model import Codec
from metrology.core.geometry.pinhole import PinholeReference, PinholeRig
from metrology.core.measure import height_statistics
from metrology.core.pinhole_measure import measure_pinhole
from metrology.core.uncertainty import stage_coordinate_sigma
from metrology.pipeline.common import PhaseTimer, check_bool, check_keys
from metrology.version import software_version

TRIANGULATE_AXES = ("auto", "u", "v")
METHODS = ("plane", "midpoint")


@dataclass(frozen=True)
class PinholeMeasureOptions:
    """Options of :func:`measure_pinhole_stacks`.

    Attributes
    ----------
    triangulate : str
        Projector axis whose planes are intersected: ``auto`` (default; the axis the baseline
        crosses most steeply), ``u`` or ``v``.
    method : str
        ``plane`` (ray-plane intersection, default) or ``midpoint`` (ray-ray midpoint, both axes).
    sigma : bool
        Compute each point's standard uncertainty, mm (needs an N >= 4 phase on that axis).
    max_sigma_mm : float or None
        Drop the points whose uncertainty exceeds this, mm (implies ``sigma``).
    """

    triangulate: str = "auto"
    method: str = "plane"
    sigma: bool = False
    max_sigma_mm: float | None = None

    def __post_init__(self) -> None:
        if self.triangulate not in TRIANGULATE_AXES:
            raise ValueError(f"triangulate must be one of {', '.join(TRIANGULATE_AXES)}, got {self.triangulate!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        check_bool("sigma", self.sigma)
        m = self.max_sigma_mm
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, float)) or not math.isfinite(m) or m <= 0):
            raise ValueError(f"max_sigma_mm must be a positive number of mm, got {m!r}")

    @property
    def wants_sigma(self) -> bool:
        return self.sigma or self.max_sigma_mm is not None

    def to_dict(self) -> dict[str, Any]:
        return {
            "triangulate": self.triangulate,
            "method": self.method,
            "sigma": self.sigma,
            "max_sigma_mm": self.max_sigma_mm,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PinholeMeasureOptions:
        check_keys("pinhole measure", data, {"triangulate", "method", "sigma", "max_sigma_mm"})
        return cls(**data)


@dataclass(frozen=True)
class PinholeMeasureResult:
    """Output of :func:`measure_pinhole_stacks`.

    Attributes
    ----------
    z_mm : (H, W) float32
        Depth (camera Z) without a reference; height above the reference plane with one (mm).
    points_mm : (H, W, 3) float32
        Points in the camera frame, mm, NaN where not measured.
    sigma_mm : (H, W) float32 or None
        Per-point standard uncertainty, mm.
    reference : PinholeReference or None
        The reference plane (centroid, normal towards the camera, point count).
    axis, method : str
        The projector axis triangulated and the method.
    decoding : CodecDecoding
        The object's decoding.
    dropped_by_max_sigma : int
    options : PinholeMeasureOptions
    software_version : str
    timings_s : dict
    """

    z_mm: np.ndarray
    points_mm: np.ndarray
    sigma_mm: np.ndarray | None
    reference: PinholeReference | None
    axis: str
    method: str
    decoding: CodecDecoding
    dropped_by_max_sigma: int
    options: PinholeMeasureOptions
    software_version: str
    timings_s: dict[str, float]

    @property
    def z_meaning(self) -> str:
        return "height above the reference plane" if self.reference is not None else "depth (camera Z)"

    def statistics(self) -> dict[str, Any]:
        """Valid pixels and min/max/mean/std of ``z_mm``; what z is; axis, method; the median sigma."""
        stats: dict[str, Any] = dict(height_statistics(self.z_mm))
        stats.update(
            model="pinhole",
            z=self.z_meaning,
            triangulate=self.axis,
            method=self.method,
            dropped_by_max_sigma=self.dropped_by_max_sigma,
        )
        if self.sigma_mm is not None:
            finite = self.sigma_mm[np.isfinite(self.sigma_mm)]
            stats["sigma_mm_median"] = float(np.median(finite)) if finite.size else None
        return stats

    def to_dict(self) -> dict[str, Any]:
        """Statistics, the reference plane, the decoding summary, options, version, timings (JSON-ready)."""
        ref = self.reference
        return {
            "statistics": self.statistics(),
            "reference_plane": None
            if ref is None
            else {"centroid_mm": ref.centroid.tolist(), "normal": ref.normal.tolist(), "points": ref.n_points},
            "decoding": self.decoding.summary(),
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
        }


def final_stage_sigma(codec: Codec, axis: str, noise: Any, modulation: Any) -> Any:
    """Coordinate sigma (projector units) of ``axis`` from the decoder's noise and modulation maps
    (:func:`metrology.core.uncertainty.stage_coordinate_sigma`); None when the decoder gave no
    noise or the chain ends where there is none (a gray code, a 3-step phase)."""
    if noise is None or not np.isfinite(noise).any():
        return None
    try:
        return stage_coordinate_sigma(codec, axis, noise, modulation)
    except ValueError:
        return None


def _coordinates(decoding: CodecDecoding) -> tuple[np.ndarray | None, np.ndarray | None]:
    u = decoding.axes["u"].coordinate if "u" in decoding.axes else None
    v = decoding.axes["v"].coordinate if "v" in decoding.axes else None
    return u, v


def measure_pinhole_stacks(
    rig: PinholeRig,
    reference: npt.ArrayLike | None,
    obj: npt.ArrayLike,
    codec: Codec,
    options: PinholeMeasureOptions | None = None,
    *,
    threads: int | None = None,
) -> PinholeMeasureResult:
    """Points, depth or heights, and sigma of an object captured with ``codec`` through a pinhole rig.

    Parameters
    ----------
    rig : PinholeRig
    reference : (frames, H, W) image stack of ``codec``, or None
        A capture of the reference plane (heights above its fitted plane), or None (depth).
    obj : (frames, H, W) image stack of ``codec``
    codec : Codec
        Its projector size must equal the rig's projector size.
    options : PinholeMeasureOptions, optional

    Raises
    ------
    ValueError
        A stack that does not match the codec or the rig's camera, a codec lacking the axis to
        triangulate, sigma asked without a noise estimate, a bad option.
    """
    options = options or PinholeMeasureOptions()
    timer = PhaseTimer()
    start = time.perf_counter()
    stacks = {"object": validate_codec_stack(np.asarray(obj), codec)}
    if reference is not None:
        stacks["reference"] = validate_codec_stack(np.asarray(reference), codec)
    for label, stack in stacks.items():
        if tuple(stack.shape[1:]) != rig.shape:
            h, w = stack.shape[1:]
            cam = f"{rig.camera.width_px}x{rig.camera.height_px}"
            raise ValueError(f"the {label} frames are {w}x{h} px but the rig's camera is {cam} px")
    with timer.phase("decode"):
        decoding = decode_codec(stacks["object"], codec, with_noise=options.wants_sigma, threads=threads)
        ref_decoding = None
        if "reference" in stacks:
            ref_decoding = decode_codec(stacks["reference"], codec, with_noise=False, threads=threads)
    axis = rig.auto_axis() if options.triangulate == "auto" else options.triangulate
    sigma_coordinate = None
    if options.wants_sigma:
        if axis not in decoding.axes:
            raise ValueError(f"the codec does not code the {axis} axis that the rig triangulates")
        decoded_axis = decoding.axes[axis]
        sigma_coordinate = final_stage_sigma(codec, axis, decoded_axis.noise, decoded_axis.modulation)
        if sigma_coordinate is None:
            raise ValueError(f"sigma needs a phase-coded {axis} axis with N >= 4 steps (a noise estimate)")
    u, v = _coordinates(decoding)
    with timer.phase("triangulate"):
        result = measure_pinhole(
            rig,
            u,
            v,
            reference_uv=None if ref_decoding is None else _coordinates(ref_decoding),
            sigma=sigma_coordinate,
            axis=options.triangulate,
            method=options.method,
            projector_size=(codec.projector_width, codec.projector_height),
            threads=threads,
        )
    points, z, sigma_mm = result.points_mm, result.z_mm, result.sigma_mm
    dropped = 0
    if options.max_sigma_mm is not None and sigma_mm is not None:
        drop = ~(sigma_mm <= np.float32(options.max_sigma_mm)) & np.isfinite(z)
        dropped = int(drop.sum())
        points[drop] = np.nan
        z[drop] = np.nan
        sigma_mm[drop] = np.nan
    timer.timings_s["measure"] = time.perf_counter() - start
    return PinholeMeasureResult(
        z_mm=z,
        points_mm=points,
        sigma_mm=sigma_mm,
        reference=result.reference,
        axis=result.axis,
        method=result.method,
        decoding=decoding,
        dropped_by_max_sigma=dropped,
        options=options,
        software_version=software_version(),
        timings_s=timer.timings_s,
    )
