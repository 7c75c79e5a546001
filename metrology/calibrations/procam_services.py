"""Writes for projector-camera calibrations: request (a queued job), compute in a worker, apply to the rig.

A :class:`~metrology.calibrations.models.ProcamCalibration` calibrates a rig's camera and projector
from board poses (captures of role ``board`` whose codec codes both projector axes) with the same
pipeline function as ``gcps calibrate-procam``
(:func:`metrology.pipeline.calibrate_procam.calibrate_procam_stacks`), and stores what that command
writes: the report (REPORT.json, ``gcps-procam-report/1``) and the pinhole rig file. Applying it
makes the rig a pinhole rig with that file; the rig's history keeps what it replaced.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from typing import Any

from django.core.files.storage import default_storage
from django.db import transaction
from django.utils import timezone

from metrology.calibrations.models import ProcamCalibration, ProcamCalibrationPose
from metrology.captures import services as capture_services
from metrology.captures.models import Capture
from metrology.captures.selectors import capture_for_job
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.rigs.models import Rig, RigParameters
from metrology.service_errors import SERVICE_ERRORS, error_sentence

MIN_POSES = 2
"""Fewest poses a request may name (the calibration needs two usable ones; docs recommend 8 to 12)."""

MAX_POSES = 40
"""Most poses a request may name (a bound on one job's work; its stacks are read one at a time)."""

MAX_BOARD_POINTS = 100
"""Most points per row, and rows, a board spec may have (a real board has a few dozen)."""


def procam_options(board: Any, options: dict[str, Any] | None) -> Any:
    """The :class:`~metrology.pipeline.calibrate_procam.ProcamOptions` of a request; :class:`BadInput` naming
    ``board`` or ``options.NAME`` when a value is refused."""
    from metrology.core.procam import parse_board
    from metrology.pipeline.calibrate_procam import OPTION_KEYS, ProcamOptions

    if not isinstance(board, str) or not board.strip():
        raise BadInput("board is required: KIND:COLSxROWS:SIZE_MM, e.g. chessboard:9x7:25 (inner corners, mm)")
    try:
        spec = parse_board(board)
    except ValueError as exc:
        raise BadInput("board: " + str(exc).removeprefix("--board ")) from None
    if spec.cols > MAX_BOARD_POINTS or spec.rows > MAX_BOARD_POINTS:
        raise BadInput(
            f"board: at most {MAX_BOARD_POINTS} points per row and {MAX_BOARD_POINTS} rows, got {spec.cols}x{spec.rows}"
        )
    options = dict(options or {})
    accepted = [key for key in OPTION_KEYS if key != "board"]  # the board is a field of its own
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise BadInput(
            f"options: unknown option(s) {', '.join(map(str, unknown))}; accepted: {', '.join(accepted)} "
            "(the board is given as board)"
        )
    try:
        return ProcamOptions.from_dict({**options, "board": board.strip()})
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from None


def _check_pose(owner, rig: Rig, capture_id: Any, index: int) -> tuple[Capture, tuple[int, int]]:
    """A pose capture of a request, checked: the owner's, of ``rig``, stored, a board pose of the rig's
    camera size whose codec codes both axes. Returns it with its codec's projector size."""
    from metrology.captures.codecs import capture_codec
    from metrology.core.codecs.model import CodecError

    where = f"poses[{index}]"
    capture = capture_for_job(owner, rig, capture_id, field=where, roles=(Capture.Role.BOARD,))
    if (capture.width_px, capture.height_px) != (rig.width_px, rig.height_px):
        raise BadInput(
            f"{where}: capture {capture.pk} is {capture.width_px}x{capture.height_px} px but the rig's camera is "
            f"{rig.width_px}x{rig.height_px} px"
        )
    try:
        codec = capture_codec(capture)
    except (CodecError, TypeError, ValueError) as exc:
        raise BadInput(f"{where}: capture {capture.pk} has no usable codec: {exc}") from None
    missing = [axis for axis in ("u", "v") if axis not in codec.axes]
    if missing:
        raise BadInput(
            f"{where}: capture {capture.pk}'s codec does not code the projector's {' and '.join(missing)} axis; "
            "a board pose needs both axes coded (docs/codecs.md)"
        )
    return capture, (int(codec.projector_width), int(codec.projector_height))


def rig_state(rig: Rig) -> dict[str, Any]:
    """What a calibration would replace: the rig's model, rig file and image size."""
    return {"model": rig.model, "rig_file": rig.rig_file(), "width_px": rig.width_px, "height_px": rig.height_px}


@transaction.atomic
def request_procam_calibration(
    *,
    owner,
    rig: Rig,
    pose_ids: Sequence[int],
    board: str,
    options: dict[str, Any] | None = None,
    apply: bool = False,
) -> ProcamCalibration:
    """Create a projector-camera calibration of ``rig`` from the board captures ``pose_ids`` (in that
    order) and queue its job.

    Raises
    ------
    BadInput
        Naming the field or pose: fewer than two or more than :data:`MAX_POSES` poses, a pose given
        twice, a capture that is not the owner's board capture of this rig, not stored, not of the
        rig's camera size, of a codec not coding both axes, poses of different projector sizes, a bad
        board spec or option.
    """
    used = procam_options(board, options)
    ids = list(pose_ids)
    if len(ids) < MIN_POSES:
        raise BadInput(f"poses: give at least {MIN_POSES} board captures (8 to 12 recommended), got {len(ids)}")
    if len(ids) > MAX_POSES:
        raise BadInput(f"poses: at most {MAX_POSES} board captures, got {len(ids)}")
    seen: set[int] = set()
    captures: list[Capture] = []
    projector: tuple[int, int] | None = None
    for index, capture_id in enumerate(ids):
        if capture_id in seen:
            raise BadInput(f"poses[{index}]: capture {capture_id} is given twice")
        seen.add(capture_id)
        capture, size = _check_pose(owner, rig, capture_id, index)
        if projector is not None and size != projector:
            raise BadInput(
                f"poses[{index}]: capture {capture.pk}'s codec has a {size[0]}x{size[1]} projector but "
                f"poses[0]'s has {projector[0]}x{projector[1]}; all poses need the same projector"
            )
        projector = size
        captures.append(capture)
    job = job_services.create_job(
        owner=owner,
        kind=Job.Kind.PROCAM_CALIBRATION,
        parameters={"rig": rig.pk, "poses": [c.pk for c in captures], "options": used.to_dict(), "apply": apply},
    )
    calibration = ProcamCalibration.objects.create(
        owner=owner, rig=rig, options=used.to_dict(), rig_before=rig_state(rig), apply=apply, job=job
    )
    ProcamCalibrationPose.objects.bulk_create(
        ProcamCalibrationPose(calibration=calibration, capture=capture, index=index)
        for index, capture in enumerate(captures)
    )
    job.parameters["procam_calibration"] = calibration.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return calibration


def request_procam_calibration_with_uploads(
    *,
    owner,
    rig: Rig,
    uploads: Sequence[Any],
    existing_ids: Sequence[int] = (),
    board: str,
    options: dict[str, Any] | None = None,
    apply: bool = False,
) -> ProcamCalibration:
    """Store the uploaded pose zips as board captures of one new capture session, then request the
    calibration of those poses followed by the stored board captures ``existing_ids``.

    All in one transaction: on any refusal no row stays and the stacks already stored are deleted.

    Raises
    ------
    BadInput
        As :func:`request_procam_calibration`, or naming the pose file whose upload was refused.
    """
    stored: list[str] = []
    try:
        with transaction.atomic():
            ids: list[int] = []
            if uploads:
                session = capture_services.create_session(
                    owner=owner, rig=rig, name=f"board poses {timezone.now():%Y-%m-%d %H:%M}"
                )
                for upload in uploads:
                    try:
                        capture = capture_services.upload_capture(
                            owner=owner, rig=rig, upload=upload, role="board", session_id=session.pk
                        )
                    except SERVICE_ERRORS as exc:
                        raise BadInput(f"pose file {upload.name}: {error_sentence(exc)}") from None
                    stored.append(capture.file.name)
                    ids.append(capture.pk)
            return request_procam_calibration(
                owner=owner, rig=rig, pose_ids=ids + list(existing_ids), board=board, options=options, apply=apply
            )
    except BaseException:
        for name in stored:
            default_storage.delete(name)
        raise


def pose_names(captures: Sequence[Capture]) -> list[str]:
    """The poses' names in the report: their uploaded file names when those are all present and
    distinct (what ``gcps calibrate-procam`` calls zips of those names), else ``capture ID``."""
    names = [c.original_name for c in captures]
    if all(names) and len(set(names)) == len(names):
        return names
    return [f"capture {c.pk}" for c in captures]


def run_procam_calibration(job: Job, run: job_services.JobRun) -> None:
    """Job handler: load every pose's stack and codec, call the pipeline with the job's progress, publish
    the report and the rig file (and apply them if asked).

    Progress: 0-90 % over the poses, each read ("read pose i of n", only then: one pose's images
    are in memory at a time) and observed ("observe pose i of n"), calibrating at 90 %. A
    calibration that cannot be done (fewer than two usable poses...) fails the job with the
    pipeline's sentence, each pose's reason included.
    """
    from metrology.captures.codecs import capture_codec
    from metrology.pipeline.calibrate_procam import (
        ProcamOptions,
        ProcamPose,
        calibrate_procam_stacks,
        report_json_text,
    )
    from metrology.pipeline.jsonsafe import json_safe

    calibration = ProcamCalibration.objects.select_related("rig").get(job=job)
    links = list(calibration.pose_links.select_related("capture__rig").order_by("index"))
    captures = [link.capture for link in links]
    names = pose_names(captures)
    options = ProcamOptions.from_dict(calibration.options)
    total = len(captures)
    # each pose's stack is read when its turn comes and released after it is observed, so one
    # pose's images are in memory at a time
    poses = [
        ProcamPose(name=name, images=functools.partial(_pose_images, capture), codec=capture_codec(capture))
        for name, capture in zip(names, captures, strict=True)
    ]
    order = {name: index for index, name in enumerate(names)}

    def progress(percent: int, phase: str) -> None:
        verb, _, name = phase.partition(" ")
        if verb in ("read", "observe") and name in order:
            phase = f"{verb} pose {order[name] + 1} of {total}"
        run.progress(percent, phase)

    start = time.perf_counter()
    try:
        outcome = calibrate_procam_stacks(poses, options, progress)
    except ValueError as exc:  # the pipeline's sentence (each pose's reason), never a traceback
        raise job_services.JobFailedError(_sentence(str(exc))) from None
    del poses
    for name, seconds in outcome.timings_s.items():
        run.timings[f"calibrate_procam.{name}"] = round(float(seconds), 4)
    report = dict(outcome.report)
    report["timings_s"] = {**report["timings_s"], "total": round(time.perf_counter() - start, 3)}
    report_text = report_json_text(report)
    rig_file = outcome.rig.to_dict()

    def publish(job_row: Job) -> None:
        ProcamCalibration.objects.filter(pk=calibration.pk).update(
            report=json_safe(report), report_json=report_text, rig_file=rig_file
        )
        job_row.software_version = outcome.software_version  # the code that computed it
        if calibration.apply:
            apply_procam_calibration(calibration=ProcamCalibration.objects.get(pk=calibration.pk), require_done=False)

    run.progress(95, "store")
    run.commit(publish)


def _pose_images(capture: Capture) -> Any:
    """A board capture's stored stack, ``(frames, H, W)`` (read when the pipeline needs it)."""
    from metrology.captures.stacks import load_capture_images

    return load_capture_images(capture)


def _sentence(text: str, limit: int = 1900) -> str:
    """A failure message short enough to be kept as the job's reason (cut at ``limit`` characters)."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


def converted_model(rig: Rig) -> str | None:
    """The label of the rig's model when applying a projector-camera calibration changes it (the
    calibration gives a pinhole rig), else None."""
    from metrology.core.geometry.pinhole import PinholeRig

    model = rig.to_core()
    return None if model.model == PinholeRig.model else model.label


def _match_default_codec(rig: Rig, calibration: ProcamCalibration) -> None:
    """Give the rig the first pose's codec as its default when its model cannot measure with its own.

    A calibrated rig measures only with codecs of its projector's size; a crossed-axes rig's default
    is usually gcps-v1 (whose projector is the paper's, not the real one), so after the conversion
    captures uploaded without their own codec would be refused. The poses' codec codes both axes
    of the calibrated projector and is what the lab projects, so it becomes the default; a default
    the model measures with is kept (the lab may measure with another pattern sequence).
    """
    from metrology.captures.codecs import capture_codec, capture_codec_value
    from metrology.core.geometry import GeometryError
    from metrology.rigs.codecs import codec_of
    from metrology.rigs.services import set_rig_codec

    model = rig.to_core()

    def measurable(codec: Any) -> bool:
        try:
            model.check_codec((codec.projector_width, codec.projector_height), tuple(codec.axes))
        except GeometryError:
            return False
        return True

    if measurable(codec_of(rig.codec)):
        return
    first = calibration.pose_links.select_related("capture__rig").order_by("index").first()
    if first is not None and measurable(capture_codec(first.capture)):
        set_rig_codec(rig=rig, codec=capture_codec_value(first.capture))


@transaction.atomic
def apply_procam_calibration(*, calibration: ProcamCalibration, require_done: bool = True) -> ProcamCalibration:
    """Give the calibration's rig the calibrated rig file (a pinhole rig's), recorded in its history.

    The rig takes the file's model and values; a rig of another model is converted (its values stay
    in its history and in ``rig_before``). Idempotent: a second call changes nothing.
    :class:`BadInput` unless the job is done (``require_done``) or when there is no rig file.
    """
    calibration = ProcamCalibration.objects.select_for_update().select_related("job").get(pk=calibration.pk)
    if require_done and calibration.job.status != Job.Status.DONE:
        raise BadInput(
            f"procam calibration {calibration.pk} cannot be applied: its job is {calibration.job.status}"
            + (f" ({calibration.job.error})" if calibration.job.error else "")
        )
    if calibration.applied:
        return calibration
    if not calibration.rig_file:
        raise BadInput(f"procam calibration {calibration.pk} has no calibrated rig file to apply")
    from metrology.rigs.services import set_rig_model, validate_model

    rig = set_rig_model(
        rig=calibration.rig,
        model=validate_model(calibration.rig_file),
        source=RigParameters.Source.CALIBRATION,
        procam=calibration,
    )
    _match_default_codec(rig, calibration)
    calibration.applied = True
    calibration.applied_at = timezone.now()
    calibration.save(update_fields=["applied", "applied_at"])
    return calibration
