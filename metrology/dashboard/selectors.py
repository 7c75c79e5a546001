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


def measurement_model(measurement) -> Any:
    """The model class of the rig values a measurement was made with."""
    from metrology.core.geometry import model_class
    from metrology.core.geometry.base import model_name

    return model_class(model_name(measurement.rig_values))


def measurement_quantity(measurement) -> str:
    """What a measurement's ``z`` is: ``"height"`` (above the reference plane, or the model's own
    plane) or ``"depth"`` (camera Z of a model measured without a reference)."""
    if measurement.reference_id is not None:
        return "height"
    return measurement_model(measurement).unreferenced_result


def measurement_figures(measurement, row: int | None = None) -> tuple[dict[str, Any], int, int]:
    """Figures of a finished measurement and the profile row used; returns (figures, row, height_px).

    The map's axes are the model's (:meth:`~metrology.core.geometry.base.GeometryModel.image_axes`:
    the paper's X, Y on R, or camera pixels), the titles say height or depth as the result is."""
    from metrology.core.geometry import model_from_dict
    from metrology.core.mesh import default_max_jump_mm
    from metrology.figures.measurement import measurement_figures as build
    from metrology.measurements.derived import measurement_points

    model = model_from_dict(measurement.rig_values)
    z = load_npy(measurement.height_npy)
    if z is None:
        return {}, 0, model.shape[0]
    points = measurement_points(measurement, z)
    axes = model.image_axes()
    height = z.shape[0]
    row = height // 2 if row is None else min(max(int(row), 0), height - 1)
    figures = build(
        z,
        points,
        row,
        gray_z_mm=load_npy(measurement.gray_only_npy),
        x_mm=axes.x,
        y_mm=axes.y,
        max_jump_mm=default_max_jump_mm(model, points),
        quantity=measurement_quantity(measurement),
        x_label=axes.x_label,
        y_label=axes.y_label,
        unit=axes.unit,
        camera_frame=model.frame == "camera",
    )
    sigma = load_npy(measurement.sigma_npy)
    if sigma is not None:  # the per-point uncertainty (options.sigma)
        from metrology.figures.uncertainty import sigma_map_figure

        figures["sigma_map"] = sigma_map_figure(sigma, axes.x, axes.y)
        figures["sigma_map"].update_xaxes(title_text=axes.x_label)
        figures["sigma_map"].update_yaxes(title_text=axes.y_label)
    pairs = load_npy(measurement.pairs_npy)
    if pairs is not None:  # a stereo rig: which pairs of devices measured each point
        from metrology.figures.pairs import pairs_figure

        figures["pairs_map"] = pairs_figure(pairs)
    return figures, row, height


def calibration_figures(calibration) -> dict[str, Any]:
    from metrology.core.geometry import model_from_dict
    from metrology.figures.calibration import calibration_figures as build

    axes = model_from_dict(calibration.rig_values).image_axes()
    return build(
        calibration.iterations or [],
        calibration.master_height_mm,
        residual_mm=load_npy(calibration.residual_npy),
        x_mm=axes.x,
        y_mm=axes.y,
        result=calibration.result or {},
    )


_CALIBRATED = (("L_mm", "L", "mm"), ("alpha_rad", "alpha", "rad"), ("d_mm", "d", "mm"))


