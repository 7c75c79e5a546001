"""REST endpoints of acquisition: capture requests, the agent protocol, the projector page's state.

The protocol (docs/acquisition.md): an agent registers (409 while another agent of the rig is
connected), beats, takes a queued acquisition, drives the projector (``POST projector/``, then a
long-poll until the page confirms), reports progress and per-frame checks, and uploads the stack
or reports the failure. Every agent call carries the ``session`` that register returned.
"""

from __future__ import annotations

import json
from typing import Any

from asgiref.sync import sync_to_async
from django.http import HttpRequest, HttpResponse
from django.utils import timezone
from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.parsers import FormParser, MultiPartParser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.acquisition import longpoll, services
from metrology.acquisition.agent.bracketing import MAX_REQUESTED_EXPOSURES
from metrology.acquisition.models import Acquisition, Agent, ProjectorState
from metrology.api_input import BoundedJSONParser
from metrology.captures.models import Capture
from metrology.errors import BadInput
from metrology.json_input import load_json_text
from metrology.rigs.selectors import get_rig

MAX_INT32 = 2**31 - 1
"""Largest value of the integer columns the projector state and frames are stored in."""
MAX_ID = 2**63 - 1
"""Largest primary key (BigAutoField)."""


def _get_acquisition(user, acquisition_id: int) -> Acquisition:
    from django.http import Http404

    acquisition = (
        Acquisition.objects.select_related("job", "rig", "agent").filter(pk=acquisition_id, owner=user).first()
    )
    if acquisition is None:
        raise Http404(f"No acquisition {acquisition_id} among yours.")
    return acquisition


@extend_schema_field(
    {
        "oneOf": [
            {"type": "string", "enum": ["auto"], "description": "The agent brackets from white and black frames"},
            {
                "type": "array",
                "items": {"type": "number", "minimum": 0, "exclusiveMinimum": True, "maximum": 60000},
                "minItems": 1,
                "maxItems": MAX_REQUESTED_EXPOSURES,
                "description": "Exposure times, ms, distinct (stored shortest first)",
            },
        ],
        "nullable": True,
        "description": (
            'A multi-exposure capture (docs/exposures.md): "auto" (at most max_exposures) or exposure '
            "times in ms; overrides the agent's --exposures. Omitted or null: the agent's choice (one "
            "exposure unless it runs with --exposures). One-camera rigs only; not with exposure."
        ),
        "example": [1.0, 10.0, 100.0],
    }
)
class ExposuresField(serializers.JSONField):
    """``"auto"`` or exposure times in ms (validated by the service)."""


class AcquireSerializer(serializers.Serializer):
    role = serializers.ChoiceField(choices=Capture.Role.choices)
    z_in_mm = serializers.FloatField(required=False, allow_null=True, help_text="Stage position, mm")
    repeat = serializers.IntegerField(required=False, min_value=0, max_value=1_000_000, default=0)
    exposure = serializers.FloatField(
        required=False, allow_null=True, help_text="Exposure, ms; omitted: the agent's auto-exposure"
    )
    exposures = ExposuresField(required=False, allow_null=True)
    max_exposures = serializers.IntegerField(
        required=False,
        allow_null=True,
        min_value=1,
        max_value=MAX_REQUESTED_EXPOSURES,
        help_text='Most exposures of the automatic bracket (exposures "auto"); omitted: the agent\'s --max-exposures',
    )
    codec = serializers.JSONField(
        required=False,
        allow_null=True,
        help_text="gcps-v1, gcps-v1:WIDTHxHEIGHT or a gcps-codec/1 object; omitted: the rig's default codec",
    )
    session = serializers.IntegerField(required=False, allow_null=True, min_value=1, max_value=MAX_ID)


def acquisition_data(acquisition: Acquisition) -> dict[str, Any]:
    """An acquisition as the API and the agent see it."""
    job = acquisition.job
    codec = services.codec_of(acquisition)
    stored = services.stored_codec_value(acquisition)
    return {
        "id": acquisition.pk,
        "rig": acquisition.rig_id,
        "session": acquisition.session_id,
        "role": acquisition.role,
        "z_in_mm": acquisition.z_in_mm,
        "repeat": acquisition.repeat,
        "exposure_ms": acquisition.exposure_ms,
        "exposures": acquisition.exposures,
        "max_exposures": acquisition.max_exposures,
        "codec": stored if isinstance(stored, dict) else codec.spec,
        "frame_names": list(codec.frame_names),
        "projector": {"width": codec.width, "height": codec.height},
        "job": job.pk,
        "status": job.status,
        "progress": job.progress,
        "phase": job.phase,
        "error": job.error,
        "agent": acquisition.agent_id,
        "capture": acquisition.capture_id,
        "frames": acquisition.frames,
        "rig_geometry": acquisition.rig.rig_file(),
        "created_at": acquisition.created_at,
    }


