"""Writes for measurements: request one (a queued job), compute it in a worker, publish atomically.

One request and one job handler for every geometric model and codec: the job reads the kept
reference (decoded once per worker process) and the object's stack in its codec's order, calls the
pipeline's :func:`~metrology.pipeline.measure.measure` (as ``gcps measure`` does), and stores
``height.npy`` (heights above the reference plane, or depths), the points (``(H, W, 3)``
float32 mm, the model frame, stored as the measured pixels' points and a bit mask, ``points.npz``:
:func:`~metrology.measurements.stored_arrays.save_point_map`) unless the heights alone give them (the paper's rig:
:attr:`~metrology.core.measure.Measurement.points_follow_from_heights`), and when computed
``gray_only_height.npy`` and ``sigma.npy``, and for a multi-exposure object ``exposure.npy`` (uint8
``(H, W)``: the exposure that measured each point, 255 none; the statistics count the points per
exposure, ``points_per_exposure``), and for a stereo rig ``pairs.npy`` (uint8 ``(H, W)``: the pairs of
devices that measured each point, bits as docs/stereo.md says, 0 none; the statistics count the points
per combination, ``points_per_pairs``); the TIFF, the meshes and points the heights give are
derived on request (:mod:`metrology.measurements.derived`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from django.db import transaction

from metrology.captures.codecs import captures_codec_value, codec_of
from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.captures.stacks import load_capture_images
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.signals import measurement_done
from metrology.measurements.stored_arrays import (
    remove_other_attempts,
    save_arrays,
    save_point_map,
    sigma_statistics,
)
from metrology.pipeline.jsonsafe import json_safe
from metrology.rigs.models import Rig


def measure_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """The full pipeline options (defaults filled in) of a request's ``options`` object; BadInput naming a bad one."""
    from metrology.core.measure import MeasureOptions

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
    """Create a measurement of ``object`` (against ``reference`` when given) on ``rig`` and queue its job.

    ``options``: :class:`metrology.core.measure.MeasureOptions` as an object (``{"decode": {...},
    "triangulate": ...}``); default the pipeline's defaults. Stored, with the defaults filled in, on
    the measurement. A reference is required where the rig's model measures against one; both
    captures must share one codec that the model can measure with.
    """
    checked = measure_options(options)
    model = rig.to_core()
    if reference_id is None and model.requires_reference:
        raise BadInput(f"reference: a {model.short_label} rig measures against a capture of the reference plane")
    if reference_id is not None and reference_id == object_id:
        raise BadInput("object: the object capture must differ from the reference capture")
    reference = None
    if reference_id is not None:
        reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    obj = capture_for_job(owner, rig, object_id, field="object")
    codec = captures_codec_value(model, reference, obj)
    rig_values = rig.rig_file()
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.MEASUREMENT,
        parameters={
            "rig": rig.pk,
            "reference": None if reference is None else reference.pk,
            "object": obj.pk,
            "rig_values": rig_values,
            "codec": codec,
        },
    )
    measurement = Measurement.objects.create(
        owner=owner, rig=rig, reference=reference, object=obj, job=job, rig_values=rig_values, options=checked
    )
    job.parameters["measurement"] = measurement.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return measurement


