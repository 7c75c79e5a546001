"""Browser pages: parse the request, call the same services and selectors as the REST API, render.

Every page needs a login and shows the user's own objects only (the selectors filter by owner, so
another user's object is a 404). Errors that the services raise are shown in words on the form.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlencode

from django.contrib.auth.decorators import login_required
from django.db import transaction
from django.http import HttpRequest, HttpResponse
from django.shortcuts import redirect, render
from django.urls import reverse
from django.utils.datastructures import MultiValueDict
from django.utils.http import url_has_allowed_host_and_scheme
from django.views.decorators.http import require_http_methods, require_POST

from metrology.calibrations import procam_services
from metrology.calibrations import selectors as calibration_selectors
from metrology.calibrations import services as calibration_services
from metrology.captures import selectors as capture_selectors
from metrology.captures import services as capture_services
from metrology.characterizations import selectors as characterization_selectors
from metrology.characterizations import services as characterization_services
from metrology.dashboard import forms
from metrology.dashboard import selectors as pages
from metrology.inspections.selectors import inspections_of_measurement
from metrology.jobs import selectors as job_selectors
from metrology.measurements import selectors as measurement_selectors
from metrology.measurements import services as measurement_services
from metrology.measurements.derived import available_files
from metrology.rigs import selectors as rig_selectors
from metrology.rigs import services as rig_services
from metrology.rigs.codecs import capture_default
from metrology.service_errors import SERVICE_ERRORS, error_sentence
from metrology.version import software_version


def _rig_from_query(request: HttpRequest):
    rig_id = request.GET.get("rig") or request.POST.get("rig")
    return rig_selectors.get_rig(request.user, rig_id) if rig_id else None


# ----------------------------------------------------------------------------- home, jobs


@login_required
def home(request: HttpRequest) -> HttpResponse:
    user = request.user
    return render(
        request,
        "dashboard/home.html",
        {
            "rigs": rig_selectors.rigs_for(user),
            "jobs": job_selectors.jobs_for(user)[:10],
            "measurements": measurement_selectors.measurements_for(user)[:5],
            "characterizations": characterization_selectors.characterizations_for(user)[:5],
        },
    )


JOBS_PER_PAGE = 50


@login_required
def job_list(request: HttpRequest) -> HttpResponse:
    """The user's jobs, newest first, filtered by kind and state, 50 a page, each with its result's page."""
    from django.core.paginator import Paginator

    form = forms.JobFilterForm(request.GET or None)
    filters = form.filters() if request.GET else {"kind": "", "status": ""}
    page = Paginator(job_selectors.jobs_filtered(request.user, **filters), JOBS_PER_PAGE).get_page(
        request.GET.get("page")
    )
    query = urlencode({key: value for key, value in filters.items() if value})
    return render(
        request,
        "dashboard/jobs.html",
        {
            "form": form if request.GET else forms.JobFilterForm(),
            "page": page,
            "jobs": [(job, pages.job_result_url(job)) for job in page],
            "filtered": any(filters.values()),
            "query": query,
        },
    )


@login_required
def job_detail(request: HttpRequest, job_id: int) -> HttpResponse:
    job = job_selectors.get_job(request.user, job_id)
    next_url = request.GET.get("next", "")
    if not url_has_allowed_host_and_scheme(next_url, allowed_hosts={request.get_host()}):
        next_url = pages.job_result_url(job)
    return render(request, "dashboard/job.html", {"job": job, "next_url": next_url})


@login_required
def plotly_js(request: HttpRequest) -> HttpResponse:
    response = HttpResponse(pages.plotly_js(), content_type="application/javascript; charset=utf-8")
    response["Cache-Control"] = "private, max-age=86400"
    return response


def favicon(request: HttpRequest) -> HttpResponse:
    """The site icon (SVG; also answered at /favicon.ico, which browsers ask for by themselves). No login."""
    from django.template.loader import render_to_string

    response = HttpResponse(render_to_string("dashboard/favicon.svg"), content_type="image/svg+xml")
    response["Cache-Control"] = "public, max-age=604800"
    return response


# ----------------------------------------------------------------------------- rigs


RIG_FORMS = ("values", "rig_file", "calibration")
"""The three ways the rigs page creates a rig: typed values, a rig file, a calibration file."""


@login_required
@require_http_methods(["GET", "POST"])
def rig_list(request: HttpRequest) -> HttpResponse:
    """The rigs, and three ways to add one: the model's values typed one by one, a rig file of any
    model, or an OpenCV FileStorage calibration file read as ``gcps rig import`` reads it (the
    message says which nodes were read)."""
    from django.contrib import messages

    posted = request.POST.get("action", "values") if request.method == "POST" else ""
    data = request.POST if posted else None
    files = request.FILES if posted else None
    form = forms.RigForm(data if posted == "values" else None)
    rig_file_form = forms.RigFileForm(data if posted == "rig_file" else None, files, prefix="file")
    import_form = forms.CalibrationImportForm(data if posted == "calibration" else None, files, prefix="import")
    try:
        if posted == "values" and form.is_valid():
            rig = rig_services.create_rig(owner=request.user, data=form.rig_data())
            return redirect("dashboard:rig", rig.pk)
        if posted == "rig_file" and rig_file_form.is_valid():
            rig_file = {**rig_file_form.cleaned_data["rig_file"], "name": rig_file_form.cleaned_data.get("name") or ""}
            rig = rig_services.create_rig(owner=request.user, data=rig_file)
            return redirect("dashboard:rig", rig.pk)
        if posted == "calibration" and import_form.is_valid():
            rig, summary = rig_services.import_calibration_file(owner=request.user, **import_form.import_kwargs())
            messages.success(request, pages.import_message(summary))
            return redirect("dashboard:rig", rig.pk)
    except SERVICE_ERRORS as exc:
        failed = {"values": form, "rig_file": rig_file_form, "calibration": import_form}[posted]
        failed.add_error(None, error_sentence(exc))
    return render(
        request,
        "dashboard/rigs.html",
        {
            "rigs": [(rig, rig.to_core()) for rig in rig_selectors.rigs_for(request.user)],
            "form": form,
            "rig_file_form": rig_file_form,
            "import_form": import_form,
            "posted": posted,
        },
        status=400 if posted else 200,
    )


def _codec_label(value: Any) -> str:
    from metrology.captures.codecs import codec_label

    return codec_label(value)


def _codec_initial(rig) -> str:
    import json

    return rig.codec if isinstance(rig.codec, str) else json.dumps(rig.codec, indent=1)


@login_required
@require_http_methods(["GET", "POST"])
def rig_detail(request: HttpRequest, rig_id: int) -> HttpResponse:
    """A rig's page, and its two forms: the default codec (``action`` ``codec``, the default) and a
    calibration file imported into the rig (``action`` ``calibration``, read as ``gcps rig import``)."""
    from django.contrib import messages

    rig = rig_selectors.get_rig(request.user, rig_id)
    action = request.POST.get("action", "codec") if request.method == "POST" else ""
    codec_form = forms.RigCodecForm(request.POST if action == "codec" else None, initial={"codec": _codec_initial(rig)})
    import_form = forms.CalibrationFileForm(
        request.POST if action == "calibration" else None,
        request.FILES if action == "calibration" else None,
        prefix="import",
    )
    if action == "codec" and codec_form.is_valid():
        try:
            rig_services.set_rig_codec(rig=rig, codec=codec_form.cleaned_data["codec"])
        except SERVICE_ERRORS as exc:
            codec_form.add_error(None, error_sentence(exc))
        else:
            if request.POST.get("next") == "captures":  # the captures page's "Use ... as the default codec"
                return redirect("dashboard:rig-captures", rig.pk)
            return redirect("dashboard:rig", rig.pk)
    if action == "calibration" and import_form.is_valid():
        try:
            rig, summary = rig_services.import_calibration_into_rig(rig=rig, **import_form.import_kwargs())
        except SERVICE_ERRORS as exc:
            import_form.add_error(None, error_sentence(exc))
        else:
            messages.success(request, pages.import_message(summary))
            return redirect("dashboard:rig", rig.pk)
    return _rig_page(request, rig, codec_form, import_form, status=400 if action else 200)


def _rig_page(
    request: HttpRequest,
    rig,
    codec_form,
    import_form=None,
    *,
    status: int = 200,
    restore_error: str = "",
) -> HttpResponse:
    from metrology.captures.codecs import codec_label

    user = request.user
    history = list(reversed(rig_selectors.rig_history(rig)))
    model = rig.to_core()
    return render(
        request,
        "dashboard/rig.html",
        {
            "codec_form": codec_form,
            "import_form": import_form if import_form is not None else forms.CalibrationFileForm(prefix="import"),
            "codec_label": codec_label(rig.codec),
            "rig": rig,
            "model": model,
            "values": model.value_rows(),
            "can": rig_selectors.rig_capabilities(rig),
            "history": history,
            "restore_error": restore_error,
            "captures": capture_selectors.captures_for(user, rig).order_by("-id")[:10],
            "measurements": measurement_selectors.measurements_for(user).filter(rig=rig)[:10],
            "calibrations": calibration_selectors.calibrations_for(user).filter(rig=rig)[:10],
            "procam_calibrations": calibration_selectors.procam_calibrations_for(user, rig)[:10],
            "characterizations": characterization_selectors.characterizations_for(user).filter(rig=rig)[:10],
        },
        status=status,
    )


@login_required
@require_POST
def rig_restore(request: HttpRequest, rig_id: int, entry_id: int) -> HttpResponse:
    """Make an earlier history entry the rig's values again; back to the rig page's history."""
    rig = rig_selectors.get_rig(request.user, rig_id)
    try:
        rig_services.restore_rig_entry(rig=rig, entry_id=entry_id)
    except SERVICE_ERRORS as exc:
        rig = rig_selectors.get_rig(request.user, rig_id)
        codec_form = forms.RigCodecForm(initial={"codec": _codec_initial(rig)})
        return _rig_page(request, rig, codec_form, status=400, restore_error=error_sentence(exc))
    return redirect(reverse("dashboard:rig", args=[rig.pk]) + "#h-hist")


@login_required
def rig_sensitivity(request: HttpRequest, rig_id: int) -> HttpResponse:
    from metrology.figures.sensitivity import sensitivity_figures

    rig = rig_selectors.get_rig(request.user, rig_id)
    if not rig_selectors.rig_capabilities(rig).sensitivity:  # Figs. 4-6 need the paper's parameters
        return redirect("dashboard:rig", rig.pk)
    error = ""
    try:
        z_mm = float(request.GET.get("z_mm", 40.0))
        curves = pages.sensitivity_curves_for(rig, z_mm)
    except (TypeError, ValueError) as exc:
        z_mm, curves, error = 40.0, pages.sensitivity_curves_for(rig, 40.0), f"Height not usable: {exc}"
    return render(
        request,
        "dashboard/sensitivity.html",
        {"rig": rig, "z_mm": z_mm, "figures": sensitivity_figures(curves), "curves": curves, "error": error},
    )


# ----------------------------------------------------------------------------- captures


@login_required
def capture_list(request: HttpRequest) -> HttpResponse:
    return render(
        request,
        "dashboard/captures.html",
        {
            "rigs": rig_selectors.rigs_for(request.user),
            "captures": capture_selectors.captures_for(request.user).select_related("rig").order_by("-id")[:200],
        },
    )


@login_required
def capture_detail(request: HttpRequest, capture_id: int) -> HttpResponse:
    """A capture: its provenance and codec; once stored, its decoding (u/v maps, modulation, reasons)."""
    from metrology.captures.codecs import capture_codec_value, codec_label

    capture = capture_selectors.get_capture(request.user, capture_id)
    figures, summary = pages.capture_decoding(capture) if capture.ready else ({}, {})
    return render(
        request,
        "dashboard/capture.html",
        {
            "capture": capture,
            "codec_label": codec_label(capture_codec_value(capture)),
            "figures": figures,
            "summary": summary,
        },
    )


@login_required
@require_http_methods(["GET", "POST"])
def rig_captures(request: HttpRequest, rig_id: int) -> HttpResponse:
    rig = rig_selectors.get_rig(request.user, rig_id)
    action = request.POST.get("action") if request.method == "POST" else None
    upload = forms.UploadCaptureForm(request.POST or None, request.FILES or None, prefix="upload")
    simulate = forms.SimulateCaptureForm(request.POST or None, prefix="simulate")
    stage = forms.StageSeriesForm(request.POST or None, prefix="stage")
    bound = {"upload": upload, "simulate": simulate, "stage": stage}
    for name, form in bound.items():
        if name != action:
            form.is_bound = False  # only the submitted form shows errors
            form.data, form.files = MultiValueDict(), MultiValueDict()  # what Django gives an unbound form
    if action in bound and bound[action].is_valid():
        try:
            target = _start_capture(request, rig, action, bound[action])
        except SERVICE_ERRORS as exc:
            bound[action].add_error(None, error_sentence(exc))
        else:
            return redirect(target)
    return render(
        request,
        "dashboard/rig_captures.html",
        {
            "rig": rig,
            "upload_form": upload,
            "simulate_form": simulate,
            "stage_form": stage,
            "can": rig_selectors.rig_capabilities(rig),
            "codec_label": _codec_label(capture_default(rig)),  # the codec itself, also when unset (gcps-v1)
            "captures": capture_selectors.captures_for(request.user, rig).order_by("-id")[:200],
            "sessions": pages.stage_sessions(request.user, rig),
        },
        status=400 if action else 200,
    )


def _start_capture(request: HttpRequest, rig, action: str, form) -> str:
    """Call the capture service for the submitted form; returns where to go next."""
    data = form.cleaned_data
    if action == "upload":
        from django.contrib import messages

        capture = capture_services.upload_capture(
            owner=request.user,
            rig=rig,
            upload=data["file"],
            role=data["role"],
            z_in_mm=data.get("z_in_mm"),
            repeat=data.get("repeat") or 0,
        )
        messages.success(request, pages.upload_message(capture))
        return reverse("dashboard:rig-captures", args=[rig.pk])
    if action == "simulate":
        capture = capture_services.request_simulated_capture(owner=request.user, rig=rig, **form.request_kwargs())
        return reverse("dashboard:job", args=[capture.job_id])
    from metrology.core.simulate import series_seed

    options = forms.NOISE_PRESETS[data["noise"]][1]
    with transaction.atomic():
        session = capture_services.create_session(
            owner=request.user, rig=rig, name=f"stage {data['z_from_mm']:g}-{data['z_to_mm']:g} mm"
        )
        last = None
        for index, z_in in enumerate(data["positions"]):
            for repeat in range(data["repeats"]):
                last = capture_services.request_simulated_capture(
                    owner=request.user,
                    rig=rig,
                    role="stage",
                    scene={"name": "stage"},
                    options={**options, "seed": series_seed(100, index, repeat)},
                    z_in_mm=z_in,
                    repeat=repeat,
                    session_id=session.pk,
                )
    assert last is not None, "the form gives at least two positions and one repeat"
    after = f"{reverse('dashboard:characterization-new')}?{urlencode({'rig': rig.pk, 'session': session.pk})}"
    return f"{reverse('dashboard:job', args=[last.job_id])}?{urlencode({'next': after})}"


# ----------------------------------------------------------------------------- measurements


@login_required
def measurement_list(request: HttpRequest) -> HttpResponse:
    return render(
        request,
        "dashboard/measurements.html",
        {
            "measurements": measurement_selectors.measurements_for(request.user)[:200],
            "rigs": rig_selectors.rigs_for(request.user),
        },
    )


@login_required
@require_http_methods(["GET", "POST"])
def measurement_new(request: HttpRequest) -> HttpResponse:
    rig = _rig_from_query(request)
    if rig is None:
        return render(request, "dashboard/choose_rig.html", _choose_rig(request, "measurement"))
    can = rig_selectors.rig_capabilities(rig)
    form = forms.MeasurementForm(
        request.POST or None,
        captures=pages.ready_captures(request.user, rig),
        reference_optional=not can.requires_reference,
        unreferenced=can.unreferenced_result,
    )
    if request.method == "POST" and form.is_valid():
        try:
            measurement = measurement_services.request_measurement(
                owner=request.user,
                rig=rig,
                reference_id=form.cleaned_data.get("reference"),
                object_id=form.cleaned_data["object"],
                options=form.options(),
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:measurement", measurement.pk)
    return render(
        request,
        "dashboard/measurement_new.html",
        {"rig": rig, "form": form, "can": can},
        status=400 if request.method == "POST" else 200,
    )


@login_required
def measurement_detail(request: HttpRequest, measurement_id: int) -> HttpResponse:
    figures: dict[str, Any]
    measurement = measurement_selectors.get_measurement(request.user, measurement_id)
    figures, row, height = {}, 0, measurement.rig.height_px
    if measurement.job.status == "done":
        requested = request.GET.get("row")
        figures, row, height = pages.measurement_figures(
            measurement, int(requested) if requested and requested.lstrip("-").isdigit() else None
        )
    files = [
        (name, reverse(f"measurement-{name}", kwargs={"measurement_id": measurement.pk}))
        for name in available_files(measurement)
    ]
    return render(
        request,
        "dashboard/measurement.html",
        {
            "measurement": measurement,
            "job": measurement.job,
            "figures": figures,
            "row": row,
            "max_row": max(0, height - 1),
            "files": files,
            "stats": measurement.statistics or {},
            "quantity": (quantity := pages.measurement_quantity(measurement)),
            "quantity_map_title": f"{quantity.capitalize()} map",
            "model_label": pages.measurement_model(measurement).label,
            "inspections": inspections_of_measurement(measurement),
        },
    )


# ----------------------------------------------------------------------------- calibrations


@login_required
def calibration_list(request: HttpRequest) -> HttpResponse:
    return render(
        request,
        "dashboard/calibrations.html",
        {"calibrations": calibration_selectors.calibrations_for(request.user)[:200]},
    )


@login_required
@require_http_methods(["GET", "POST"])
def calibration_new(request: HttpRequest) -> HttpResponse:
    rig = _rig_from_query(request)
    if rig is None:
        return render(request, "dashboard/choose_rig.html", _choose_rig(request, "calibration"))
    form = forms.CalibrationForm(request.POST or None, captures=pages.ready_captures(request.user, rig))
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        try:
            calibration = calibration_services.request_calibration(
                owner=request.user,
                rig=rig,
                reference_id=data["reference"],
                master_id=data["master"],
                master_height_mm=data["master_height_mm"],
                method=data["method"],
                initial=form.initial_values(),
                apply=data["apply"],
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:calibration", calibration.pk)
    return render(
        request,
        "dashboard/calibration_new.html",
        {"rig": rig, "form": form, "can": rig_selectors.rig_capabilities(rig)},
        status=400 if request.method == "POST" else 200,
    )


@login_required
def calibration_detail(request: HttpRequest, calibration_id: int) -> HttpResponse:
    calibration = calibration_selectors.get_calibration(request.user, calibration_id)
    figures = pages.calibration_figures(calibration) if calibration.job.status == "done" else {}
    return render(
        request,
        "dashboard/calibration.html",
        {
            "calibration": calibration,
            "job": calibration.job,
            "figures": figures,
            "result": calibration.result or {},
            "summary": pages.calibration_summary(calibration),
            "error": request.GET.get("error", ""),
        },
    )


@login_required
@require_POST
def calibration_apply(request: HttpRequest, calibration_id: int) -> HttpResponse:
    calibration = calibration_selectors.get_calibration(request.user, calibration_id)
    try:
        calibration_services.apply_calibration(calibration=calibration)
    except SERVICE_ERRORS as exc:
        calibration = calibration_selectors.get_calibration(request.user, calibration_id)
        return render(
            request,
            "dashboard/calibration.html",
            {
                "calibration": calibration,
                "job": calibration.job,
                "figures": {},
                "result": calibration.result or {},
                "summary": pages.calibration_summary(calibration),
                "error": error_sentence(exc),
            },
            status=400,
        )
    return redirect("dashboard:rig", calibration.rig_id)


# ----------------------------------------------------------------------------- procam calibrations


@login_required
def procam_list(request: HttpRequest) -> HttpResponse:
    rig = _rig_from_query(request)
    return render(
        request,
        "dashboard/procam_calibrations.html",
        {"rig": rig, "calibrations": calibration_selectors.procam_calibrations_for(request.user, rig)[:200]},
    )


@login_required
@require_http_methods(["GET", "POST"])
def procam_new(request: HttpRequest) -> HttpResponse:
    """The board spec, the pose zips (uploaded into one new capture session) or stored board captures,
    the options; starts the job and goes to the calibration's page."""
    rig = _rig_from_query(request)
    if rig is None:
        return render(request, "dashboard/choose_rig.html", _choose_rig(request, "projector-camera calibration"))
    board_captures = pages.ready_captures(request.user, rig).filter(role="board").order_by("id")
    form = forms.ProcamCalibrationForm(request.POST or None, request.FILES or None, board_captures=board_captures)
    if request.method == "POST" and form.is_valid():
        try:
            data = form.cleaned_data
            calibration = procam_services.request_procam_calibration_with_uploads(
                owner=request.user,
                rig=rig,
                uploads=data.get("pose_files") or [],
                existing_ids=data.get("existing") or [],
                board=data["board"],
                options=form.options(),
                apply=data["apply"],
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:procam-calibration", calibration.pk)
    return render(
        request,
        "dashboard/procam_new.html",
        {
            "rig": rig,
            "converts_from": procam_services.converted_model(rig),
            "form": form,
            "has_board_captures": bool(form.fields["existing"].choices),
            "option_fields": [
                form[name]
                for name in (
                    "window",
                    "min_decoded",
                    "min_modulation",
                    "min_inverse_contrast",
                    "fix_k3",
                    "fixed_intrinsics",
                    "apply",
                )
            ],
        },
        status=400 if request.method == "POST" else 200,
    )


def _procam_context(request: HttpRequest, calibration, error: str = "") -> dict[str, Any]:
    from metrology.dashboard.procam_pages import procam_summary, rig_change

    done = calibration.job.status == "done"
    return {
        "calibration": calibration,
        "job": calibration.job,
        "summary": procam_summary(calibration.report) if done else {},
        "rig_change": rig_change(calibration.rig_before or {}, calibration.rig_file),
        "pose_ids": calibration_selectors.procam_pose_ids(calibration),
        "error": error,
    }


@login_required
def procam_detail(request: HttpRequest, calibration_id: int) -> HttpResponse:
    calibration = calibration_selectors.get_procam_calibration(request.user, calibration_id)
    return render(request, "dashboard/procam_calibration.html", _procam_context(request, calibration))


@login_required
@require_POST
def procam_apply(request: HttpRequest, calibration_id: int) -> HttpResponse:
    calibration = calibration_selectors.get_procam_calibration(request.user, calibration_id)
    try:
        procam_services.apply_procam_calibration(calibration=calibration)
    except SERVICE_ERRORS as exc:
        calibration = calibration_selectors.get_procam_calibration(request.user, calibration_id)
        context = _procam_context(request, calibration, error_sentence(exc))
        return render(request, "dashboard/procam_calibration.html", context, status=400)
    return redirect("dashboard:rig", calibration.rig_id)


def _svg(text: str) -> HttpResponse:
    """An SVG figure: no script may run in it, even when opened on its own."""
    response = HttpResponse(text, content_type="image/svg+xml; charset=utf-8")
    response["Content-Security-Policy"] = "default-src 'none'; style-src 'unsafe-inline'"
    response["X-Content-Type-Options"] = "nosniff"
    response["Cache-Control"] = "private, max-age=3600"
    return response


@login_required
def procam_residual_svg(request: HttpRequest, calibration_id: int, index: int) -> HttpResponse:
    """The residual arrows of the calibration's pose ``index`` (0-based, the report's order), SVG."""
    from django.http import Http404

    from metrology.core.procam.figures import residual_svg

    calibration = calibration_selectors.get_procam_calibration(request.user, calibration_id)
    poses = (calibration.report or {}).get("poses") or []
    if not 0 <= index < len(poses) or not poses[index].get("used"):
        raise Http404(f"procam calibration {calibration.pk} has no used pose {index}")
    return _svg(residual_svg(calibration.report, poses[index]["name"]))


@login_required
def procam_coverage_svg(request: HttpRequest, calibration_id: int, device: str) -> HttpResponse:
    """The used corners over the camera's or the projector's image and the covered grid cells, SVG."""
    from django.http import Http404

    from metrology.core.procam.figures import coverage_svg

    calibration = calibration_selectors.get_procam_calibration(request.user, calibration_id)
    if device not in ("camera", "projector") or not calibration.report:
        raise Http404(f"procam calibration {calibration.pk} has no {device} coverage")
    return _svg(coverage_svg(calibration.report, device))


# ----------------------------------------------------------------------------- characterizations


@login_required
def characterization_list(request: HttpRequest) -> HttpResponse:
    return render(
        request,
        "dashboard/characterizations.html",
        {"characterizations": characterization_selectors.characterizations_for(request.user)[:200]},
    )


@login_required
@require_http_methods(["GET", "POST"])
def characterization_new(request: HttpRequest) -> HttpResponse:
    rig = _rig_from_query(request)
    if rig is None:
        return render(request, "dashboard/choose_rig.html", _choose_rig(request, "characterization"))
    initial = {"session": request.GET.get("session")} if request.GET.get("session") else None
    form = forms.CharacterizationForm(
        request.POST or None,
        initial=initial,
        captures=pages.ready_captures(request.user, rig),
        sessions=pages.stage_sessions(request.user, rig),
    )
    if request.method == "POST" and form.is_valid():
        data = form.cleaned_data
        try:
            characterization = characterization_services.request_characterization(
                owner=request.user,
                rig=rig,
                reference_id=data["reference"],
                session_id=data["session"],
                options={"n_points": data["n_points"], "rows": data["rows"]},
            )
        except SERVICE_ERRORS as exc:
            form.add_error(None, error_sentence(exc))
        else:
            return redirect("dashboard:characterization", characterization.pk)
    return render(
        request,
        "dashboard/characterization_new.html",
        {"rig": rig, "form": form, "can": rig_selectors.rig_capabilities(rig)},
        status=400 if request.method == "POST" else 200,
    )


@login_required
def characterization_detail(request: HttpRequest, characterization_id: int) -> HttpResponse:
    from metrology.figures.characterization import FIGURE_TITLES, characterization_figures, summary_rows

    characterization = characterization_selectors.get_characterization(request.user, characterization_id)
    done = characterization.job.status == "done"
    results = characterization.results or {}
    figures = characterization_figures(results) if done else {}
    return render(
        request,
        "dashboard/characterization.html",
        {
            "characterization": characterization,
            "job": characterization.job,
            "figures": [(key, FIGURE_TITLES[key], fig) for key, fig in figures.items()],
            "summary": summary_rows(results) if done else [],
            "rig_rows": rig_selectors.rig_value_rows(characterization.rig_values),
            "software_version": software_version(),
        },
    )


def _choose_rig(request: HttpRequest, what: str) -> dict:
    return {"rigs": rig_selectors.rigs_for(request.user), "what": what, "action": request.path}
