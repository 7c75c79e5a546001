"""Reads for the pages: stored result arrays, figures ready to draw, where a job's result lives.

Every object comes from the apps' own selectors (scoped to the user); this module only loads the
stored arrays and hands them to the figure builders of :mod:`metrology.figures`.
"""

from __future__ import annotations

import functools
import io
import json
from typing import Any

import numpy as np
from django.urls import reverse

from metrology.jobs.models import Job


def load_npy(field) -> np.ndarray | None:
    """A stored ``.npy`` file field as an array (None if the field is empty)."""
    if not field:
        return None
    with field.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def measurement_figures(measurement, row: int | None = None) -> tuple[dict[str, Any], int, int]:
    """Figures of a finished measurement and the profile row used; returns (figures, row, height_px)."""
    from metrology.core.mesh import default_max_jump_mm
    from metrology.core.rig import Rig as CoreRig
    from metrology.core.triangulate import points_from_heights
    from metrology.figures.measurement import measurement_figures as build

    rig = CoreRig.from_dict(measurement.rig_values)
    z = load_npy(measurement.height_npy)
    if z is None:
        return {}, 0, rig.height_px
    gray = load_npy(measurement.gray_only_npy)
    height = z.shape[0]
    row = height // 2 if row is None else min(max(int(row), 0), height - 1)
    figures = build(
        z,
        points_from_heights(rig, z),
        row,
        gray_z_mm=gray,
        x_mm=rig.column_x_mm(),
        y_mm=rig.row_y_mm(),
        max_jump_mm=default_max_jump_mm(rig),
    )
    return figures, row, height


def calibration_figures(calibration) -> dict[str, Any]:
    from metrology.core.rig import Rig as CoreRig
    from metrology.figures.calibration import calibration_figures as build

    rig = CoreRig.from_dict(calibration.rig_values)
    return build(
        calibration.iterations or [],
        calibration.master_height_mm,
        residual_mm=load_npy(calibration.residual_npy),
        x_mm=rig.column_x_mm(),
        y_mm=rig.row_y_mm(),
    )


@functools.lru_cache(maxsize=32)
def _curves(geometry_json: str, z_mm: float) -> dict[str, Any]:
    from metrology.core.rig import Rig as CoreRig
    from metrology.core.sensitivity import sensitivity_curves

    return sensitivity_curves(CoreRig.from_dict(json.loads(geometry_json)), z_mm=z_mm)


def sensitivity_curves_for(rig, z_mm: float) -> dict[str, Any]:
    """Figs. 4-6 data of a rig at height ``z_mm`` (cached per geometry and height)."""
    return _curves(json.dumps(rig.geometry(), sort_keys=True), float(z_mm))


def job_result_url(job: Job) -> str:
    """The page that shows what ``job`` produces."""
    params = job.parameters or {}
    if job.kind == Job.Kind.MEASUREMENT and "measurement" in params:
        return reverse("dashboard:measurement", args=[params["measurement"]])
    if job.kind == Job.Kind.CALIBRATION and "calibration" in params:
        return reverse("dashboard:calibration", args=[params["calibration"]])
    if job.kind == Job.Kind.CHARACTERIZATION and "characterization" in params:
        return reverse("dashboard:characterization", args=[params["characterization"]])
    if job.kind == Job.Kind.SIMULATE_CAPTURE:
        capture = getattr(job, "capture", None)
        if capture is not None:
            return reverse("dashboard:rig-captures", args=[capture.rig_id])
    if job.kind == "report":
        return "/reports/"
    return reverse("dashboard:home")


def stage_sessions(user, rig):
    """The user's capture sessions of ``rig`` holding stage captures, with ``n_stage`` (newest first)."""
    from django.db.models import Count, Q

    from metrology.captures.selectors import sessions_for

    return (
        sessions_for(user, rig)
        .annotate(n_stage=Count("captures", filter=Q(captures__role="stage")))
        .filter(n_stage__gt=0)
        .order_by("-id")
    )


def ready_captures(user, rig):
    """The user's stored captures of ``rig`` (newest first), for the forms' choices."""
    from metrology.captures.selectors import captures_for

    return captures_for(user, rig).exclude(file="").order_by("-id")


@functools.cache
def plotly_js() -> bytes:
    """plotly.js as shipped inside the plotly Python package (served locally; no CDN)."""
    from plotly.offline import get_plotlyjs

    return get_plotlyjs().encode("utf-8")
