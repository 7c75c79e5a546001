"""Writes for measurements: request one (a queued job), compute it in a worker, publish atomically."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from django.core.files import File
from django.core.files.storage import default_storage
from django.db import transaction

from metrology.api_errors import BadInput
from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.captures.services import load_capture_stack
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.jobs.results import json_safe
from metrology.measurements.models import Measurement
from metrology.rigs.models import Rig

MESH_FORMATS = ("ply", "stl", "obj")


@transaction.atomic
def request_measurement(*, owner, rig: Rig, reference_id: int, object_id: int) -> Measurement:
    """Create a measurement of ``object`` against ``reference`` on ``rig`` and queue its job."""
    if reference_id == object_id:
        raise BadInput("object: the object capture must differ from the reference capture")
    reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    obj = capture_for_job(owner, rig, object_id, field="object")
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.MEASUREMENT,
        parameters={"rig": rig.pk, "reference": reference.pk, "object": obj.pk, "rig_values": rig.geometry()},
    )
    measurement = Measurement.objects.create(
        owner=owner, rig=rig, reference=reference, object=obj, job=job, rig_values=rig.geometry()
    )
    job.parameters["measurement"] = measurement.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return measurement


def run_measurement(job: Job, run: job_services.JobRun) -> None:
    """Job handler: decode both stacks, compute heights, write height map and meshes, publish."""
    from metrology.core.io import write_height_tiff
    from metrology.core.measure import height_statistics, measure_height
    from metrology.core.mesh import mesh_from_heights, write_mesh
    from metrology.core.rig import Rig as CoreRig

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    rig = CoreRig.from_dict(measurement.rig_values)
    with run.phase("read", 5):
        reference = load_capture_stack(measurement.reference)
        obj = load_capture_stack(measurement.object)
    with run.phase("measure", 20):
        result = measure_height(rig, reference.images, obj.images)
    for name, seconds in result.timings_s.items():
        run.timings[f"measure.{name}"] = round(float(seconds), 4)
    z_mm = np.asarray(result.z_mm, dtype=np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    names: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="gcps-measurement-") as tmp:
        folder = Path(tmp)
        with run.phase("write height", 50):
            np.save(folder / "height.npy", z_mm)
            write_height_tiff(z_mm, folder / "height.tiff")
            if result.gray_z_mm is not None:
                np.save(folder / "gray_only_height.npy", np.asarray(result.gray_z_mm, dtype=np.float32))
        with run.phase("mesh", 60):
            mesh = mesh_from_heights(rig, z_mm)
            for fmt in MESH_FORMATS:
                write_mesh(mesh, folder / f"mesh.{fmt}")
        with run.phase("store", 90):
            for path in sorted(folder.iterdir()):
                with path.open("rb") as handle:
                    names[path.name] = run.save_file(default_storage, f"{prefix}/{path.name}", File(handle))
    statistics = json_safe(result.statistics())
    if result.gray_z_mm is not None:
        statistics["gray_only"] = json_safe(height_statistics(np.asarray(result.gray_z_mm)))
    statistics["shape"] = list(z_mm.shape)
    start = time.perf_counter()

    def publish(_job: Job) -> None:
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names.get("height.npy", ""),
            height_tiff=names.get("height.tiff", ""),
            gray_only_npy=names.get("gray_only_height.npy", ""),
            mesh_ply=names.get("mesh.ply", ""),
            mesh_stl=names.get("mesh.stl", ""),
            mesh_obj=names.get("mesh.obj", ""),
            statistics=statistics,
        )

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
