"""Writes for captures: validated uploads, simulated captures (a job), reading stacks back.

Uploads are validated completely (size, zip structure, pattern names, shapes, bit depth, the rig's
shape) by the core's reader *before* anything is stored; the file is saved only then, and deleted
again if the rows cannot be written, so a refused upload leaves neither a row nor a file.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import uuid
from pathlib import Path
from typing import Any

import numpy as np
from django.conf import settings
from django.core.files import File
from django.core.files.storage import default_storage
from django.db import transaction

from metrology.captures.models import Capture, CaptureSession
from metrology.captures.sources import CaptureRequest, get_source
from metrology.captures.stacks import MIB, frame_shape, read_upload_stack, stored_exposures
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.rigs.models import Rig


def _sha256(handle) -> tuple[str, int]:
    digest = hashlib.sha256()
    size = 0
    handle.seek(0)
    for chunk in iter(lambda: handle.read(MIB), b""):
        digest.update(chunk)
        size += len(chunk)
    handle.seek(0)
    return digest.hexdigest(), size


def _session_for(*, owner, rig: Rig, session_id: int | None, name: str = "") -> CaptureSession:
    if session_id is None:
        return CaptureSession.objects.create(owner=owner, rig=rig, name=name)
    session = CaptureSession.objects.filter(pk=session_id, owner=owner).first()
    if session is None:
        raise BadInput(f"session {session_id} does not exist among yours")
    if session.rig_id != rig.pk:
        raise BadInput(f"session {session_id} belongs to rig {session.rig_id}, not to rig {rig.pk}")
    return session


def _check_stage(role: str, z_in_mm: float | None) -> None:
    if role == Capture.Role.STAGE and z_in_mm is None:
        raise BadInput("z_in_mm is required for a stage capture (the stage position, mm)")
    if z_in_mm is not None and not np.isfinite(z_in_mm):
        raise BadInput(f"z_in_mm must be a finite number of millimetres, got {z_in_mm}")


def _new_stack_name(rig: Rig) -> str:
    return f"captures/rig_{rig.pk}/{uuid.uuid4().hex}.zip"


@transaction.atomic
def create_session(*, owner, rig: Rig, name: str = "", notes: str = "") -> CaptureSession:
    return CaptureSession.objects.create(owner=owner, rig=rig, name=name, notes=notes)


def upload_capture(
    *,
    owner,
    rig: Rig,
    upload,
    role: str,
    z_in_mm: float | None = None,
    repeat: int = 0,
    session_id: int | None = None,
    bit_depth: int | None = None,
) -> Capture:
    """Validate an uploaded zip stack for ``rig`` and store it as a capture.

    Raises
    ------
    BadInput
        Naming the problem; nothing is stored.
    """
    limit = settings.GCPS_MAX_UPLOAD_BYTES
    if upload.size is not None and upload.size > limit:
        raise BadInput(f"upload of {upload.size} bytes exceeds the limit of {limit} bytes (GCPS_MAX_UPLOAD_BYTES)")
    _check_stage(role, z_in_mm)
    if session_id is not None:  # fail early on a bad session, before reading the stack
        _session_for(owner=owner, rig=rig, session_id=session_id)
    upload.seek(0)

    codec, stack = read_upload_stack(upload, rig, expected_bit_depth=bit_depth)
    checksum, size = _sha256(upload)
    stored = default_storage.save(_new_stack_name(rig), upload)
    try:
        with transaction.atomic():
            session = _session_for(owner=owner, rig=rig, session_id=session_id, name="upload")
            height_px, width_px = frame_shape(stack)
            return Capture.objects.create(
                owner=owner,
                rig=rig,
                session=session,
                role=role,
                z_in_mm=z_in_mm,
                repeat=repeat,
                source=Capture.Source.UPLOAD,
                file=stored,
                original_name=os.path.basename(upload.name or "")[:255],
                checksum_sha256=checksum,
                size_bytes=size,
                bit_depth=int(stack.bit_depth),
                height_px=height_px,
                width_px=width_px,
                codec=codec,
                exposures=stored_exposures(stack),
            )
    except BaseException:
        default_storage.delete(stored)
        raise


@transaction.atomic
def request_simulated_capture(
    *,
    owner,
    rig: Rig,
    role: str,
    scene: dict[str, Any],
    options: dict[str, Any],
    z_in_mm: float | None = None,
    repeat: int = 0,
    session_id: int | None = None,
    source: str = "virtual",
) -> Capture:
    """Create a capture that a worker renders with the virtual rig; returns it with its queued job.

    The virtual rig projects the rig's default codec (gcps-v1 unless set), which the rig's model
    must measure with, and renders it through the model (any model: docs/file-formats.md).
    """
    from metrology.rigs.codecs import capture_default, check_codec_for_rig, codec_of

    _check_stage(role, z_in_mm)
    codec_value = capture_default(rig)
    codec = codec_of(codec_value)
    check_codec_for_rig(codec, rig)
    request = CaptureRequest(role=role, scene=scene, options=options, z_in_mm=z_in_mm, repeat=repeat, codec=codec)
    try:
        get_source(source).check(rig.to_core(), request)
    except (ValueError, TypeError) as exc:
        raise BadInput(str(exc)) from None
    session = _session_for(owner=owner, rig=rig, session_id=session_id, name=f"{source} capture")
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.SIMULATE_CAPTURE,
        parameters={"source": source, "scene": scene, "options": options, "z_in_mm": z_in_mm, "repeat": repeat},
    )
    capture = Capture.objects.create(
        owner=owner,
        rig=rig,
        session=session,
        role=role,
        z_in_mm=z_in_mm,
        repeat=repeat,
        source=Capture.Source.VIRTUAL,
        parameters={"source": source, "scene": scene, "options": options},
        job=job,
        codec=codec_value,
    )
    job.parameters["capture"] = capture.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return capture


def run_simulate_capture(job: Job, run: job_services.JobRun) -> None:
    """Job handler: render the stack, store it (and the truth heights), then publish the capture."""
    from metrology.captures.codecs import capture_codec
    from metrology.core.codecs.stack import write_cameras_capture

    capture = Capture.objects.select_related("rig").get(job=job)
    if capture.file:  # already stored by an earlier attempt that committed
        run.commit(lambda _job: None)
        return
    params = capture.parameters
    request = CaptureRequest(
        role=capture.role,
        scene=params.get("scene", {}),
        options=params.get("options", {}),
        z_in_mm=capture.z_in_mm,
        repeat=capture.repeat,
        codec=capture_codec(capture),
    )
    with run.phase("render", 5):
        stack = get_source(params.get("source", "virtual")).acquire(capture.rig.to_core(), request)
    with tempfile.TemporaryDirectory(prefix="gcps-capture-") as tmp:
        with run.phase("write", 70):
            zip_path = Path(tmp) / "stack.zip"
            write_cameras_capture(stack.camera_stacks, zip_path, request.codec)
            with zip_path.open("rb") as handle:
                checksum, size = _sha256(handle)
                stack_name = run.save_file(default_storage, _new_stack_name(capture.rig), File(handle))
            truth_name = ""
            if stack.truth_mm is not None:
                truth_path = Path(tmp) / "truth.npy"
                np.save(truth_path, np.asarray(stack.truth_mm, dtype=np.float32))
                with truth_path.open("rb") as handle:
                    truth_name = run.save_file(
                        default_storage, f"captures/rig_{capture.rig_id}/{uuid.uuid4().hex}-truth.npy", File(handle)
                    )

        def publish(_job: Job) -> None:
            Capture.objects.filter(pk=capture.pk).update(
                file=stack_name,
                truth=truth_name,
                checksum_sha256=checksum,
                size_bytes=size,
                bit_depth=stack.bit_depth,
                height_px=stack.images.shape[1],
                width_px=stack.images.shape[2],
            )

        run.commit(publish)