def run_measurement(job: Job, run: job_services.JobRun) -> None:
    """Job handler: the kept reference, the object's stack, the pipeline's measure; store, publish."""
    from metrology.captures.references import kept_reference
    from metrology.core.geometry import model_from_dict
    from metrology.core.measure import MeasureOptions, as_exposures
    from metrology.pipeline.measure import measure

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    model = model_from_dict(measurement.rig_values)
    options = MeasureOptions.from_dict(measurement.options or {})
    codec_value = job.parameters.get("codec")
    codec = None if codec_value is None else codec_of(codec_value)
    captures = [c for c in (measurement.reference, measurement.object) if c is not None]
    exposures = any(c.exposures for c in captures)
    if exposures and codec is None:  # a multi-exposure capture takes both through the codec path
        from metrology.core.codecs.model import gcps_v1_codec

        codec = gcps_v1_codec()
    reference = None
    if measurement.reference is not None:
        with run.phase("reference", 5):
            reference, _kept = kept_reference(
                measurement.reference, measurement.rig_values, codec, options, exposures=exposures
            )
    with run.phase("read", 10):
        obj = load_capture_images(measurement.object)
    if exposures:  # against a multi-exposure reference a single stack is one exposure (per camera)
        obj = as_exposures(obj)
    with run.phase("measure", 20):
        result = measure(model, reference, obj, options, codec=codec)
    for name, seconds in result.timings_s.items():
        if name != "measure":
            run.timings[name] = round(float(seconds), 4)
    z_mm = np.asarray(result.z_mm, dtype=np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    arrays = {"height.npy": z_mm}
    points = None if result.measurement.points_follow_from_heights else result.points_mm()  # else derived
    if result.gray_z_mm is not None:
        arrays["gray_only_height.npy"] = np.asarray(result.gray_z_mm, dtype=np.float32)
    if result.sigma_mm is not None:  # options.sigma
        arrays["sigma.npy"] = np.asarray(result.sigma_mm, dtype=np.float32)
    exposure = result.measurement.exposure_map()
    if exposure is not None:  # a multi-exposure object: which exposure measured each point
        arrays["exposure.npy"] = exposure
    pairs = result.measurement.pairs_map()
    if pairs is not None:  # a stereo rig: which pairs of devices measured each point
        arrays["pairs.npy"] = pairs
    with run.phase("store", 80):
        names = save_arrays(run, prefix, arrays)
        if points is not None:
            names["points.npy"] = save_point_map(run, prefix, points)
    data = result.to_dict()
    statistics = json_safe(data["statistics"])
    statistics["shape"] = list(z_mm.shape)
    statistics.update(sigma_statistics(result.sigma_mm))
    statistics["codec"] = json_safe(codec_value) if codec_value is not None else result.codec_name
    statistics["reference_plane"] = json_safe(data["reference_plane"])
    if "decoding" in data:
        statistics["decoding"] = json_safe(data["decoding"])
    statistics["codec_check"] = json_safe(data["codec_check"])  # the object's codec self-check

    def publish(job_row: Job) -> None:
        start = time.perf_counter()
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names["height.npy"],
            points_npy=names.get("points.npy", ""),
            gray_only_npy=names.get("gray_only_height.npy", ""),
            sigma_npy=names.get("sigma.npy", ""),
            exposure_npy=names.get("exposure.npy", ""),
            pairs_npy=names.get("pairs.npy", ""),
            statistics=statistics,
            options=result.options.to_dict(),
        )
        job_row.software_version = result.software_version  # the code that computed it, not the requester's
        run.timings["publish"] = round(time.perf_counter() - start, 4)

    run.commit(publish)
    remove_other_attempts(prefix)
    measurement_done.send(sender=Measurement, measurement=Measurement.objects.get(pk=measurement.pk))


def request_derived_file(measurement: Measurement, filename: str) -> Job:
    """The job that builds the derived file ``filename`` of ``measurement``: the one queued or running
    for it already, else a new one, queued (``Job.Kind.DERIVED_FILE``, owned by the measurement's owner).

    Raises :class:`BadInput` when ``filename`` is not derived for this measurement.
    """
    from metrology.measurements import derived

    if not derived.is_derived(measurement, filename):
        raise BadInput(f"{filename} of measurement {measurement.pk} is not built from its results")
    parameters = {
        "measurement": measurement.pk,
        "filename": filename,
        "name": derived.derived_name(measurement, filename),
    }
    with transaction.atomic():
        # one job per file at a time: concurrent requests for the same file wait on this row lock
        Measurement.objects.select_for_update().filter(pk=measurement.pk).first()
        pending = (
            Job.objects.filter(
                kind=Job.Kind.DERIVED_FILE,
                status__in=(Job.Status.QUEUED, Job.Status.RUNNING),
                parameters__measurement=measurement.pk,
                parameters__name=parameters["name"],
            )
            .order_by("pk")
            .first()
        )
        if pending is not None:
            return pending
        job = job_services.create_job(owner=measurement.owner, kind=Job.Kind.DERIVED_FILE, parameters=parameters)
        job_services.enqueue_job(job)
    job.refresh_from_db()
    return job


def run_derived_file(job: Job, run: job_services.JobRun) -> None:
    """Job handler: build one derived file of a measurement and store it (:func:`derived.build_derived_file`)."""
    from metrology.measurements import derived

    measurement = Measurement.objects.get(pk=job.parameters["measurement"])
    with run.phase("build", 10):
        derived.build_derived_file(measurement, job.parameters["filename"], save=run.save_file)
    run.commit(lambda _job: None)
