"""Acceptance: VDI/VDE 2634 part 2 quantities from a capture of a plane, a sphere or a ball bar
(the ``gcps acceptance`` command and the acceptance of a measurement), for every codec and
geometric model.

The capture is measured as any measurement is (:func:`metrology.pipeline.measure.measure`) and the
fits run on its points in the model frame: flatness from every point (no reference capture
needed where the model measures without one); probing and spacing on the spheres, the pixels
standing more than ``min_height_mm`` above the reference plane (a reference is required).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import acceptance as core
from metrology.core.codecs.model import Codec
from metrology.core.decode import GcpsV1Options
from metrology.core.filters import FilterOptions
from metrology.core.geometry.base import GeometryModel, GeometryOptions
from metrology.core.measure import (
    SETTINGS_KEYS,
    MeasureOptions,
    Reference,
    check_settings,
    settings_from_dict,
    settings_to_dict,
)
from metrology.core.option_checks import check_keys, check_positive
from metrology.pipeline.common import PhaseTimer
from metrology.pipeline.measure import measure
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
        probing/spacing: pixels this high above the reference plane belong to the spheres, mm (default 1).
    filters, gcps_v1, geometry
        How the capture is measured (JSON: ``decode``, ``triangulate``, ``method``).
    """

    test: str
    diameter_mm: float | None = None
    spacing_mm: float | None = None
    min_height_mm: float = 1.0
    filters: FilterOptions = field(default_factory=FilterOptions)
    gcps_v1: GcpsV1Options = field(default_factory=GcpsV1Options)
    geometry: GeometryOptions = field(default_factory=GeometryOptions)

    def __post_init__(self) -> None:
        if self.test not in TESTS:
            raise ValueError(f"test must be one of {', '.join(TESTS)}, got {self.test!r}")
        check_positive("diameter_mm", self.diameter_mm, allow_none=self.test != "probing")
        check_positive("spacing_mm", self.spacing_mm, allow_none=self.test != "spacing")
        check_positive("min_height_mm", self.min_height_mm)
        check_settings(self)

    @property
    def needs_reference(self) -> bool:
        """probing and spacing segment the spheres by their height above the reference plane."""
        return self.test != "flatness"

    def to_dict(self) -> dict[str, Any]:
        return {
            "test": self.test,
            "diameter_mm": self.diameter_mm,
            "spacing_mm": self.spacing_mm,
            "min_height_mm": self.min_height_mm,
            **settings_to_dict(self.filters, self.gcps_v1, self.geometry),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> AcceptanceOptions:
        own = ("test", "diameter_mm", "spacing_mm", "min_height_mm")
        check_keys("acceptance", data, {*SETTINGS_KEYS, *own})
        return cls(**settings_from_dict(data), **{k: data[k] for k in own if k in data})


@dataclass(frozen=True)
class AcceptanceResult:
    """Output of :func:`acceptance`: the test's quantities (with and without the 0.3 % outlier
    rejection), the model, its frame and the axis triangulated, the options, the software version
    and per-phase timings (``measure``, ``fit``)."""

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


def fit_points(points_mm: npt.ArrayLike, z_mm: npt.ArrayLike, options: AcceptanceOptions) -> dict[str, Any]:
    """The VDI/VDE 2634-2 quantities of ``options.test`` from per-pixel points.

    Parameters
    ----------
    points_mm : (H, W, 3) float array
        Points in the model frame, mm, NaN where not measured.
    z_mm : (H, W) float array
        Heights above the reference plane, mm (segments the spheres of probing/spacing;
        flatness does not use it).
    options : AcceptanceOptions

    Returns
    -------
    dict
        The report of :func:`metrology.core.acceptance.flatness_error`, ``probing_error`` or
        ``sphere_spacing_error`` (with and without the 0.3 % rejection), the fits done on the
        finite points (total least-squares plane; sphere).

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
    model: GeometryModel,
    reference: npt.ArrayLike | Reference | None,
    obj: npt.ArrayLike,
    options: AcceptanceOptions,
    *,
    codec: Codec | None = None,
    threads: int | None = None,
) -> AcceptanceResult:
    """Measure ``obj`` and compute the VDI/VDE 2634-2 quantity of ``options.test`` (module docstring).

    Raises
    ------
    ValueError
        On a bad option or stack, a probing/spacing test without reference, or spheres that
        cannot be segmented.
    """
    if reference is None and options.needs_reference:
        raise ValueError(f"the {options.test} test segments the spheres by height: give a reference capture")
    timer = PhaseTimer()
    with timer.phase("measure"):
        measured = measure(model, reference, obj, MeasureOptions.of(options), codec=codec, threads=threads)
    with timer.phase("fit"):
        # the float32 points a measurement stores (points.npy, `gcps measure --xyz`): the same fit as
        # the application's acceptance of a stored measurement
        report = fit_points(measured.points_mm(), measured.z_mm, options)
    report["model"] = model.model
    report["frame"] = model.frame
    report["triangulate"] = measured.measurement.prepared.axis
    return AcceptanceResult(
        report=report, options=options, software_version=software_version(), timings_s=timer.timings_s
    )
