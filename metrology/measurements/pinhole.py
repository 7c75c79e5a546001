"""Measurements with a pinhole rig (docs/pinhole.md): request (the reference is optional), the job
handler through the pipeline's :func:`~metrology.pipeline.measure_pinhole.measure_pinhole_stacks`,
and the meshes of the stored camera-frame points.

Stored: ``height.npy`` (depth, camera Z, without a reference; height above the reference plate
with one; mm), ``points.npy`` (``(H, W, 3)`` float32 mm, camera frame) and, with
``options.sigma``, ``sigma.npy``; the statistics hold what z is, the axis triangulated, the
codec, the decoding summary and the reference plane; ``rig_values`` the pinhole rig file used.
"""

from __future__ import annotations

import io
import json
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from django.db import transaction

from metrology.captures.codecs import capture_codec_value, codec_of
from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.stored_arrays import save_arrays
from metrology.pipeline.jsonsafe import json_safe


def pinhole_options(options: Any) -> dict[str, Any]:
    """The full pinhole options (defaults filled in) of a request; BadInput naming a bad one."""
    from metrology.pipeline.measure_pinhole import PinholeMeasureOptions

    if options is not None and not isinstance(options, dict):
        raise BadInput(f"options must be an object, got {options!r}")
    try:
        return PinholeMeasureOptions.from_dict(options or {}).to_dict()
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from exc


@transaction.atomic
def request_pinhole_measurement(
    *, owner, rig: Any, reference_id: int | None, object_id: int, options: dict[str, Any] | None = None
) -> Measurement:
    """Create a measurement of ``object`` (against ``reference`` when given) on a pinhole rig; queue its job."""
    checked = pinhole_options(options)
    if reference_id is not None and reference_id == object_id:
        raise BadInput("object: the object capture must differ from the reference capture")
    reference = None
    if reference_id is not None:
        reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    obj = capture_for_job(owner, rig, object_id, field="object")
    codec = capture_codec_value(obj)
    if reference is not None and codec_of(capture_codec_value(reference)) != codec_of(codec):
        raise BadInput(
            f"object: capture {obj.pk} has another codec than the reference capture {reference.pk} "
            "(both captures of a measurement must use one codec)"
        )
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


def run_pinhole_measurement(job: Job, run: job_services.JobRun) -> None:
    """Job handler: both stacks in codec order, the pipeline's pinhole measurement, store, publish."""
    from metrology.captures.codecs import load_codec_stack
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.measurements.services import _remove_other_attempts
    from metrology.pipeline.measure_pinhole import PinholeMeasureOptions, measure_pinhole_stacks

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    rig = PinholeRig.from_dict(measurement.rig_values)
    options = PinholeMeasureOptions.from_dict(measurement.options or {})
    with run.phase("read", 5):
        obj = load_codec_stack(measurement.object)
        reference = load_codec_stack(measurement.reference) if measurement.reference_id else None
    with run.phase("measure", 20):
        result = measure_pinhole_stacks(
            rig, None if reference is None else reference.images, obj.images, obj.codec, options
        )
    for name, seconds in result.timings_s.items():
        if name != "measure":
            run.timings[name] = round(float(seconds), 4)
    arrays = {"height.npy": result.z_mm.astype(np.float32), "points.npy": result.points_mm.astype(np.float32)}
    if result.sigma_mm is not None:
        arrays["sigma.npy"] = result.sigma_mm.astype(np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    with run.phase("store", 80):
        names = save_arrays(run, prefix, arrays)
    data = result.to_dict()
    statistics = json_safe(data["statistics"])
    statistics["shape"] = list(result.z_mm.shape)
    statistics["codec"] = json.loads(json.dumps(job.parameters.get("codec")))
    statistics["decoding"] = json_safe(data["decoding"])
    statistics["reference_plane"] = json_safe(data["reference_plane"])

    def publish(job_row: Job) -> None:
        start = time.perf_counter()
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names["height.npy"],
            points_npy=names["points.npy"],
            gray_only_npy="",
            sigma_npy=names.get("sigma.npy", ""),
            statistics=statistics,
            options=result.options.to_dict(),
        )
        job_row.software_version = result.software_version
        run.timings["publish"] = round(time.perf_counter() - start, 4)

    run.commit(publish)
    _remove_other_attempts(prefix)


def load_points(measurement: Measurement) -> np.ndarray | None:
    """The stored camera-frame points ``(H, W, 3)`` of a pinhole measurement, or None."""
    if not measurement.points_npy:
        return None
    with measurement.points_npy.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def pinhole_mesh_chunks(measurement: Measurement, fmt: str) -> Iterator[bytes]:
    """The mesh file (``ply``, ``stl`` or ``obj``) of a pinhole measurement's points, camera frame, as chunks."""
    from metrology.commands.measure_pinhole import _mesh
    from metrology.core.mesh import write_mesh

    def chunks() -> Iterator[bytes]:
        points = load_points(measurement)
        if points is None:
            raise ValueError(f"measurement {measurement.pk} has no stored points")
        with tempfile.TemporaryDirectory(prefix="gcps-pinhole-mesh-") as tmp:
            path = Path(tmp) / f"mesh.{fmt}"
            write_mesh(_mesh(points), path)
            data = path.read_bytes()
        for start in range(0, len(data), 1 << 20):
            yield data[start : start + (1 << 20)]

    return chunks()
