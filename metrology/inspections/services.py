"""Writes for inspections: store a nominal model, request an inspection (a queued job), compute it in a
worker, keep a rig's inspection plan and apply it to each new measurement of the rig.

A nominal model is a mesh file (STL, PLY, OBJ) or a STEP file; a STEP file is read by the same core
reader as ``gcps inspect`` (:func:`~metrology.core.inspection.nominal.read_nominal`, tessellated at its
recorded tolerance) once, at upload, and its triangles are stored beside it as a binary PLY that the
jobs read as they read an uploaded mesh.

One request and one job handler for every geometric model: the job reads the measurement's points
(``(H, W, 3)`` float32 mm in the model frame, :func:`metrology.measurements.derived.measurement_points`)
and, when the measurement computed them, its per-point sigmas, and calls the pipeline's
:func:`~metrology.pipeline.inspect.inspect`, as ``gcps inspect`` does; it stores the
``gcps-inspection/1`` report and ``deviations.npy`` (``(H, W)`` float32 mm, NaN where no point).
"""

from __future__ import annotations

import hashlib
import io
import math
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any
from uuid import uuid4

import numpy as np
from django.conf import settings
from django.core.files import File
from django.core.files.storage import default_storage
from django.db import transaction

from metrology.core.io.meshes import triangle_mesh_ply_bytes
from metrology.core.io.step import STEP_SUFFIXES, ocp_available
from metrology.errors import BadInput, Conflict
from metrology.inspections.models import Inspection, InspectionPlan, NominalModel
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.pipeline.jsonsafe import json_safe

NOMINAL_FORMATS: tuple[str, ...] = ("stl", "ply", "obj", "step", "stp")
"""File name extensions a nominal model may have: the mesh readers of metrology.core.io.meshes and STEP
(metrology.core.io.step, where cadquery-ocp is installed)."""
STEP_FORMATS: tuple[str, ...] = tuple(suffix.lstrip(".") for suffix in STEP_SUFFIXES)
STEP_EXTRA = "pip install 'gcps-lab[step]' (cadquery-ocp)"


def _suffix(name: str) -> str:
    suffix = Path(name).suffix.lower().lstrip(".")
    if suffix not in NOMINAL_FORMATS:
        raise BadInput(f"file: a nominal model must be .stl, .ply, .obj, .step or .stp, got {name!r}")
    return suffix


def _read_nominal_file(path: Path, name: str) -> Any:
    """The validated :class:`~metrology.core.inspection.nominal.NominalModel` at ``path``; BadInput naming the file."""
    from metrology.core.inspection.nominal import read_nominal

    try:
        return read_nominal(path)
    except (OSError, ValueError) as exc:
        raise BadInput(f"file: {name}: {exc}") from exc


