"""Reads for captures and sessions, scoped to the user."""

from __future__ import annotations

from typing import Any

from django.db.models import QuerySet
from django.http import Http404

from metrology.captures.models import Capture, CaptureSession
from metrology.errors import BadInput
from metrology.rigs.models import Rig


def captures_for(user, rig: Rig | None = None) -> QuerySet[Capture]:
    captures = Capture.objects.filter(owner=user).select_related("job")
    return captures.filter(rig=rig) if rig is not None else captures


def sessions_for(user, rig: Rig | None = None) -> QuerySet[CaptureSession]:
    sessions = CaptureSession.objects.filter(owner=user)
    return sessions.filter(rig=rig) if rig is not None else sessions


def get_capture(user, capture_id) -> Capture:
    capture = captures_for(user).filter(pk=capture_id).first() if str(capture_id).isdigit() else None
    if capture is None:
        raise Http404(f"No capture {capture_id} among yours.")
    return capture


def capture_for_job(user, rig: Rig, capture_id: int, *, field: str, roles: tuple[str, ...] = ()) -> Capture:
    """A capture named in a request body: the user's, of ``rig``, stored, of an allowed role; else 400."""
    capture = captures_for(user).select_related("job").filter(pk=capture_id).first()
    if capture is None:
        raise BadInput(f"{field}: capture {capture_id} does not exist among yours")
    if capture.rig_id != rig.pk:
        raise BadInput(f"{field}: capture {capture_id} belongs to rig {capture.rig_id}, not to rig {rig.pk}")
    if roles and capture.role not in roles:
        raise BadInput(f"{field}: capture {capture_id} has role {capture.role!r}; expected {' or '.join(roles)}")
    if not capture.ready:
        job = capture.job
        state = f"its job {job.pk} is {job.status}" + (f": {job.error}" if job and job.error else "") if job else ""
        raise BadInput(f"{field}: capture {capture_id} is not stored yet ({state}); retry when its job is done")
    return capture


def capture_codec_check(capture: Capture) -> dict[str, Any] | None:
    """The codec self-check of a stored capture's stack with its codec (``{axis: {"status",
    "offset_px", "outside_share", "message", ...}}``, docs/codecs.md), or None when it is not
    stored yet or cannot be read."""
    from metrology.captures.stacks import load_codec_stack
    from metrology.core.codecs.check import summary_of
    from metrology.core.codecs.decode import decode_codec

    if not capture.ready:
        return None
    try:
        stack = load_codec_stack(capture)
        return summary_of(decode_codec(stack.images, stack.codec, with_noise=False).codec_check)
    except (ValueError, OSError):
        return None