def agent_data(agent: Agent | None) -> dict[str, Any]:
    if agent is None:
        return {"connected": False}
    return {
        "connected": agent.disconnected_at is None,
        "id": agent.pk,
        "name": agent.name,
        "camera": agent.camera,
        "software_version": agent.software_version,
        "connected_at": agent.connected_at,
        "last_seen_at": agent.last_seen_at,
        "last_seen_seconds": round((timezone.now() - agent.last_seen_at).total_seconds(), 1),
    }


def projector_data(state: ProjectorState) -> dict[str, Any]:
    return {
        "seq": state.seq,
        "kind": state.kind,
        "frame": state.frame,
        "acquisition": state.acquisition_id,
        "shown_seq": state.shown_seq,
        "shown_kind": state.shown_kind,
        "shown_frame": state.shown_frame,
        "shown_at": state.shown_at,
        "screen": state.screen,
        "page_seen_at": state.page_seen_at,
    }


class RigAcquireApi(APIView):
    parser_classes = (BoundedJSONParser, FormParser, MultiPartParser)

    @extend_schema(request=AcquireSerializer, responses={202: dict}, operation_id="rig_captures_acquire")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = AcquireSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        acquisition = services.request_acquisition(
            owner=request.user,
            rig=rig,
            role=data["role"],
            z_in_mm=data.get("z_in_mm"),
            repeat=data.get("repeat", 0),
            exposure_ms=data.get("exposure"),
            exposures=data.get("exposures"),
            max_exposures=data.get("max_exposures"),
            codec=data.get("codec"),
            session_id=data.get("session"),
        )
        acquisition.refresh_from_db()
        body = acquisition_data(acquisition)
        body["agent_connected"] = services.connected_agent(rig) is not None
        return Response(body, status=status.HTTP_202_ACCEPTED)


class AcquisitionDetailApi(APIView):
    @extend_schema(responses=dict, operation_id="acquisitions_retrieve")
    def get(self, request: Request, acquisition_id: int) -> Response:
        acquisition = _get_acquisition(request.user, acquisition_id)
        services.expire_agents(acquisition.rig)
        # read again in one statement: the acquisition's capture and its job's status are committed
        # together, and two reads could see the job done and the capture not yet set
        return Response(acquisition_data(_get_acquisition(request.user, acquisition_id)))


# ----------------------------------------------------------------------------- agent protocol
class RegisterSerializer(serializers.Serializer):
    camera = serializers.CharField(max_length=200)
    name = serializers.CharField(max_length=200, required=False, allow_blank=True, default="")
    software_version = serializers.CharField(max_length=64, required=False, allow_blank=True, default="")


class AgentSessionSerializer(serializers.Serializer):
    session = serializers.UUIDField()
    reason = serializers.CharField(max_length=2000, required=False, allow_blank=True, default="")


class RigAgentApi(APIView):
    @extend_schema(responses=dict, operation_id="rig_agent_status")
    def get(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        agent = services.connected_agent(rig) or Agent.objects.filter(rig=rig).order_by("-connected_at").first()
        return Response(agent_data(agent))


class RigAgentRegisterApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=RegisterSerializer, responses={201: dict}, operation_id="rig_agent_register")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = RegisterSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        agent = services.register_agent(owner=request.user, rig=rig, **serializer.validated_data)
        from django.conf import settings

        body = agent_data(agent) | {
            "session": str(agent.session),
            "heartbeat_seconds": settings.GCPS_AGENT_TIMEOUT_SECONDS / 3,
            "rig_geometry": rig.rig_file(),
        }
        return Response(body, status=status.HTTP_201_CREATED)


def _agent(request: Request, rig, data=None) -> Agent:
    serializer = AgentSessionSerializer(data=data if data is not None else request.data)
    serializer.is_valid(raise_exception=True)
    return services.agent_for_session(owner=request.user, rig=rig, session=serializer.validated_data["session"])


class RigAgentHeartbeatApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=AgentSessionSerializer, responses=dict, operation_id="rig_agent_heartbeat")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        return Response(agent_data(_agent(request, rig)))


class RigAgentDisconnectApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=AgentSessionSerializer, responses=dict, operation_id="rig_agent_disconnect")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        agent = _agent(request, rig)
        reason = str(request.data.get("reason") or "").strip() or "the capture agent disconnected"
        services.disconnect_agent(agent, reason)
        agent.refresh_from_db()
        return Response(agent_data(agent))


class RigAgentTakeApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=AgentSessionSerializer, responses={200: dict, 204: None}, operation_id="rig_agent_take")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        agent = _agent(request, rig)
        acquisition = services.take_acquisition(agent)
        if acquisition is None:
            return Response(status=status.HTTP_204_NO_CONTENT)
        return Response(acquisition_data(acquisition))


class ProgressSerializer(AgentSessionSerializer):
    percent = serializers.IntegerField(min_value=0, max_value=100, required=False, default=0)
    phase = serializers.CharField(max_length=64, required=False, allow_blank=True, default="")
    frames = serializers.JSONField(required=False, allow_null=True)


def _frames(value: Any) -> list | None:
    if value is None or value == "":
        return None
    if isinstance(value, str):
        try:
            value = load_json_text(value)
        except json.JSONDecodeError:
            raise BadInput("frames must be a JSON list of per-frame checks") from None
        except ValueError as exc:
            raise BadInput(f"frames refused: {exc}") from None
    if not isinstance(value, list):
        raise BadInput("frames must be a JSON list of per-frame checks")
    return value


class AcquisitionProgressApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=ProgressSerializer, responses=dict, operation_id="acquisitions_progress")
    def post(self, request: Request, acquisition_id: int) -> Response:
        acquisition = _get_acquisition(request.user, acquisition_id)
        serializer = ProgressSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        agent = services.agent_for_session(owner=request.user, rig=acquisition.rig, session=data["session"])
        services.report_progress(
            agent, acquisition, percent=data["percent"], phase=data["phase"], frames=_frames(data.get("frames"))
        )
        return Response({"ok": True})


class AcquisitionFailApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=ProgressSerializer, responses=dict, operation_id="acquisitions_fail")
    def post(self, request: Request, acquisition_id: int) -> Response:
        acquisition = _get_acquisition(request.user, acquisition_id)
        serializer = ProgressSerializer(data=request.data)  # the schema it documents
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        agent = services.agent_for_session(owner=request.user, rig=acquisition.rig, session=data["session"])
        services.fail_acquisition(agent, acquisition, data["reason"], frames=_frames(data.get("frames")))
        acquisition.job.refresh_from_db()
        return Response(acquisition_data(acquisition))


class AcquisitionUploadSerializer(serializers.Serializer):
    session = serializers.UUIDField()
    file = serializers.FileField(help_text="Zip of the stack, frames named as the codec says")
    camera = serializers.CharField(max_length=200, required=False, allow_blank=True, default="")
    exposure_ms = serializers.FloatField(required=False, allow_null=True)
    frames = serializers.CharField(required=False, allow_blank=True, default="[]", help_text="JSON per-frame checks")


class AcquisitionUploadApi(APIView):
    parser_classes = (MultiPartParser, FormParser)

    @extend_schema(
        request={"multipart/form-data": AcquisitionUploadSerializer},
        responses={201: dict},
        operation_id="acquisitions_upload",
    )
    def post(self, request: Request, acquisition_id: int) -> Response:
        acquisition = _get_acquisition(request.user, acquisition_id)
        serializer = AcquisitionUploadSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        agent = services.agent_for_session(owner=request.user, rig=acquisition.rig, session=data["session"])
        capture = services.store_acquired_capture(
            agent,
            acquisition,
            upload=data["file"],
            camera=data["camera"],
            exposure_ms=data.get("exposure_ms"),
            frames=_frames(data["frames"]) or [],
        )
        acquisition.refresh_from_db()
        acquisition.job.refresh_from_db()
        return Response(acquisition_data(acquisition) | {"capture": capture.pk}, status=status.HTTP_201_CREATED)


