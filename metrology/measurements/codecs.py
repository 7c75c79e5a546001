"""Measurements of captures of a codec other than gcps-v1 (docs/codecs.md): the codec both captures
share, and the job handler's branch that decodes them with the codec decoder.

gcps-v1 measurements keep the handler of :mod:`metrology.measurements.services` unchanged; a
measurement whose captures have another codec (coding the projector's u axis) is computed here
by the same pipeline function, :func:`metrology.pipeline.measure`, with ``codec=``, and stored
the same way (height map, TIFF, meshes, statistics), the statistics holding the codec and the
decoding summary (pixels per reason, repaired slips, the validity rules used).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from django.core.files import File
from django.core.files.storage import default_storage

from metrology.api_errors import BadInput
from metrology.captures.codecs import capture_codec_value, codec_of, is_gcps_v1
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.jobs.results import json_safe
from metrology.measurements.models import Measurement

MESH_FORMATS = ("ply", "stl", "obj")


def stacks_codec_value(reference: Any, obj: Any) -> Any:
    """The stored codec value both captures share (each its own, else its rig's default).

    Raises
    ------
    BadInput
        When they differ, or when the codec does not code the projector's u axis.
    """
    ref_value, obj_value = capture_codec_value(reference), capture_codec_value(obj)
    ref_codec, obj_codec = codec_of(ref_value), codec_of(obj_value)
    if ref_codec != obj_codec or ref_codec.name != obj_codec.name:
        raise BadInput(
            f"object: capture {obj.pk} has another codec than the reference capture {reference.pk} "
            "(both captures of a measurement must use one codec)"
        )
    if "u" not in obj_codec.axes:
        raise BadInput(f"object: the codec of capture {obj.pk} does not code the projector's u axis")
    return obj_value


def job_codec(job: Job) -> Any:
    """The :class:`~metrology.core.codecs.model.Codec` of a measurement job when it is not gcps-v1, else None."""
    value = job.parameters.get("codec")
    if value is None:
        return None
    codec = codec_of(value)
    return None if is_gcps_v1(codec) else codec


def run_codec_measurement(job: Job, run: job_services.JobRun, codec: Any) -> None:
    """Job handler for captures of ``codec``: read both stacks in codec order, the pipeline's measure,
    write height map, TIFF and meshes, publish (as the gcps-v1 handler does)."""
    from metrology.captures.codecs import load_codec_stack
    from metrology.core.io import write_height_tiff
    from metrology.core.mesh import mesh_from_heights, write_mesh
    from metrology.core.rig import Rig as CoreRig
    from metrology.pipeline import MeasureOptions, measure

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    rig = CoreRig.from_dict(measurement.rig_values)
    options = MeasureOptions.from_dict(measurement.options or {})
    with run.phase("read", 5):
        reference = load_codec_stack(measurement.reference)
        obj = load_codec_stack(measurement.object)
    with run.phase("measure", 20):
        result = measure(rig, reference.images, obj.images, options, codec=codec)
    for name, seconds in result.timings_s.items():
        if name != "measure":
            run.timings[name] = round(float(seconds), 4)
    z_mm = np.asarray(result.z_mm, dtype=np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    names: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="gcps-measurement-") as tmp:
        folder = Path(tmp)
        with run.phase("write height", 50):
            np.save(folder / "height.npy", z_mm)
            write_height_tiff(z_mm, folder / "height.tiff")
        with run.phase("mesh", 60):
            mesh = mesh_from_heights(rig, z_mm)
            for fmt in MESH_FORMATS:
                write_mesh(mesh, folder / f"mesh.{fmt}")
        with run.phase("store", 90):
            for path in sorted(folder.iterdir()):
                with path.open("rb") as handle:
                    names[path.name] = run.save_file(default_storage, f"{prefix}/{path.name}", File(handle))
    statistics = json_safe(result.statistics())
    statistics["shape"] = list(z_mm.shape)
    statistics["codec"] = json.loads(json.dumps(job.parameters.get("codec")))
    if result.decoding is not None:
        statistics["decoding"] = json_safe(result.decoding.summary())

    def publish(job_row: Job) -> None:
        start = time.perf_counter()
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names.get("height.npy", ""),
            height_tiff=names.get("height.tiff", ""),
            gray_only_npy="",
            mesh_ply=names.get("mesh.ply", ""),
            mesh_stl=names.get("mesh.stl", ""),
            mesh_obj=names.get("mesh.obj", ""),
            statistics=statistics,
            options=result.options.to_dict(),
        )
        job_row.software_version = result.software_version
        run.timings["publish"] = round(time.perf_counter() - start, 4)

    run.commit(publish)