def upload_nominal(
    *, owner, upload, name: str | None = None, step_reader_available: Callable[[], bool] = ocp_available
) -> NominalModel:
    """Validate an uploaded mesh (STL, PLY or OBJ, mm) or STEP file and store it as a nominal model.

    A STEP file (``.step``, ``.stp``) is tessellated by the core reader at its default tolerances
    (:mod:`metrology.core.io.step`, recorded in ``tessellation``) and the triangles kept, outward and
    merged as :func:`~metrology.core.inspection.nominal.nominal_from_arrays` left them, as a binary PLY
    in ``mesh_file``; ``file``, ``sha256`` and ``size_bytes`` are the STEP file's, ``file_format`` is
    ``"step"``. ``step_reader_available`` says whether this server can read STEP (default: whether
    ``cadquery-ocp`` imports).

    Raises
    ------
    BadInput
        Naming the problem (size, format, an empty or unreadable file, STEP on a server without
        ``cadquery-ocp``: naming the extra to install); nothing is stored.
    """
    limit = settings.GCPS_MAX_UPLOAD_BYTES
    if upload.size is not None and upload.size > limit:
        raise BadInput(f"upload of {upload.size} bytes exceeds the limit of {limit} bytes (GCPS_MAX_UPLOAD_BYTES)")
    filename = Path(upload.name or "nominal").name
    suffix = _suffix(filename)
    is_step = suffix in STEP_FORMATS
    if is_step and not step_reader_available():
        raise BadInput(
            f"file: {filename}: this server cannot read STEP files: OpenCASCADE is not installed ({STEP_EXTRA}); "
            "upload the part as STL, PLY or OBJ, or ask the administrator to install the extra"
        )
    upload.seek(0)
    digest = hashlib.sha256()
    size = 0
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"nominal.{suffix}"
        with path.open("wb") as out:
            for chunk in upload.chunks():
                digest.update(chunk)
                size += len(chunk)
                out.write(chunk)
        nominal = _read_nominal_file(path, filename)
        summary = json_safe(nominal.summary())
        folder_name = f"nominals/{uuid4().hex}"
        with path.open("rb") as stored_file:
            stored = default_storage.save(f"{folder_name}/{filename}", File(stored_file, name=filename))
    mesh = ""
    try:
        if is_step:
            mesh_bytes = triangle_mesh_ply_bytes(nominal.vertices, nominal.faces)
            mesh_name = f"{Path(filename).stem}.tessellated.ply"
            mesh = default_storage.save(f"{folder_name}/{mesh_name}", File(io.BytesIO(mesh_bytes), name=mesh_name))
        return NominalModel.objects.create(
            owner=owner,
            name=(name or Path(filename).stem)[:200],
            file=stored,
            file_format="step" if is_step else suffix,
            mesh_file=mesh,
            tessellation=None if nominal.tessellation is None else json_safe(dict(nominal.tessellation)),
            sha256=digest.hexdigest(),
            size_bytes=size,
            triangle_count=int(nominal.triangle_count),
            units=str(nominal.units),
            summary=summary,
        )
    except Exception:
        for name_stored in (stored, mesh):
            if name_stored:
                default_storage.delete(name_stored)
        raise


def delete_nominal(nominal: NominalModel) -> None:
    """Delete a nominal model and its file; Conflict while an inspection or a plan uses it."""
    if nominal.inspections.exists() or nominal.plans.exists():
        raise Conflict(f"nominal model {nominal.pk} is used by inspections or an inspection plan; delete those first")
    names = [nominal.file.name, nominal.mesh_file.name]
    nominal.delete()
    for name in names:
        if name:
            default_storage.delete(name)


def inspect_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """The full inspection options (defaults filled in) of a request's ``options``; BadInput naming a bad one."""
    from metrology.pipeline.inspect import InspectOptions

    if options is not None and not isinstance(options, dict):
        raise BadInput(f"options must be an object, got {options!r}")
    try:
        return InspectOptions.from_dict(options or {}).to_dict()
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from exc


@transaction.atomic
def request_inspection(
    *,
    owner,
    measurement: Measurement,
    nominal: NominalModel,
    options: dict[str, Any] | None = None,
    plan: InspectionPlan | None = None,
) -> Inspection:
    """Create an inspection of ``measurement`` against ``nominal`` and queue its job.

    Raises
    ------
    BadInput
        The measurement is not done, or an option is bad.
    """
    if measurement.job.status != Job.Status.DONE:
        raise BadInput(f"measurement: measurement {measurement.pk} is {measurement.job.status}, not done")
    options = dict(options or {})
    if "systematic_mm" in options:
        systematic = {"mm": options["systematic_mm"], "from": "the request"}
    else:  # the rig's own figure, recorded
        value, origin = systematic_term_mm(measurement)
        options["systematic_mm"] = value
        systematic = {"mm": value, "from": origin}
    used = inspect_options(options)
    parameters = {"measurement": measurement.pk, "nominal": nominal.pk, "systematic": systematic}
    job = job_services.create_job(owner=owner, kind=Job.Kind.INSPECTION, parameters=parameters)
    inspection = Inspection.objects.create(
        owner=owner, measurement=measurement, nominal=nominal, plan=plan, options=used, job=job
    )
    job.parameters["inspection"] = inspection.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return inspection