# ----------------------------------------------------------------------------- projector
class ShowSerializer(AgentSessionSerializer):
    kind = serializers.ChoiceField(choices=services.PROJECTOR_KINDS)
    frame = serializers.IntegerField(required=False, default=-1, min_value=-1, max_value=MAX_INT32)
    acquisition = serializers.IntegerField(required=False, allow_null=True, min_value=1, max_value=MAX_ID)


class ShownSerializer(serializers.Serializer):
    seq = serializers.IntegerField(min_value=0, max_value=MAX_INT32)
    kind = serializers.CharField(max_length=16)
    frame = serializers.IntegerField(min_value=-1, max_value=MAX_INT32)
    screen = serializers.JSONField(required=False, default=dict)


def _wait_param(request: Request, name: str) -> int | None:
    raw = request.query_params.get(name)
    if raw is None or raw == "":
        return None
    try:
        value = int(raw)
    except ValueError:
        raise BadInput(f"{name} must be an integer, got {raw!r}") from None
    if not -1 <= value <= MAX_INT32:
        raise BadInput(f"{name} must be an integer from -1 to {MAX_INT32}, got {raw!r}")
    return value


class RigProjectorApi(APIView):
    """GET: the state (long-poll with ``after``/``shown`` and ``wait`` seconds); POST (agent): show a pattern."""

    parser_classes = (BoundedJSONParser,)

    @extend_schema(responses=dict, operation_id="rig_projector_state")
    def get(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        after, shown = _wait_param(request, "after"), _wait_param(request, "shown")
        try:
            wait = float(request.query_params.get("wait") or 0)
        except ValueError:
            raise BadInput(f"wait must be a number of seconds, got {request.query_params.get('wait')!r}") from None
        if request.query_params.get("page"):
            services.projector_state(rig)
            services.mark_page_seen(rig)
            services.expire_agents(rig)
        state = services.projector_state(rig)
        response = Response(projector_data(state))
        poll = longpoll.LongPoll.start(rig.pk, seq_above=after, shown_at_least=shown, timeout_s=wait)
        if poll.remaining() > 0 and not poll.reached(state):
            response.long_poll = (poll, state)  # type: ignore[attr-defined]  # waited for by rig_projector
        return response

    @extend_schema(request=ShowSerializer, responses=dict, operation_id="rig_projector_show")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = ShowSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        services.agent_for_session(owner=request.user, rig=rig, session=data["session"])
        acquisition = None
        if data.get("acquisition") is not None:
            acquisition = _get_acquisition(request.user, data["acquisition"])
            if acquisition.rig_id != rig.pk:
                raise BadInput(f"acquisition {acquisition.pk} is not of rig {rig.pk}")
        seq = services.show_on_projector(rig, kind=data["kind"], frame=data["frame"], acquisition=acquisition)
        return Response({"seq": seq})


class RigProjectorShownApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=ShownSerializer, responses=dict, operation_id="rig_projector_shown")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = ShownSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        screen = data.get("screen") if isinstance(data.get("screen"), dict) else {}
        state = services.confirm_shown(rig, seq=data["seq"], kind=data["kind"], frame=data["frame"], screen=screen)
        return Response(projector_data(state))


_rig_projector_api = RigProjectorApi.as_view()


async def rig_projector(request: HttpRequest, rig_id: int) -> HttpResponse:
    """``/api/rigs/{id}/projector/``: :class:`RigProjectorApi`, whose long-poll waits here, on the event loop.

    The DRF view runs first in a thread (authentication, rate limits, permissions, parameters, the
    state as it is now, the same errors and JSON as every endpoint); when it leaves a long-poll to
    wait for, the thread and its database connection are released and the wait is a coroutine
    (:mod:`metrology.acquisition.longpoll`), after which the same response carries the new state.
    """
    response = await sync_to_async(_rig_projector_api)(request, rig_id=rig_id)
    pending = getattr(response, "long_poll", None)
    if pending is not None:
        poll, state = pending
        await sync_to_async(longpoll.release_connection)()
        state = await longpoll.wait(poll, state)
        response.data = projector_data(state)  # a DRF Response, rendered later
    return response


# CSRF is DRF's business (SessionAuthentication checks it on POST); the schema generator finds the
# DRF view through these attributes, as on any APIView.as_view().
rig_projector.csrf_exempt = True  # type: ignore[attr-defined]
rig_projector.cls = RigProjectorApi  # type: ignore[attr-defined]
rig_projector.initkwargs = {}  # type: ignore[attr-defined]
