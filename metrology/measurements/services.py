"""Writes for measurements: request one (a queued job), compute it in a worker, publish atomically."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from django.core.files.storage import default_storage
from django.db import transaction

from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.captures.services import load_capture_stack
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.stored_arrays import save_arrays, sigma_statistics
from metrology.pipeline.jsonsafe import json_safe
from metrology.rigs.models import Rig


def measure_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """The full pipeline options (defaults filled in) of a request's ``options`` object; BadInput naming a bad one."""
    from metrology.pipeline import MeasureOptions

    if options is not None and not isinstance(options, dict):
        raise BadInput(f"options must be an object, got {options!r}")
    try:
        return MeasureOptions.from_dict(options or {}).to_dict()
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from exc


@transaction.atomic
def request_measurement(
    *, owner, rig: Rig, reference_id: int | None, object_id: int, options: dict[str, Any] | None = None
) -> Measurement:
    """Create a measurement of ``object`` against ``reference`` on ``rig`` and queue its job.

    ``options``: :class:`metrology.pipeline.MeasureOptions` as an object (``{"decode": {...}}``);
    default the pipeline's defaults. Stored, with the defaults filled in, on the measurement.
    A pinhole rig's measurement (reference optional) is :mod:`metrology.measurements.pinhole`'s.
    """
    if rig.is_pinhole:  # codecapp: pinhole rigs
        from metrology.measurements.pinhole import request_pinhole_measurement

        return request_pinhole_measurement(
            owner=owner, rig=rig, reference_id=reference_id, object_id=object_id, options=options
        )
    if reference_id is None:
        raise BadInput("reference: a crossed-axes rig measures against a capture of the reference plane")
    checked = measure_options(options)
    if reference_id == object_id:
        raise BadInput("object: the object capture must differ from the reference capture")
    reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    obj = capture_for_job(owner, rig, object_id, field="object")
    from metrology.measurements.codecs import stacks_codec_value  # codecapp: the captures' codec

    codec = stacks_codec_value(reference, obj)
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.MEASUREMENT,
        parameters={
            "rig": rig.pk,
            "reference": reference.pk,
            "object": obj.pk,
            "rig_values": rig.geometry(),
            "codec": codec,
        },
    )
    measurement = Measurement.objects.create(
        owner=owner, rig=rig, reference=reference, object=obj, job=job, rig_values=rig.geometry(), options=checked
    )
    job.parameters["measurement"] = measurement.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return measurement


def run_measurement(job: Job, run: job_services.JobRun) -> None:
    """Job handler: the kept reference (decoded once per process), the object's stack, the pipeline's
    measure; store the height maps, publish.

    Stores ``height.npy`` and ``gray_only_height.npy`` (float32) and the statistics only; the
    TIFF and the meshes are derived on request (:mod:`metrology.measurements.derived`).
    """
    from metrology.captures.references import kept_reference
    from metrology.core.rig import Rig as CoreRig
    from metrology.pipeline import MeasureOptions, measure

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    from metrology.measurements.codecs import job_codec, run_codec_measurement  # codecapp

    if measurement.rig_values.get("model") == "pinhole":
        from metrology.measurements.pinhole import run_pinhole_measurement

        run_pinhole_measurement(job, run)
        return
    codec = job_codec(job)
    if codec is not None:  # captures of a codec other than gcps-v1
        run_codec_measurement(job, run, codec)
        return
    rig = CoreRig.from_dict(measurement.rig_values)
    options = MeasureOptions.from_dict(measurement.options or {})
    # a crossed-axes measurement always has one (request_measurement; the capture is PROTECTed)
    assert measurement.reference is not None, "a crossed-axes measurement without its reference capture"
    with run.phase("reference", 5):
        reference, _kept = kept_reference(measurement.reference, measurement.rig_values, options.decode)
    with run.phase("read", 10):
        obj = load_capture_stack(measurement.object)
    with run.phase("measure", 20):
        result = measure(rig, reference, obj.images, options)
    for name, seconds in result.timings_s.items():
        if name != "measure":
            run.timings[name] = round(float(seconds), 4)
    z_mm = np.asarray(result.z_mm, dtype=np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    arrays = {"height.npy": z_mm}
    if result.gray_z_mm is not None:
        arrays["gray_only_height.npy"] = np.asarray(result.gray_z_mm, dtype=np.float32)
    if result.sigma_mm is not None:  # options.sigma
        arrays["sigma.npy"] = np.asarray(result.sigma_mm, dtype=np.float32)
    with run.phase("store", 80):
        names = save_arrays(run, prefix, arrays)
    statistics = json_safe(result.statistics())
    statistics["shape"] = list(z_mm.shape)
    statistics.update(sigma_statistics(result.sigma_mm))

    def publish(job_row: Job) -> None:
        start = time.perf_counter()
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names.get("height.npy", ""),
            gray_only_npy=names.get("gray_only_height.npy", ""),
            sigma_npy=names.get("sigma.npy", ""),
            statistics=statistics,
            options=result.options.to_dict(),
        )
        job_row.software_version = result.software_version  # the code that computed it, not the requester's
        run.timings["publish"] = round(time.perf_counter() - start, 4)

    run.commit(publish)
    _remove_other_attempts(prefix)


def _remove_other_attempts(prefix: str) -> None:
    """Delete files that earlier, killed attempts left under sibling prefixes (never referenced)."""
    parent, _, mine = prefix.rpartition("/")
    try:
        folders, _files = default_storage.listdir(parent)
    except (OSError, NotImplementedError):
        return
    for folder in folders:
        if folder == mine:
            continue
        try:
            _sub, files = default_storage.listdir(f"{parent}/{folder}")
            for name in files:
                default_storage.delete(f"{parent}/{folder}/{name}")
            default_storage.delete(f"{parent}/{folder}")
        except OSError:
            continue