def systematic_term_mm(measurement: Measurement) -> tuple[float, str]:
    """The rig's systematic term and where it comes from: the magnitude of the overall mean error of
    its latest finished characterization (paper section 5), else 0 ("none")."""
    from metrology.characterizations.selectors import characterizations_of_rig

    latest = characterizations_of_rig(measurement.rig).filter(overall_mean_error_mm__isnull=False).first()
    if latest is None or latest.overall_mean_error_mm is None or not math.isfinite(latest.overall_mean_error_mm):
        return 0.0, "none"
    return abs(float(latest.overall_mean_error_mm)), f"characterization {latest.pk}"


def _load_array(field) -> np.ndarray:
    with field.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def run_inspection(job: Job, run: job_services.JobRun) -> None:
    """Job handler: the measurement's points (and sigmas), the nominal mesh, the pipeline's inspect; store, publish."""
    from metrology.measurements.derived import measurement_points

    inspection = Inspection.objects.select_related("measurement__rig", "nominal").get(job=job)
    measurement = inspection.measurement
    with run.phase("read", 5):
        points = np.asarray(measurement_points(measurement), dtype=np.float64)
        sigma = _load_array(measurement.sigma_npy) if measurement.sigma_npy else None
        mesh, mesh_format = inspection.nominal.mesh
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / f"nominal.{mesh_format}"
            with mesh.open("rb") as source, path.open("wb") as out:
                out.write(source.read())
            nominal = _read_nominal_file(path, inspection.nominal.name)
    if sigma is not None and sigma.shape != points.shape[:2]:
        raise job_services.JobFailedError(f"sigma.npy is {sigma.shape}, the points {points.shape[:2]}")
    with run.phase("inspect", 15):
        result = _inspect(nominal, points, sigma, inspection)
    provenance = {
        "nominal": {
            "id": inspection.nominal.pk,
            "sha256": inspection.nominal.sha256,
            "units": nominal.units,
            "format": inspection.nominal.file_format,
            **({"tessellation": inspection.nominal.tessellation} if inspection.nominal.tessellation else {}),
        },
        "scan": {"measurement": measurement.pk, "software_version": measurement.job.software_version},
        "rig": {"id": measurement.rig_id, "values": measurement.rig_values},
        "systematic": job.parameters.get("systematic") or {"mm": 0.0, "from": "none"},
    }
    report = json_safe(result.report(provenance))
    prefix = f"inspections/{inspection.pk}/{run.token.hex}"
    with run.phase("store", 90):
        buffer = io.BytesIO()
        np.save(buffer, np.asarray(result.deviation_map(), dtype=np.float32))
        buffer.seek(0)
        stored = run.save_file(default_storage, f"{prefix}/deviations.npy", File(buffer, name="deviations.npy"))
    for name, seconds in result.timings_s.items():
        run.timings[f"inspect.{name}"] = round(float(seconds), 4)

    def publish(job_row: Job) -> None:
        Inspection.objects.filter(pk=inspection.pk).update(report=report, deviations_npy=stored)
        job_row.software_version = result.software_version

    run.commit(publish)


def _inspect(nominal: Any, points: np.ndarray, sigma: np.ndarray | None, inspection: Inspection) -> Any:
    """The pipeline's inspection of a measurement's point map (``(H, W, 3)`` mm) and sigma map.

    The stored sigma is the model's (:attr:`~metrology.core.geometry.GeometryModel.sigma_direction`):
    along the camera ray for a calibrated rig, along the height for the paper's rig, whose camera
    looks down on the scene; both are taken along the ray from the camera's centre (for the paper's
    rig an approximation by the cosine of the ray's angle to the vertical, at most a few per cent
    across its field)."""
    from metrology.core.geometry import model_from_dict
    from metrology.core.inspection.scan import Scan
    from metrology.pipeline.inspect import InspectOptions, inspect

    measurement = inspection.measurement
    model = model_from_dict(measurement.rig_values)
    height, width = points.shape[:2]
    scan = Scan(
        points_mm=points.reshape(-1, 3),
        shape=(height, width),
        sigma_mm=None if sigma is None else np.asarray(sigma, dtype=np.float64).reshape(-1),
        sigma_along_ray=sigma is not None,
        ray_origin_mm=np.asarray(model.camera_centre_mm, dtype=np.float64),
        source={"measurement": measurement.pk, "rig": measurement.rig_id, "rig_values": measurement.rig_values},
    )
    try:
        return inspect(nominal, scan, InspectOptions.from_dict(inspection.options))
    except ValueError as exc:
        raise job_services.JobFailedError(f"the inspection cannot be done: {exc}") from exc


