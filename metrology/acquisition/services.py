"""Writes for acquisition: agents (register, beat, disconnect), acquisition requests, the projector state.

An acquisition is a :class:`~metrology.jobs.models.Job` of kind ``acquire_capture`` that no Celery
worker runs: the rig's connected agent takes it, reports progress and per-frame checks, and
uploads the stack; :func:`store_acquired_capture` validates it and, in one transaction, stores the
capture (source ``rig``) and marks the job done. One agent per rig: a second one is refused while
the first is connected. An agent not heard from for ``GCPS_AGENT_TIMEOUT_SECONDS`` is
disconnected by :func:`expire_agents` (called by every agent, projector and status request) and its
running acquisition failed with the reason; nothing of it is stored.
"""

from __future__ import annotations

import uuid
from datetime import timedelta
from typing import Any

from django.conf import settings
from django.core.files.storage import default_storage
from django.db import transaction
from django.utils import timezone

from metrology.acquisition import longpoll
from metrology.acquisition.agent.bracketing import MAX_REQUESTED_EXPOSURES, parse_exposures
from metrology.acquisition.agent.patterns import ProjectedCodec, resolve_codec
from metrology.acquisition.models import Acquisition, Agent, ProjectorState
from metrology.captures import services as capture_services
from metrology.captures.models import Capture
from metrology.core.codecs.decode import fringe_refusal
from metrology.errors import BadInput, Conflict
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.rigs import codecs as rig_codecs
from metrology.rigs.models import Rig

ACQUIRE_KIND = "acquire_capture"
PROJECTOR_KINDS = ("blank", "test", "white", "black", "frame")


def _timeout() -> timedelta:
    return timedelta(seconds=settings.GCPS_AGENT_TIMEOUT_SECONDS)


# ----------------------------------------------------------------------------- agents
def expire_agents(rig: Rig | None = None) -> int:
    """Disconnect agents not heard from within the timeout (and fail their acquisitions), and fail the
    acquisitions no agent took in time (:func:`expire_acquisitions`). Returns how many agents."""
    count = _disconnect_silent_agents(rig)
    expire_acquisitions(rig)
    return count


def _disconnect_silent_agents(rig: Rig | None) -> int:
    now = timezone.now()
    stale = Agent.objects.filter(disconnected_at__isnull=True, last_seen_at__lt=now - _timeout())
    if rig is not None:
        stale = stale.filter(rig=rig)
    count = 0
    for agent in list(stale):
        silent = (now - agent.last_seen_at).total_seconds()
        disconnect_agent(
            agent, f"the capture agent stopped responding (not heard from for {silent:.0f} s, {agent.camera})"
        )
        count += 1
    return count


def expire_acquisitions(rig: Rig | None = None) -> int:
    """Fail, with the reason, the acquisitions queued for longer than ``GCPS_ACQUISITION_TIMEOUT_SECONDS``
    that no agent took, on rigs without a connected agent (a connected agent works through its
    rig's queue, however long). Called on every read of an acquisition, an agent or the projector
    (:func:`expire_agents`) and by the periodic job sweep (:func:`sweep_acquisitions`). An agent that
    takes one at the same moment wins (the job is failed only while still queued). Returns how many."""
    limit = settings.GCPS_ACQUISITION_TIMEOUT_SECONDS
    cutoff = timezone.now() - timedelta(seconds=limit)
    # never enqueued: an acquisition requeued by the job sweep (its agent went silent) is a worker's
    waiting = Acquisition.objects.filter(
        job__status=Job.Status.QUEUED, job__enqueued_at__isnull=True, job__created_at__lt=cutoff
    ).exclude(rig_id__in=Agent.objects.filter(disconnected_at__isnull=True).values("rig_id"))
    if rig is not None:
        waiting = waiting.filter(rig=rig)
    expired = 0
    for job_id, rig_name in waiting.values_list("job_id", "rig__name"):
        reason = (
            f"no capture agent took this acquisition within {limit:g} s (GCPS_ACQUISITION_TIMEOUT_SECONDS): "
            f"start the agent of rig {rig_name!r} (gcps agent, or the webcam page) and request the capture again"
        )
        expired += Job.objects.filter(pk=job_id, status=Job.Status.QUEUED).update(
            status=Job.Status.FAILED, error=reason, phase="expired", finished_at=timezone.now()
        )
    return expired


