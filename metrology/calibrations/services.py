"""Writes for calibrations: request (a queued job), compute in a worker, publish, apply to the rig."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from django.core.files import File
from django.core.files.storage import default_storage
from django.db import transaction
from django.utils import timezone

from metrology.calibrations.models import Calibration
from metrology.captures.codecs import captures_codec_value, codec_of
from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.captures.stacks import load_capture_images
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.pipeline.jsonsafe import json_safe
from metrology.rigs.models import Rig, RigParameters
from metrology.rigs.services import history_values, require_capability, update_rig_parameters, validate_model

# Options each method accepts (passed to metrology.core.calibrate), with their types.
METHOD_OPTIONS: dict[str, dict[str, type]] = {
    "paper": {"delta_z_mm": float, "m_hat": float, "w": float, "max_iterations": int},
    "lsq": {"fit_d": bool, "use_floor": bool, "max_iterations": int, "tolerance": float},
}


def _check_options(method: str, options: dict[str, Any]) -> dict[str, Any]:
    allowed = METHOD_OPTIONS[method]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise BadInput(
            f"options: method {method!r} has no option {', '.join(unknown)}; it accepts {', '.join(allowed)}"
        )
    checked: dict[str, Any] = {}
    for name, value in options.items():
        kind = allowed[name]
        if value is None and name == "w":
            checked[name] = None
            continue
        if kind is bool:
            if not isinstance(value, bool):
                raise BadInput(f"options.{name} must be true or false, got {value!r}")
        elif kind is int:
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 1000:
                raise BadInput(f"options.{name} must be an integer in [1, 1000], got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise BadInput(f"options.{name} must be a finite number, got {value!r}")
        elif name != "w" and value <= 0:
            raise BadInput(f"options.{name} must be positive, got {value!r}")
        checked[name] = value
    return checked


@transaction.atomic
def request_calibration(
    *,
    owner,
    rig: Rig,
    reference_id: int,
    master_id: int,
    master_height_mm: float,
    method: str = "lsq",
    initial: dict[str, float] | None = None,
    options: dict[str, Any] | None = None,
    apply: bool = False,
) -> Calibration:
    """Create a calibration of ``rig`` on a master block and queue its job.

    ``initial``: starting values of the parameters the paper's calibration adjusts (the model's
    :attr:`~metrology.core.geometry.base.GeometryModel.calibration_parameters`: L, alpha, d);
    default the rig's. The captures share one codec (their own, else the rig's default).
    """
    model = rig.to_core()
    adjustable = model.calibration_parameters
    require_capability(
        rig, bool(adjustable), "the paper's calibration adjusts L and alpha", "calibrate it from board poses"
    )
    method = str(getattr(method, "value", method))
    if method not in METHOD_OPTIONS:
        raise BadInput(f"method must be one of {', '.join(METHOD_OPTIONS)}, got {method!r}")
    if not math.isfinite(master_height_mm) or master_height_mm <= 0:
        raise BadInput(f"master_height_mm must be a positive number of millimetres, got {master_height_mm}")
    initial = dict(initial or {})
    unknown = sorted(set(initial) - set(adjustable))
    if unknown:
        raise BadInput(f"initial: unknown key(s) {', '.join(unknown)}; accepted: {', '.join(adjustable)}")
    start = history_values(validate_model({**rig.rig_file(), **initial}))
    options = _check_options(method, dict(options or {}))
    used = _pipeline_options(method, master_height_mm, options).to_dict()
    if reference_id == master_id:
        raise BadInput("master: the master capture must differ from the reference capture")
    reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    master = capture_for_job(owner, rig, master_id, field="master", roles=(Capture.Role.MASTER, Capture.Role.OBJECT))
    codec = captures_codec_value(model, reference, master, what="master")
    parameters = {"initial": start, "options": options, "master_height_mm": master_height_mm, "method": method}
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.CALIBRATION,
        parameters={"rig": rig.pk, "reference": reference.pk, "master": master.pk, "codec": codec, **parameters},
    )
    calibration = Calibration.objects.create(
        owner=owner,
        rig=rig,
        reference=reference,
        master=master,
        master_height_mm=master_height_mm,
        method=method,
        parameters=parameters,
        rig_values=rig.rig_file(),
        options=used,
        apply=apply,
        job=job,
    )
    job.parameters["calibration"] = calibration.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return calibration


def _pipeline_options(method: str, master_height_mm: float, options: dict[str, Any]) -> Any:
    """:class:`metrology.pipeline.CalibrateOptions` of a request (BadInput naming a bad value)."""
    from metrology.pipeline.calibrate import CalibrateOptions

    try:
        return CalibrateOptions(master_height_mm=master_height_mm, method=method, **options)
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from exc


def run_calibration(job: Job, run: job_services.JobRun) -> None:
    """Job handler: load reference and master, call the pipeline's calibrate, publish (and apply if asked)."""
    from metrology.core.geometry import model_from_dict
    from metrology.pipeline.calibrate import CalibrateOptions, calibrate

    calibration = Calibration.objects.select_related("reference__rig", "master__rig", "rig").get(job=job)
    start_rig = model_from_dict(calibration.parameters["initial"])
    codec_value = job.parameters.get("codec")
    codec = None if codec_value is None else codec_of(codec_value)
    if calibration.options:
        options = CalibrateOptions.from_dict(calibration.options)
    else:  # requested before options were stored
        options = _pipeline_options(
            calibration.method, calibration.master_height_mm, dict(calibration.parameters.get("options") or {})
        )
    with run.phase("read", 5):
        reference = load_capture_images(calibration.reference)
        master = load_capture_images(calibration.master)
    with run.phase("calibrate", 15):
        outcome = calibrate(start_rig, reference, [master], options, codec=codec)
    for name, seconds in outcome.timings_s.items():
        run.timings[f"calibrate.{name}"] = round(float(seconds), 4)
    result = outcome.calibration
    summary = json_safe(result.to_dict())
    iterations = summary.pop("history", [])
    residual_name = ""
    if result.residual_mm is not None:
        with run.phase("store", 90), tempfile.TemporaryDirectory(prefix="gcps-calibration-") as tmp:
            path = Path(tmp) / "residual.npy"
            np.save(path, np.asarray(result.residual_mm, dtype=np.float32))
            with path.open("rb") as handle:
                residual_name = run.save_file(
                    default_storage, f"calibrations/{calibration.pk}/{run.token.hex}/residual.npy", File(handle)
                )

    def publish(job_row: Job) -> None:
        Calibration.objects.filter(pk=calibration.pk).update(
            iterations=iterations, result=summary, residual_npy=residual_name, options=outcome.options.to_dict()
        )
        job_row.software_version = outcome.software_version  # the code that computed it
        if calibration.apply:
            apply_calibration(calibration=Calibration.objects.get(pk=calibration.pk), require_done=False)

    run.commit(publish)


@transaction.atomic
def apply_calibration(*, calibration: Calibration, require_done: bool = True) -> Calibration:
    """Set the rig's calibrated parameters (L, alpha, and d if fitted) to the calibration's result;
    recorded in the rig's history."""
    calibration = Calibration.objects.select_for_update().select_related("job", "rig").get(pk=calibration.pk)
    if require_done and calibration.job.status != Job.Status.DONE:
        raise BadInput(f"calibration {calibration.pk} cannot be applied: its job is {calibration.job.status}")
    if calibration.applied:
        return calibration
    result = calibration.result
    adjustable = calibration.rig.to_core().calibration_parameters
    changes = {key: result[key] for key in adjustable if isinstance(result.get(key), int | float)}
    if not changes:
        raise BadInput(f"calibration {calibration.pk} has no calibrated values to apply to its rig's model")
    update_rig_parameters(
        rig=calibration.rig, changes=changes, source=RigParameters.Source.CALIBRATION, calibration=calibration
    )
    calibration.applied = True
    calibration.applied_at = timezone.now()
    calibration.save(update_fields=["applied", "applied_at"])
    return calibration