def deviations_ply(inspection: Inspection) -> str:
    """The storage name of the finished inspection's ``deviations.ply``, built on first request.

    A binary PLY point cloud (:func:`metrology.core.io.points.ply_point_cloud`) of every point that
    has a deviation, in the nominal's frame (the report's transform applied to the measurement's
    points), mm, with ``deviation_mm`` (signed, positive outside the material) and, when the
    measurement stored its sigma map, ``sigma_mm`` (each point's standard uncertainty as measured,
    along the model's sigma direction, mm). Kept in the bounded folder of derived files
    (:func:`metrology.measurements.derived.derived_files`), keyed by the stored deviations.

    Raises
    ------
    Conflict
        The inspection has no deviations yet (its job is not done).
    """
    from metrology.core.io.points import ply_point_cloud
    from metrology.measurements.derived import CACHE_PREFIX, derived_files, measurement_points

    if not inspection.deviations_npy:
        raise Conflict(f"inspection {inspection.pk} has no deviations: its job is {inspection.job.status}")
    digest = hashlib.sha256(inspection.deviations_npy.name.encode()).hexdigest()[:16]
    name = f"{CACHE_PREFIX}/inspection-{inspection.pk}-deviations-{digest}.ply"
    if default_storage.exists(name):
        return name
    measurement = inspection.measurement
    deviation = np.asarray(_load_array(inspection.deviations_npy), dtype=np.float64).reshape(-1)
    points = np.asarray(measurement_points(measurement), dtype=np.float64).reshape(-1, 3)
    if points.shape[0] != deviation.shape[0]:
        raise Conflict(f"inspection {inspection.pk}: its deviations do not match the measurement's points")
    transform = np.asarray(inspection.report["transform"], dtype=np.float64)
    keep = np.isfinite(deviation) & np.isfinite(points).all(axis=1)
    aligned = points[keep] @ transform[:3, :3].T + transform[:3, 3]
    sigma = None
    if measurement.sigma_npy:
        sigma = np.asarray(_load_array(measurement.sigma_npy), dtype=np.float64).reshape(-1)[keep]
    data = ply_point_cloud(aligned, sigma_mm=sigma, deviation_mm=deviation[keep])
    stored = default_storage.save(name, File(io.BytesIO(data), name="deviations.ply"))
    if stored != name:  # another request stored it first: keep theirs
        default_storage.delete(stored)
    derived_files().trim(keep=name)
    return name


@transaction.atomic
def set_plan(*, owner, rig, nominal: NominalModel, options: dict[str, Any] | None = None, active: bool = True):
    """Create or replace ``rig``'s inspection plan (one per rig). The options are kept as given
    (validated): those left out take their defaults when each inspection is requested, the
    systematic term the rig's latest characterization then."""
    options = dict(options or {})
    inspect_options(options)  # BadInput naming a bad one
    plan, _created = InspectionPlan.objects.update_or_create(
        rig=rig, defaults={"owner": owner, "nominal": nominal, "options": options, "active": active}
    )
    return plan


def delete_plan(plan: InspectionPlan) -> None:
    plan.delete()


def apply_plan(measurement: Measurement) -> Inspection | None:
    """Queue the inspection that the rig's active plan asks for on a newly finished measurement
    (once per measurement and plan); None when the rig has no active plan."""
    plan = InspectionPlan.objects.filter(rig_id=measurement.rig_id, active=True).select_related("nominal").first()
    if plan is None or Inspection.objects.filter(measurement=measurement, plan=plan).exists():
        return None
    return request_inspection(
        owner=plan.owner, measurement=measurement, nominal=plan.nominal, options=plan.options, plan=plan
    )