def sweep_acquisitions() -> dict[str, int]:
    """The acquisitions' part of the periodic job sweep (registered in ``AcquisitionConfig.ready``)."""
    agents = _disconnect_silent_agents(None)  # first: their rigs' queued acquisitions may then expire
    return {"agents_expired": agents, "acquisitions_expired": expire_acquisitions()}


def connected_agent(rig: Rig) -> Agent | None:
    """The rig's connected agent, if any (after expiring silent ones)."""
    expire_agents(rig)
    return Agent.objects.filter(rig=rig, disconnected_at__isnull=True).order_by("-connected_at").first()


@transaction.atomic
def register_agent(*, owner, rig: Rig, camera: str, name: str = "", software_version: str = "") -> Agent:
    """A new agent session for ``rig``. Raises :class:`Conflict` while another agent is connected."""
    expire_agents(rig)
    Rig.objects.select_for_update().filter(pk=rig.pk).first()  # serialise registrations of one rig
    other = Agent.objects.filter(rig=rig, disconnected_at__isnull=True).first()
    if other is not None:
        seen = (timezone.now() - other.last_seen_at).total_seconds()
        raise Conflict(
            f"rig {rig.pk} already has a connected capture agent (agent {other.pk}, {other.camera}, "
            f"{other.name or 'unnamed'}, seen {seen:.0f} s ago); stop it first"
        )
    if not camera.strip():
        raise BadInput("camera must name the camera backend, e.g. opencv:0")
    now = timezone.now()
    return Agent.objects.create(
        owner=owner,
        rig=rig,
        session=uuid.uuid4(),
        camera=camera.strip()[:200],
        name=name.strip()[:200],
        software_version=software_version[:64],
        last_seen_at=now,
    )


def agent_for_session(*, owner, rig: Rig, session: Any) -> Agent:
    """The connected agent of ``session`` (its ``last_seen_at`` refreshed). Raises :class:`Conflict` otherwise."""
    try:
        key = uuid.UUID(str(session))
    except ValueError:
        raise BadInput(f"session must be the UUID register returned, got {session!r}") from None
    expire_agents(rig)
    agent = Agent.objects.filter(session=key, rig=rig, owner=owner).first()
    if agent is None:
        raise Conflict(f"no agent session {key} on rig {rig.pk}; register first")
    if agent.disconnected_at is not None:
        raise Conflict(f"agent {agent.pk} was disconnected: {agent.disconnect_reason}; register again")
    now = timezone.now()
    Agent.objects.filter(pk=agent.pk).update(last_seen_at=now)
    agent.last_seen_at = now
    running = Acquisition.objects.filter(agent=agent, job__status=Job.Status.RUNNING).values_list("job_id", flat=True)
    Job.objects.filter(pk__in=list(running)).update(heartbeat_at=now)
    return agent


def disconnect_agent(agent: Agent, reason: str) -> None:
    """Mark ``agent`` disconnected and fail its running acquisition with ``reason`` (nothing is stored)."""
    with transaction.atomic():
        Agent.objects.filter(pk=agent.pk, disconnected_at__isnull=True).update(
            disconnected_at=timezone.now(), disconnect_reason=reason[:300]
        )
        for acquisition in Acquisition.objects.filter(agent=agent, job__status=Job.Status.RUNNING):
            _fail_job(acquisition.job_id, f"{reason}; no capture was stored")


def _fail_job(job_id: int, reason: str) -> None:
    Job.objects.filter(pk=job_id, status__in=(Job.Status.QUEUED, Job.Status.RUNNING)).update(
        status=Job.Status.FAILED, error=reason, finished_at=timezone.now()
    )