def finite_or_none(value: Any) -> float | None:
    """``value`` as a float, or None when it is not a finite number (stored JSON may hold null)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) else None


def calibration_stop_reason(method: str, result: dict[str, Any]) -> str:
    """Why the fit stopped, in plain words (scipy's and the paper loop's messages translated).

    scipy's ``least_squares`` reports ``"`ftol` termination condition is satisfied."`` and the
    like; the paper's loop ``"converged"`` or ``"not converged after N iterations"``.
    """
    message = str(result.get("message") or "")
    options = result.get("parameters") or {}
    tolerance = finite_or_none(options.get("tolerance"))
    limit = options.get("max_iterations")
    within = f" (relative tolerance {tolerance:g})" if tolerance is not None else ""
    if method == "paper":
        if result.get("converged"):
            dz, m_hat = finite_or_none(options.get("delta_z_mm")), finite_or_none(options.get("m_hat"))
            if dz is not None and m_hat is not None:
                return f"the master's mean height is within {dz * 1000:g} µm of H and its slope within {m_hat:g}"
            return "the master's mean height and slope are within tolerance"
        return f"stopped at the iteration limit ({limit}) before the master's height and slope were within tolerance"
    if "`ftol`" in message and "`xtol`" in message:
        return f"both the residuals and the fitted values stopped changing{within}"
    if "`ftol`" in message:
        return f"the sum of squared height residuals stopped decreasing{within}"
    if "`xtol`" in message:
        return f"the fitted values stopped changing{within}"
    if "`gtol`" in message:
        return f"the fit reached a minimum: its gradient vanished{within}"
    if "maximum number of function evaluations" in message:
        return f"stopped at the iteration limit ({limit}) before converging"
    return "the fit converged" if result.get("converged") else "the fit stopped before converging"


def calibration_summary(calibration) -> dict[str, Any]:
    """What the calibration page states: start -> result per value, iteration count, stop reason.

    ``start`` is the fit's true starting point (``parameters["initial"]``: the rig's values with
    the form's start L and alpha), not the rig's stored values, which are given separately when
    they differ. Uncertainties (least squares only) are one-sigma, in µm for lengths and µrad
    for angles. ``iterations`` is the number of points drawn after the start (iteration 0).
    """
    from metrology.figures.calibration import iteration_points

    result = calibration.result or {}
    stored = calibration.rig_values or {}
    start = {**stored, **((calibration.parameters or {}).get("initial") or {})}
    sigma = result.get("std_errors") or {}
    rows = []
    for key, name, unit in _CALIBRATED:
        before, after, stored_value = (
            finite_or_none(start.get(key)),
            finite_or_none(result.get(key)),
            finite_or_none(stored.get(key)),
        )
        if after is None:
            continue
        u = finite_or_none(sigma.get(key))
        rows.append(
            {
                "name": name,
                "unit": unit,
                "digits": 5 if unit == "rad" else 3,
                "start": before,
                "result": after,
                "changed": before is not None and not np.isclose(before, after, rtol=0.0, atol=1e-9),
                "uncertainty": None if u is None else u * 1e6 if unit == "rad" else u * 1e3,
                "uncertainty_unit": "µrad" if unit == "rad" else "µm",
                "stored": stored_value
                if stored_value is not None and before is not None and not np.isclose(stored_value, before)
                else None,
            }
        )
    points = iteration_points(calibration.iterations or [], result)
    return {
        "values": rows,
        "iterations": max(len(points) - 1, 0),
        "converged": bool(result.get("converged")),
        "stop_reason": calibration_stop_reason(calibration.method, result),
        "residual_rms_mm": finite_or_none(result.get("residual_rms_mm")),
        "n_pixels": result.get("n_pixels"),
    }


@functools.lru_cache(maxsize=32)
def _curves(rig_file_json: str, z_mm: float) -> dict[str, Any]:
    from metrology.core.geometry import model_from_dict
    from metrology.core.sensitivity import sensitivity_curves

    return sensitivity_curves(model_from_dict(json.loads(rig_file_json)), z_mm=z_mm)  # type: ignore[arg-type]


def sensitivity_curves_for(rig, z_mm: float) -> dict[str, Any]:
    """Figs. 4-6 data of a rig at height ``z_mm`` (cached per rig file and height); the page offers
    it where the model has the paper's parameters."""
    return _curves(json.dumps(rig.rig_file(), sort_keys=True), float(z_mm))


def import_message(summary: dict[str, Any]) -> str:
    """What a calibration file's import read, in a sentence: each value's node and the camera size's origin."""
    read = ", ".join(f"{key} from {source.rsplit('#', 1)[-1]}" for key, source in summary.get("read", {}).items())
    size = summary.get("camera_size") or {}
    width, height = (size.get("value") or [None, None])[:2]
    origin = size.get("from") or "the form"
    return (
        f"Imported the calibration: {read}; camera {width} x {height} px (from {origin}); "
        f"triangulate auto takes the {summary.get('triangulate_auto')} axis."
    )


