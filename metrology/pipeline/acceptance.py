"""Acceptance: VDI/VDE 2634 part 2 quantities from a capture of a plane, a sphere or a ball bar
(the ``gcps acceptance`` command)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import acceptance as core
from metrology.core import measure as core_measure
from metrology.core.codecs.model import Codec
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.measure import DecodeOptions
from metrology.core.rig import Rig
from metrology.pipeline.common import PhaseTimer, check_keys, check_positive, decode_options
from metrology.version import software_version

TESTS = ("flatness", "probing", "spacing")


@dataclass(frozen=True)
class AcceptanceOptions:
    """Options of :func:`acceptance`.

    Attributes
    ----------
    test : {'flatness', 'probing', 'spacing'}
        Flatness of a plane; probing error (form, size) of a sphere; spacing of two spheres.
    diameter_mm : float or None
        probing: the sphere's calibrated diameter, mm (required).
    spacing_mm : float or None
        spacing: the calibrated centre distance, mm (required).
    min_height_mm : float
        probing/spacing: pixels this high above R belong to the spheres, mm (default 1).
    decode : DecodeOptions
    """

    test: str
    diameter_mm: float | None = None
    spacing_mm: float | None = None
    min_height_mm: float = 1.0
    decode: DecodeOptions = field(default_factory=DecodeOptions)

    def __post_init__(self) -> None:
        if self.test not in TESTS:
            raise ValueError(f"test must be one of {', '.join(TESTS)}, got {self.test!r}")
        check_positive("diameter_mm", self.diameter_mm, allow_none=self.test != "probing")
        check_positive("spacing_mm", self.spacing_mm, allow_none=self.test != "spacing")
        check_positive("min_height_mm", self.min_height_mm)
        object.__setattr__(self, "decode", decode_options(self.decode))

    def to_dict(self) -> dict[str, Any]:
        return {
            "test": self.test,
            "diameter_mm": self.diameter_mm,
            "spacing_mm": self.spacing_mm,
            "min_height_mm": self.min_height_mm,
            "decode": self.decode.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> AcceptanceOptions:
        check_keys("acceptance", data, {f for f in cls.__dataclass_fields__})
        return cls(**data)


@dataclass(frozen=True)
class AcceptanceResult:
    """Output of :func:`acceptance`: the test's quantities (with and without the 0.3 % outlier
    rejection), the options, the software version and per-phase timings (``measure``, ``fit``)."""

    report: dict[str, Any]
    options: AcceptanceOptions
    software_version: str
    timings_s: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "test": self.options.test,
            "standard": "VDI/VDE 2634 part 2",
            **self.report,
            "options": self.options.to_dict(),
            "software_version": self.software_version,
            "timings_s": dict(self.timings_s),
        }


def fit_height_map(rig: Rig, z_mm: npt.ArrayLike, options: AcceptanceOptions) -> dict[str, Any]:
    """The VDI/VDE 2634-2 quantities of ``options.test`` from a crossed-axes height map.

    Parameters
    ----------
    rig : Rig
        The crossed-axes rig the heights were measured with (points by
        :func:`metrology.core.acceptance.points_from_height_map`, DESIGN frame X_H, Y_H, z).
    z_mm : (H, W) float array
        Heights above the reference plane, mm, NaN where not measured.
    options : AcceptanceOptions
        ``decode`` is not used (the heights are given).

    Returns
    -------
    dict
        The report of :func:`metrology.core.acceptance.flatness_error`, ``probing_error`` or
        ``sphere_spacing_error`` (with and without the 0.3 % rejection).

    Raises
    ------
    ValueError
        When the spheres cannot be segmented or too few points are valid.
    """
    z = np.asarray(z_mm)
    if options.test == "flatness":
        return core.flatness_error(core.points_from_height_map(rig, z))
    if options.test == "probing":
        assert options.diameter_mm is not None
        (sphere,) = core.segment_objects(z, 1, options.min_height_mm)
        return core.probing_error(core.points_from_height_map(rig, z, sphere), options.diameter_mm)
    assert options.spacing_mm is not None
    first, second = core.segment_objects(z, 2, options.min_height_mm)
    return core.sphere_spacing_error(
        core.points_from_height_map(rig, z, first),
        core.points_from_height_map(rig, z, second),
        options.spacing_mm,
    )


def fit_points(points_mm: npt.ArrayLike, z_mm: npt.ArrayLike, options: AcceptanceOptions) -> dict[str, Any]:
    """The VDI/VDE 2634-2 quantities of ``options.test`` from per-pixel points (pinhole rigs).

    Parameters
    ----------
    points_mm : (H, W, 3) float array
        Camera-frame points, mm, NaN where not measured.
    z_mm : (H, W) float array
        Heights above the reference plane, mm (segments the spheres of probing/spacing;
        flatness does not use it).
    options : AcceptanceOptions

    Returns
    -------
    dict
        As :func:`fit_height_map`, the fits done on the finite points (TLS plane; sphere).

    Raises
    ------
    ValueError
        When the spheres cannot be segmented or too few points are valid.
    """
    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)

    def cloud(mask: np.ndarray | None = None) -> np.ndarray:
        keep = finite if mask is None else finite & np.asarray(mask).reshape(-1)
        return pts[keep]

    if options.test == "flatness":
        return core.flatness_error(cloud())
    if options.test == "probing":
        assert options.diameter_mm is not None
        (sphere,) = core.segment_objects(z_mm, 1, options.min_height_mm)
        return core.probing_error(cloud(sphere), options.diameter_mm)
    assert options.spacing_mm is not None
    first, second = core.segment_objects(z_mm, 2, options.min_height_mm)
    return core.sphere_spacing_error(cloud(first), cloud(second), options.spacing_mm)


def acceptance(
    rig: Rig,
    reference: npt.ArrayLike,
    obj: npt.ArrayLike,
    options: AcceptanceOptions,
    *,
    threads: int | None = None,
) -> AcceptanceResult:
    """Measure ``obj`` and compute the VDI/VDE 2634-2 quantity of ``options.test``.

    Raises
    ------
    ValueError
        On a bad option or stack, or when the spheres cannot be segmented.
    """
    timer = PhaseTimer()
    with timer.phase("measure"):
        z_mm = core_measure.measure_height(rig, reference, obj, options.decode, gray_only=False, threads=threads).z_mm
    with timer.phase("fit"):
        report = fit_height_map(rig, z_mm, options)
    return AcceptanceResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )


def acceptance_pinhole(
    rig: PinholeRig,
    reference: npt.ArrayLike | None,
    obj: npt.ArrayLike,
    codec: Codec,
    options: AcceptanceOptions,
    *,
    triangulate: str = "auto",
    threads: int | None = None,
) -> AcceptanceResult:
    """The VDI/VDE 2634-2 quantity of ``options.test`` from a capture through a pinhole rig
    (docs/pinhole.md), on the camera-frame points ``(H, W, 3)`` mm of
    :func:`~metrology.pipeline.measure_pinhole.measure_pinhole_stacks`.

    flatness: the range of the residuals to the total-least-squares plane through every point
    (no reference capture needed). probing / spacing: the spheres are the pixels higher than
    ``options.min_height_mm`` above the reference capture's plane (a reference is required),
    fitted by least squares in the camera frame. ``options.decode`` is not used (the codec
    decoder has its own).

    Raises
    ------
    ValueError
        On a bad option or stack, a probing/spacing test without reference, or spheres that
        cannot be segmented.
    """
    from metrology.pipeline.measure_pinhole import PinholeMeasureOptions, measure_pinhole_stacks

    if reference is None and options.test != "flatness":
        raise ValueError(f"the {options.test} test segments the spheres by height: give a reference capture")
    timer = PhaseTimer()
    with timer.phase("measure"):
        measured = measure_pinhole_stacks(
            rig, reference, obj, codec, PinholeMeasureOptions(triangulate=triangulate), threads=threads
        )
    with timer.phase("fit"):
        report = fit_points(measured.points_mm, measured.z_mm, options)
    report["model"] = "pinhole"
    report["frame"] = "camera"
    report["triangulate"] = measured.axis
    return AcceptanceResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