# ----------------------------------------------------------------------------- acquisition requests
def request_acquisition(
    *,
    owner,
    rig: Rig,
    role: str,
    z_in_mm: float | None = None,
    repeat: int = 0,
    exposure_ms: float | None = None,
    codec: Any = None,
    session_id: int | None = None,
    exposures: Any = None,
    max_exposures: int | None = None,
) -> Acquisition:
    """Queue a capture for the rig's agent. Returns the acquisition with its queued job.

    ``exposures`` asks for a multi-exposure capture (docs/exposures.md): ``"auto"`` (the agent
    brackets, at most ``max_exposures``, 1..8; None: the agent's ``--max-exposures``) or a list of
    exposure times in ms (:func:`~metrology.acquisition.agent.bracketing.parse_exposures`: at most
    8, distinct, stored shortest first). It overrides the agent's ``--exposures``; None leaves the
    choice to the agent.

    Raises
    ------
    BadInput
        On a bad role/stage position/exposure/exposures/codec; nothing is stored.
    """
    if role not in Capture.Role.values:
        raise BadInput(f"role must be one of {', '.join(Capture.Role.values)}, got {role!r}")
    capture_services._check_stage(role, z_in_mm)
    if exposure_ms is not None and not (0 < exposure_ms <= 60_000):
        raise BadInput(f"exposure must be a number of milliseconds in (0, 60000], got {exposure_ms}")
    choice = _exposure_choice(rig, exposure_ms, exposures, max_exposures)
    value = acquisition_codec_value(rig, codec)
    try:
        resolve_codec(value)  # the agent must be able to render it
    except ValueError as exc:
        raise BadInput(f"codec: {exc}") from None
    with transaction.atomic():
        session = capture_services._session_for(owner=owner, rig=rig, session_id=session_id, name="rig capture")
        job = job_services.create_job(
            owner=owner,
            kind=ACQUIRE_KIND,
            parameters={
                "rig": rig.pk,
                "role": role,
                "z_in_mm": z_in_mm,
                "repeat": repeat,
                "exposure_ms": exposure_ms,
                "exposures": choice,
                "max_exposures": max_exposures,
                "codec": value,
            },
        )
        Job.objects.filter(pk=job.pk).update(phase="waiting for the rig's capture agent")
        acquisition = Acquisition.objects.create(
            owner=owner,
            rig=rig,
            session=session,
            role=role,
            z_in_mm=z_in_mm,
            repeat=repeat,
            exposure_ms=exposure_ms,
            exposures=choice,
            max_exposures=max_exposures,
            codec={"name": value} if isinstance(value, str) else value,
            job=job,
        )
        job.parameters["acquisition"] = acquisition.pk
        job.save(update_fields=["parameters"])
    return acquisition


def _exposure_choice(rig: Rig, exposure_ms: float | None, exposures: Any, max_exposures: int | None) -> Any:
    """The request's multi-exposure choice as stored: None, ``"auto"`` or the times (ms) shortest
    first. Raises :class:`BadInput` naming the field."""
    try:
        choice = parse_exposures(exposures)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    if max_exposures is not None:
        if choice != "auto":
            raise BadInput('max_exposures applies to exposures "auto" only (the agent\'s automatic bracket)')
        if isinstance(max_exposures, bool) or not 1 <= max_exposures <= MAX_REQUESTED_EXPOSURES:
            raise BadInput(f"max_exposures must be an integer in 1..{MAX_REQUESTED_EXPOSURES}, got {max_exposures!r}")
    if choice is None:
        return None
    if exposure_ms is not None:
        raise BadInput("give exposure (one exposure) or exposures (a multi-exposure capture), not both")
    return list(choice) if isinstance(choice, tuple) else choice  # a stereo rig's cameras are bracketed as a pair


def acquisition_codec_value(rig: Rig, codec: Any) -> Any:
    """The codec an acquisition projects, as stored on its capture: ``codec`` (a built-in name,
    ``{"name": ...}`` or a gcps-codec/1 object), else the rig's default codec.

    A name is kept as given (``"gcps-v1"``, ``"gcps-v1:1280x800"``), an object in its canonical
    gcps-codec/1 form. Raises :class:`BadInput` for a malformed codec, one of more than
    :data:`~metrology.rigs.codecs.MAX_CODEC_FRAMES` frames, or one the rig cannot measure with
    (:func:`~metrology.rigs.codecs.check_codec_for_rig`).
    """
    from metrology.rigs.codecs import capture_default, check_codec_for_rig, codec_of, validate_codec

    if isinstance(codec, dict) and set(codec) == {"name"}:
        codec = codec["name"]
    if codec is None or codec == "":
        codec = capture_default(rig)
    value = validate_codec(codec)
    check_codec_for_rig(codec_of(value), rig)
    return value


def stored_codec_value(acquisition: Acquisition) -> Any:
    """The acquisition's codec as :attr:`Capture.codec <metrology.captures.models.Capture.codec>` stores it:
    a built-in name or a gcps-codec/1 object."""
    codec = acquisition.codec
    if isinstance(codec, dict) and set(codec) == {"name"}:
        return codec["name"]
    return codec