def job_result_url(job: Job) -> str:
    """The page that shows what ``job`` produces."""
    params = job.parameters or {}
    if job.kind == Job.Kind.MEASUREMENT and "measurement" in params:
        return reverse("dashboard:measurement", args=[params["measurement"]])
    if job.kind == Job.Kind.CALIBRATION and "calibration" in params:
        return reverse("dashboard:calibration", args=[params["calibration"]])
    if job.kind == Job.Kind.PROCAM_CALIBRATION and "procam_calibration" in params:
        return reverse("dashboard:procam-calibration", args=[params["procam_calibration"]])
    if job.kind == Job.Kind.CHARACTERIZATION and "characterization" in params:
        return reverse("dashboard:characterization", args=[params["characterization"]])
    if job.kind == Job.Kind.SIMULATE_CAPTURE:
        capture = getattr(job, "capture", None)
        if capture is not None:
            return reverse("dashboard:rig-captures", args=[capture.rig_id])
    if job.kind == "report":
        return "/reports/"
    if job.kind == Job.Kind.DERIVED_FILE and {"measurement", "filename"} <= params.keys():
        # the file itself: downloaded from the storage once the job is done
        return reverse(f"measurement-{params['filename']}", kwargs={"measurement_id": params["measurement"]})
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


def capture_origin(capture) -> str:
    """Where a capture came from, in words: the uploaded file's name, the virtual scene's name, or the source.

    Uploads carry empty ``parameters``; virtual captures carry ``{"scene": {"name": ...}, ...}``.
    """
    parameters = capture.parameters if isinstance(capture.parameters, dict) else {}
    scene = parameters.get("scene")
    scene_name = scene.get("name", "") if isinstance(scene, dict) else ""
    return str(capture.original_name or scene_name or capture.source)


def upload_message(capture) -> str:
    """What an upload stored, in a sentence: the capture (number, role, file, frames) and the codec
    it is decoded with, saying when that is the rig's default (a zip without ``codec.json``)."""
    from metrology.captures.codecs import codec_label
    from metrology.rigs.codecs import capture_default

    codec = codec_label(capture.codec)
    if capture.codec == capture_default(capture.rig):
        codec = f"{codec}, the rig's default codec (used when the zip has no codec.json)"
    else:
        codec = f"{codec}, from the zip's codec.json"
    return (
        f"Stored capture #{capture.pk} ({capture.get_role_display().lower()}, {capture_origin(capture)}): "
        f"{capture.width_px} x {capture.height_px} px, {capture.bit_depth} bit, decoded with {codec}."
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


def capture_decoding(capture) -> tuple[dict[str, Any], dict[str, Any]]:
    """Figures of a stored capture's decoding with its codec (u/v maps, modulation, reasons) and the
    decoding summary; ``({}, {"error": ...})`` when the stack cannot be read or decoded."""
    from metrology.captures.codecs import capture_codec
    from metrology.captures.stacks import load_codec_stack, load_exposure_stack
    from metrology.core.codecs.decode import decode_codec
    from metrology.core.codecs.exposures import decode_exposures
    from metrology.figures.capture import decoding_figures

    try:
        if capture.exposures:  # fused per pixel (docs/exposures.md)
            decoding = decode_exposures(load_exposure_stack(capture), capture_codec(capture), with_noise=False)
        else:
            stack = load_codec_stack(capture)
            decoding = decode_codec(stack.images, stack.codec, with_noise=False)
    except (ValueError, OSError) as exc:
        return {}, {"error": str(exc)}
    arrays = {
        name: {
            "coordinate": axis.coordinate,
            "modulation": axis.modulation,
            "reason": axis.reason,
            **({"exposure": decoding.exposure[name]} if name in decoding.exposure else {}),
        }
        for name, axis in decoding.axes.items()
    }
    summary = decoding.summary()
    exposures = summary.get("exposures")
    if exposures is not None:  # per exposure: its time and the pixels it measured on each axis
        times = {entry["name"]: entry for entry in capture.exposures}
        summary["exposure_rows"] = [
            {
                "name": name,
                "exposure_us": times.get(name, {}).get("exposure_us"),
                "gain": times.get(name, {}).get("gain", 1.0),
                "pixels": {axis: counts[name] for axis, counts in exposures["pixels"].items()},
            }
            for name in exposures["names"]
        ]
        summary["exposure_none"] = {axis: counts["none"] for axis, counts in exposures["pixels"].items()}
    return decoding_figures(arrays, decoding.exposure_names), summary
