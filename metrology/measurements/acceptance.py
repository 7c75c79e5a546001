"""VDI/VDE 2634-2 acceptance of a stored measurement, computed on request from its stored result.

No job is run: the fit is over the stored points (fast). The quantities are those of
``gcps acceptance`` (:mod:`metrology.pipeline.acceptance`), with and without the 0.3 % outlier
rejection:

- crossed-axes rigs: the points of the stored height map ``height.npy`` in the frame of the
  paper's model (:func:`metrology.pipeline.acceptance.fit_height_map`);
- pinhole rigs: the stored camera-frame points ``points.npy``
  (:func:`metrology.pipeline.acceptance.fit_points`); probing and spacing segment the spheres by
  their height above the reference plane, so they need a measurement made with a reference.
"""

from __future__ import annotations

import io
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from metrology.core.measure import DecodeOptions
from metrology.core.rig import Rig as CoreRig
from metrology.errors import BadInput, Conflict
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.pinhole import load_points
from metrology.pipeline.acceptance import TESTS, AcceptanceOptions, AcceptanceResult, fit_height_map, fit_points
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


def acceptance_options(query: Mapping[str, str], decode: Mapping[str, Any] | None = None) -> AcceptanceOptions:
    """The :class:`AcceptanceOptions` of a request's query parameters; BadInput naming a bad or missing one.

    ``test`` is required (flatness, probing, spacing); ``diameter`` (probing) and ``spacing``
    (spacing) are required for their test, mm; ``min_height`` is optional (default 1 mm).
    ``decode``: the decoding options the measurement was made with (reported, not used).
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
            decode=_decode_options(decode),
        )
    except (TypeError, ValueError) as exc:
        raise BadInput(str(exc)) from exc


def _decode_options(decode: Mapping[str, Any] | None) -> DecodeOptions:
    """The stored decoding options of a measurement (the defaults when absent or not readable)."""
    try:
        return DecodeOptions.from_dict(decode) if decode else DecodeOptions()
    except (TypeError, ValueError):
        return DecodeOptions()


def _load(field: Any) -> np.ndarray:
    with field.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def measurement_acceptance(measurement: Measurement, query: Mapping[str, str]) -> dict[str, Any]:
    """The VDI/VDE 2634-2 report of ``measurement`` for the test of ``query`` (JSON-ready).

    The body of ``gcps acceptance --json`` (test, standard, the quantities with and without the
    0.3 % rejection, options, software version, timings ``load`` and ``fit`` in s) plus
    ``measurement`` (its id) and, for pinhole rigs, ``model``, ``frame`` and ``triangulate``.

    Raises
    ------
    BadInput
        A bad or missing query parameter; a probing/spacing test of a pinhole measurement made
        without a reference; spheres that cannot be segmented, too few points.
    NotDone
        The measurement's job is not done (no stored result).
    """
    job = measurement.job
    if job.status != Job.Status.DONE or not measurement.height_npy:
        raise NotDone(
            f"measurement {measurement.pk} is not done (its job is {job.status}): acceptance needs its stored result"
        )
    pinhole = measurement.rig_values.get("model") == "pinhole"
    decode = None if pinhole else (measurement.options or {}).get("decode")
    options = acceptance_options(query, decode)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    z_mm = _load(measurement.height_npy)
    points = load_points(measurement) if pinhole else None
    timings["load"] = time.perf_counter() - start
    if pinhole and points is None:
        raise NotDone(f"measurement {measurement.pk} has no stored points.npy")
    if pinhole and measurement.reference_id is None and options.test != "flatness":
        raise BadInput(
            f"test: the {options.test} test segments the spheres by their height above the reference plane, "
            f"and measurement {measurement.pk} was made without a reference capture (its heights are depths)"
        )
    start = time.perf_counter()
    try:
        if points is not None:
            report = fit_points(points, z_mm, options)
        else:
            report = fit_height_map(CoreRig.from_dict(measurement.rig_values), z_mm, options)
    except ValueError as exc:
        raise BadInput(f"{options.test}: {exc}") from exc
    timings["fit"] = time.perf_counter() - start
    if pinhole:
        report.update(model="pinhole", frame="camera", triangulate=(measurement.statistics or {}).get("triangulate"))
    result = AcceptanceResult(report=report, options=options, software_version=software_version(), timings_s=timings)
    return json_safe({"measurement": measurement.pk, **result.to_dict()})