def codec_of(acquisition: Acquisition) -> ProjectedCodec:
    """The acquisition's codec, ready to project."""
    return resolve_codec(acquisition.codec)


def take_acquisition(agent: Agent) -> Acquisition | None:
    """The oldest queued acquisition of the agent's rig, now running under this agent; ``None`` if none."""
    with transaction.atomic():
        acquisition = (
            Acquisition.objects.select_for_update()
            .filter(rig_id=agent.rig_id, job__status=Job.Status.QUEUED)
            .order_by("id")
            .first()
        )
        if acquisition is None:
            return None
        now = timezone.now()
        Job.objects.filter(pk=acquisition.job_id).update(
            status=Job.Status.RUNNING,
            attempts=1,
            run_token=uuid.uuid4(),
            started_at=now,
            heartbeat_at=now,
            phase=f"taken by agent {agent.pk} ({agent.camera})"[:64],
            progress=1,
        )
        acquisition.agent = agent
        acquisition.save(update_fields=["agent"])
    acquisition.refresh_from_db()
    return acquisition


def _running_for(agent: Agent, acquisition: Acquisition) -> Job:
    job = Job.objects.get(pk=acquisition.job_id)
    if acquisition.agent_id != agent.pk:
        raise Conflict(f"acquisition {acquisition.pk} is not taken by agent {agent.pk}")
    if job.status != Job.Status.RUNNING:
        raise Conflict(f"acquisition {acquisition.pk} is {job.status}: {job.error or job.phase}")
    return job


def report_progress(
    agent: Agent, acquisition: Acquisition, *, percent: int, phase: str, frames: list | None = None
) -> None:
    """Record the agent's progress (0-99), its phase and, optionally, the per-frame checks so far."""
    _running_for(agent, acquisition)
    Job.objects.filter(pk=acquisition.job_id, status=Job.Status.RUNNING).update(
        progress=max(1, min(99, int(percent))), phase=phase[:64], heartbeat_at=timezone.now()
    )
    if frames is not None:
        Acquisition.objects.filter(pk=acquisition.pk).update(frames=frames)


def fail_acquisition(agent: Agent, acquisition: Acquisition, reason: str, frames: list | None = None) -> None:
    """The agent gives up on ``acquisition`` with ``reason``: the job fails, nothing is stored."""
    _running_for(agent, acquisition)
    if frames is not None:
        Acquisition.objects.filter(pk=acquisition.pk).update(frames=frames)
    _fail_job(acquisition.job_id, reason.strip()[:2000] or "the capture agent reported a failure")


