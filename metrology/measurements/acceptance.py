"""VDI/VDE 2634-2 acceptance of a stored measurement, computed on request from its stored result.

No job is run: the fit is over the stored points in the model frame (fast;
:func:`metrology.pipeline.acceptance.fit_points`, as ``gcps acceptance``), with and without the
0.3 % outlier rejection. Probing and spacing segment the spheres by their height above the
reference plane, so they need a measurement made with a reference.
"""

from __future__ import annotations

import io
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from metrology.core.measure import settings_from_dict
from metrology.errors import BadInput, Conflict
from metrology.jobs.models import Job
from metrology.measurements.derived import measurement_points
from metrology.measurements.models import Measurement
from metrology.pipeline.acceptance import TESTS, AcceptanceOptions, AcceptanceResult, fit_points
from metrology.pipeline.jsonsafe import json_safe
from metrology.version import software_version

QUERY_PARAMETERS = ("test", "diameter", "spacing", "min_height")
"""Query parameters of the acceptance endpoint (diameter, spacing, min_height in mm)."""


class NotDone(Conflict):
    """The measurement's job is not done (queued, running or failed): no stored result to fit (409)."""


def _millimetres(query: Mapping[str, str], name: str) -> float | None:
    raw = query.get(name)
    if raw is None or raw == "":
        return None
    try:
        value = float(raw)
    except ValueError:
        raise BadInput(f"{name} must be a number of millimetres, got {raw!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise BadInput(f"{name} must be a positive number of millimetres, got {raw!r}")
    return value


def acceptance_options(query: Mapping[str, str], measured: Mapping[str, Any] | None = None) -> AcceptanceOptions:
    """The :class:`AcceptanceOptions` of a request's query parameters; BadInput naming a bad or missing one.

    ``test`` is required (flatness, probing, spacing); ``diameter`` (probing) and ``spacing``
    (spacing) are required for their test, mm; ``min_height`` is optional (default 1 mm).
    ``measured``: the options the measurement was made with (its settings are reported, not used).
    """
    unknown = sorted(set(query) - set(QUERY_PARAMETERS))
    if unknown:
        raise BadInput(f"unknown query parameter {unknown[0]!r}: use {', '.join(QUERY_PARAMETERS)}")
    test = query.get("test")
    if not test:
        raise BadInput(f"test is required: one of {', '.join(TESTS)}")
    if test not in TESTS:
        raise BadInput(f"test must be one of {', '.join(TESTS)}, got {test!r}")
    diameter = _millimetres(query, "diameter")
    spacing = _millimetres(query, "spacing")
    min_height = _millimetres(query, "min_height")
    if test == "probing" and diameter is None:
        raise BadInput("diameter is required for the probing test: the sphere's calibrated diameter, mm")
    if test == "spacing" and spacing is None:
        raise BadInput("spacing is required for the spacing test: the calibrated centre distance, mm")
    try:
        return AcceptanceOptions(
            test=test,
            diameter_mm=diameter,
            spacing_mm=spacing,
            min_height_mm=1.0 if min_height is None else min_height,
            **_measured_settings(measured),
        )
    except (TypeError, ValueError) as exc:
        raise BadInput(str(exc)) from exc


def _measured_settings(measured: Mapping[str, Any] | None) -> dict[str, Any]:
    """The filters, gcps-v1 and geometry settings a measurement was made with (the defaults when
    absent or not readable)."""
    try:
        return settings_from_dict(measured or {})
    except (TypeError, ValueError):
        return settings_from_dict({})


def _load(field: Any) -> np.ndarray:
    with field.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def measurement_acceptance(measurement: Measurement, query: Mapping[str, str]) -> dict[str, Any]:
    """The VDI/VDE 2634-2 report of ``measurement`` for the test of ``query`` (JSON-ready).

    The body of ``gcps acceptance --json`` (test, standard, the quantities with and without the
    0.3 % rejection, options, software version, timings ``load`` and ``fit`` in s) plus
    ``measurement`` (its id), the rig's ``model``, its ``frame`` and the axis triangulated.

    Raises
    ------
    BadInput
        A bad or missing query parameter; a probing/spacing test of a measurement made without a
        reference; spheres that cannot be segmented, too few points.
    NotDone
        The measurement's job is not done (no stored result).
    """
    job = measurement.job
    if job.status != Job.Status.DONE or not measurement.height_npy:
        raise NotDone(
            f"measurement {measurement.pk} is not done (its job is {job.status}): acceptance needs its stored result"
        )
    options = acceptance_options(query, measurement.options)
    if measurement.reference_id is None and options.needs_reference:
        raise BadInput(
            f"test: the {options.test} test segments the spheres by their height above the reference plane, "
            f"and measurement {measurement.pk} was made without a reference capture (its heights are depths)"
        )
    timings: dict[str, float] = {}
    start = time.perf_counter()
    z_mm = _load(measurement.height_npy)
    try:
        points = measurement_points(measurement, z_mm)
    except ValueError as exc:
        raise NotDone(str(exc)) from exc
    timings["load"] = time.perf_counter() - start
    start = time.perf_counter()
    try:
        report = fit_points(points, z_mm, options)
    except ValueError as exc:
        raise BadInput(f"{options.test}: {exc}") from exc
    timings["fit"] = time.perf_counter() - start
    statistics = measurement.statistics or {}
    report.update(
        model=statistics.get("model") or _model_name(measurement),
        frame=_model_frame(measurement),
        triangulate=statistics.get("triangulate"),
    )
    result = AcceptanceResult(report=report, options=options, software_version=software_version(), timings_s=timings)
    return json_safe({"measurement": measurement.pk, **result.to_dict()})


def _model_name(measurement: Measurement) -> str:
    from metrology.core.geometry.base import model_name

    return model_name(measurement.rig_values)


def _model_frame(measurement: Measurement) -> str:
    from metrology.core.geometry import model_class

    return model_class(_model_name(measurement)).frame
