"""Pages of inspections: nominal models (list, upload), inspections (request on a measurement, the
result with its deviation map, histogram, alignment and conformance, a printable report) and a
rig's inspection plan with its trend across measurements."""

from __future__ import annotations

from typing import Any

import numpy as np
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.views.decorators.http import require_http_methods

from metrology.dashboard import forms
from metrology.inspections import selectors, services
from metrology.measurements import selectors as measurement_selectors
from metrology.rigs import selectors as rig_selectors
from metrology.service_errors import SERVICE_ERRORS, error_sentence


@login_required
@require_http_methods(["GET", "POST"])
def nominal_list(request: HttpRequest) -> HttpResponse:
    form = forms.NominalUploadForm(request.POST or None, request.FILES or None)
    if request.method == "POST" and form.is_valid():
        try:
            services.upload_nominal(
                owner=request.user, upload=form.cleaned_data["file"], name=form.cleaned_data.get("name")
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:nominals")
    return render(
        request,
        "dashboard/nominals.html",
        {"nominals": selectors.nominals_for(request.user)[:200], "form": form},
        status=400 if request.method == "POST" else 200,
    )


@login_required
def inspection_list(request: HttpRequest) -> HttpResponse:
    return render(request, "dashboard/inspections.html", {"inspections": selectors.inspections_for(request.user)[:200]})


@login_required
@require_http_methods(["GET", "POST"])
def inspection_new(request: HttpRequest, measurement_id: int) -> HttpResponse:
    measurement = measurement_selectors.get_measurement(request.user, measurement_id)
    nominals = selectors.nominals_for(request.user)
    form = forms.InspectionForm(request.POST or None, nominals=nominals)
    if request.method == "POST" and form.is_valid():
        try:
            inspection = services.request_inspection(
                owner=request.user,
                measurement=measurement,
                nominal=selectors.get_nominal(request.user, form.cleaned_data["nominal"]),
                options=form.options(),
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:inspection", inspection.pk)
    return render(
        request,
        "dashboard/inspection_new.html",
        {"measurement": measurement, "form": form, "has_nominals": nominals.exists()},
        status=400 if request.method == "POST" else 200,
    )


def _inspection_context(inspection) -> dict[str, Any]:
    """What the inspection page and its report show: the report's figures and, once done, the
    deviation map and histogram."""
    from metrology.figures.inspection import deviation_histogram, deviation_map
    from metrology.measurements.derived import measurement_points

    report = inspection.report or {}
    context: dict[str, Any] = {"inspection": inspection, "job": inspection.job, "report": report, "figures": []}
    if inspection.job.status != "done" or not inspection.deviations_npy:
        return context
    with inspection.deviations_npy.open("rb") as handle:
        deviations = np.load(handle, allow_pickle=False)
    tolerance = report.get("tolerance_mm")
    points = measurement_points(inspection.measurement)
    context["figures"] = [
        ("deviation_map", "Deviation map", deviation_map(points, deviations, tolerance)),
        ("deviation_histogram", "Histogram", deviation_histogram(deviations, tolerance)),
    ]
    alignment = report.get("alignment") or {}
    std = alignment.get("std") or {}
    context["alignment_rows"] = [
        ("Start", (report.get("provenance") or {}).get("start", {}).get("method", alignment.get("method"))),
        ("Method", alignment.get("method")),
        ("RMS of the fit", _um(alignment.get("rms_mm"))),
        ("Points used", alignment.get("points_used")),
        ("Iterations", alignment.get("iterations")),
        ("Converged", "yes" if alignment.get("converged") else "no"),
        ("Free degrees of freedom (symmetry)", _free_dof(alignment.get("symmetric_dof"))),
        ("Rotation std (deg)", _list(std.get("rotation_deg"), "{:.2e}")),
        ("Translation std (µm)", _list([_scaled(v, 1000) for v in std.get("translation_mm") or []], "{:.3f}")),
    ]
    deviation = report.get("deviation") or {}
    context["deviation_rows"] = [
        (label, _um(deviation.get(key)))
        for label, key in (
            ("Mean", "mean_mm"),
            ("Standard deviation", "std_mm"),
            ("RMS", "rms_mm"),
            ("Minimum", "min_mm"),
            ("1st percentile", "p01_mm"),
            ("99th percentile", "p99_mm"),
            ("Maximum", "max_mm"),
        )
    ]
    context["transform"] = report.get("transform")
    context["feature_rows"] = feature_rows(report.get("features") or [])
    return context


def _quantity_text(name: str, value: Any) -> str:
    """A compared quantity's value: mm to 0.1 um, degrees to 1e-4; "-" when absent."""
    if value is None:
        return "-"
    if name.endswith("_deg"):
        return f"{float(value):.4f}°"
    return f"{float(value):.4f} mm"


def feature_rows(features: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per compared quantity of each feature of the report (``features``, docs/inspection.md):
    the feature (on its first row), the quantity, its measured value, standard uncertainty, nominal
    value and difference; a feature without numbers gets one row with its error."""
    rows: list[dict[str, Any]] = []
    for feature in features:
        head = {"name": feature.get("name"), "kind": feature.get("kind"), "points": feature.get("points")}
        if feature.get("error"):
            rows.append({**head, "first": True, "error": feature["error"]})
            continue
        for index, q in enumerate(feature.get("quantities") or []):
            name = str(q.get("name"))
            rows.append(
                {
                    **head,
                    "first": index == 0,
                    "quantity": name.removesuffix("_mm").removesuffix("_deg").replace("_", " "),
                    "measured": _quantity_text(name, q.get("measured")),
                    "std": _quantity_text(name, q.get("u_measured")),
                    "nominal": _quantity_text(name, q.get("nominal")),
                    "difference": _quantity_text(name, q.get("difference")),
                }
            )
    return rows


def _um(value: Any) -> str:
    return "-" if value is None else f"{float(value) * 1000:.2f} µm"


def _vector(values: Any) -> str:
    return "(" + ", ".join(f"{float(v):.3g}" for v in values) + ")"


def _free_dof(free: Any) -> str:
    """The report's ``symmetric_dof`` in words: "none", or each free motion ("rotation about (0, 0, 1)
    through (352, 0, 0) mm", "translation along (1, 0, 0)")."""
    if not free:
        return "none"
    if not isinstance(free, list):
        return str(free)
    words = []
    for motion in free:
        if motion.get("kind") == "rotation":
            words.append(f"rotation about {_vector(motion['axis'])} through {_vector(motion['point_mm'])} mm")
        elif motion.get("kind") == "translation":
            words.append(f"translation along {_vector(motion['direction'])}")
        else:
            words.append(str(motion))
    return "; ".join(words)


def _scaled(value: Any, factor: float) -> float | None:
    return None if value is None else float(value) * factor


def _list(values: Any, fmt: str) -> str:
    """Numbers of a report's list; "free" for a value the alignment cannot determine (None)."""
    return ", ".join("free" if v is None else fmt.format(float(v)) for v in values) if values else "-"


@login_required
def inspection_detail(request: HttpRequest, inspection_id: int) -> HttpResponse:
    inspection = selectors.get_inspection(request.user, inspection_id)
    return render(request, "dashboard/inspection.html", _inspection_context(inspection))


@login_required
def inspection_report(request: HttpRequest, inspection_id: int) -> HttpResponse:
    """A printable HTML report of a finished inspection (figures, tables, provenance)."""
    inspection = selectors.get_inspection(request.user, inspection_id)
    return render(request, "dashboard/inspection_report.html", _inspection_context(inspection))


def _feature_history(inspections: list[Any], name: Any) -> list[dict[str, Any]]:
    """``[{"measurement": id, "feature": the report's entry named name or None}]``, in the inspections' order."""
    history = []
    for inspection in inspections:
        found = [f for f in (inspection.report or {}).get("features") or [] if f.get("name") == name]
        history.append({"measurement": inspection.measurement_id, "feature": found[0] if found else None})
    return history


@login_required
@require_http_methods(["GET", "POST"])
def rig_inspection_plan(request: HttpRequest, rig_id: int) -> HttpResponse:
    from metrology.figures.inspection import feature_trend, plan_trend

    rig = rig_selectors.get_rig(request.user, rig_id)
    plan = selectors.plan_of_rig(rig)
    initial = {"nominal": plan.nominal_id, **plan.options} if plan else None
    form = forms.InspectionForm(request.POST or None, initial=initial, nominals=selectors.nominals_for(request.user))
    if request.method == "POST" and form.is_valid():
        try:
            services.set_plan(
                owner=request.user,
                rig=rig,
                nominal=selectors.get_nominal(request.user, form.cleaned_data["nominal"]),
                options=form.options(),
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:rig-inspection-plan", rig.pk)
    inspections = list(selectors.plan_inspections(plan)) if plan else []
    trend = plan_trend([{"measurement": i.measurement_id, "deviation": i.report.get("deviation")} for i in inspections])
    names = [f.get("name") for f in (plan.options.get("features") or [])] if plan else []
    feature_trends = [
        (f"feature_trend_{index}", f"Feature {name}", feature_trend(str(name), _feature_history(inspections, name)))
        for index, name in enumerate(names)
    ]
    return render(
        request,
        "dashboard/rig_inspection_plan.html",
        {
            "rig": rig,
            "plan": plan,
            "form": form,
            "inspections": inspections,
            "trend": trend,
            "feature_trends": feature_trends,
        },
        status=400 if request.method == "POST" else 200,
    )