def store_acquired_capture(
    agent: Agent, acquisition: Acquisition, *, upload, camera: str, exposure_ms: float | None, frames: list
) -> Capture:
    """Validate the uploaded stack and store it as the acquisition's capture; the job is then done.

    The stack is read and checked in full by the capture reader (names, shapes, the rig's size; a
    rig of several cameras: ``cam0/``, ``cam1/`` ..., each camera's stack) and must show the codec's
    fringes, in every camera's stack (:func:`~metrology.core.codecs.decode.fringe_refusal`:
    modulation present, coordinates following the code; else the acquisition fails with the
    reason, naming the camera, and :class:`BadInput` names it) before anything is written; the
    file is saved, then the rows are written in one transaction that re-checks that this agent
    still runs the acquisition (else the file is deleted again).
    """
    job = _running_for(agent, acquisition)
    rig = acquisition.rig
    upload.seek(0)
    from metrology.captures.stacks import frame_shape, read_upload_stack, stored_exposures

    codec, stack = read_upload_stack(upload, rig, codec=stored_codec_value(acquisition))
    exposures = stored_exposures(stack)
    # a bracketed acquisition (docs/exposures.md) must show the fringes in its most exposed stack
    cameras = getattr(stack, "stacks", None)  # a capture of several cameras: each camera's stack
    shown = [stack.stack.images[-1] if exposures is not None else stack.images] if cameras is None else cameras
    refusal = None
    for index, images in enumerate(shown):
        refusal = fringe_refusal(images, rig_codecs.codec_of(codec))
        if refusal is not None:
            refusal = f"camera {index} (cam{index}/): {refusal}" if len(shown) > 1 else refusal
            break
    if refusal is not None:
        # nothing is stored; the job fails with the reason (the page shows it), the agent gets it as a 400
        reason = f"the uploaded stack was refused: {refusal}"
        _fail_job(job.pk, reason[:2000])
        raise BadInput(reason)
    checksum, size = capture_services._sha256(upload)
    stored = default_storage.save(capture_services._new_stack_name(rig), upload)
    try:
        with transaction.atomic():
            job = Job.objects.select_for_update().get(pk=job.pk)
            current = Acquisition.objects.select_for_update().get(pk=acquisition.pk)
            if job.status != Job.Status.RUNNING or current.agent_id != agent.pk:
                raise Conflict(f"acquisition {acquisition.pk} is {job.status}: {job.error or job.phase}")
            height_px, width_px = frame_shape(stack)
            capture = Capture.objects.create(
                owner=acquisition.owner,
                rig=rig,
                session=acquisition.session,
                role=acquisition.role,
                z_in_mm=acquisition.z_in_mm,
                repeat=acquisition.repeat,
                source=Capture.Source.RIG,
                codec=codec,
                exposures=exposures,
                file=stored,
                original_name=f"acquisition-{acquisition.pk}.zip",
                checksum_sha256=checksum,
                size_bytes=size,
                bit_depth=int(stack.bit_depth),
                height_px=height_px,
                width_px=width_px,
                parameters={
                    "source": "rig",
                    "acquisition": acquisition.pk,
                    "agent": agent.pk,
                    "agent_name": agent.name,
                    "camera": camera[:200] or agent.camera,
                    "exposure_ms": exposure_ms,
                    "codec": acquisition.codec,
                    "regrabs": sum(int(f.get("regrabs", 0)) for f in frames if isinstance(f, dict)),
                },
                job=job,
            )
            current.capture = capture
            current.frames = frames
            current.save(update_fields=["capture", "frames"])
            now = timezone.now()
            job.status = Job.Status.DONE
            job.progress = 100
            job.phase = "done"
            job.error = ""
            job.finished_at = job.heartbeat_at = now
            job.save()
            return capture
    except BaseException:
        default_storage.delete(stored)
        raise


def run_acquisition_job(job: Job, run: job_services.JobRun) -> None:
    """Job handler for a requeued acquisition (its agent went silent): it cannot run in a worker."""
    raise job_services.JobFailedError(
        "the capture agent running this acquisition stopped responding; acquisitions run on the rig's agent, "
        "request the capture again once the agent is back"
    )


# ----------------------------------------------------------------------------- projector
def projector_state(rig: Rig) -> ProjectorState:
    state, _ = ProjectorState.objects.get_or_create(rig=rig)
    return state


def show_on_projector(rig: Rig, *, kind: str, frame: int = -1, acquisition: Acquisition | None = None) -> int:
    """Tell the projector page to show a pattern; returns its sequence number."""
    if kind not in PROJECTOR_KINDS:
        raise BadInput(f"kind must be one of {', '.join(PROJECTOR_KINDS)}, got {kind!r}")
    if kind == "frame":
        if acquisition is None:
            raise BadInput("a frame needs its acquisition")
        n = codec_of(acquisition).n_frames
        if not 0 <= frame < n:
            raise BadInput(f"frame must be in 0..{n - 1} for this codec, got {frame}")
    projector_state(rig)
    with transaction.atomic():
        state = ProjectorState.objects.select_for_update().get(rig=rig)
        state.seq += 1
        state.kind = kind
        state.frame = frame if kind == "frame" else -1
        state.acquisition = acquisition
        state.save(update_fields=["seq", "kind", "frame", "acquisition"])
        longpoll.notify_changed(rig.pk)
        return state.seq


def confirm_shown(rig: Rig, *, seq: int, kind: str, frame: int, screen: dict) -> ProjectorState:
    """The page painted pattern ``seq`` (``kind``, ``frame``) on ``screen``."""
    now = timezone.now()
    ProjectorState.objects.filter(rig=rig, seq__gte=seq).update(
        shown_seq=seq, shown_kind=kind[:16], shown_frame=frame, shown_at=now, screen=screen, page_seen_at=now
    )
    longpoll.notify_changed(rig.pk)
    return projector_state(rig)


def mark_page_seen(rig: Rig) -> None:
    ProjectorState.objects.filter(rig=rig).update(page_seen_at=timezone.now())
