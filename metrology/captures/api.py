"""REST endpoints for captures: upload a zip stack, simulate one with the virtual rig, list, download."""

from __future__ import annotations

from django.conf import settings
from django.http.response import HttpResponseBase
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiResponse, extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.parsers import FormParser, MultiPartParser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser, RealNumberField
from metrology.captures import selectors, services
from metrology.captures.models import Capture, CaptureSession
from metrology.captures.simulation import DEFAULT_PRESET, PRESETS, preset_options
from metrology.core.scenes import SCENES
from metrology.errors import BadInput
from metrology.file_serving import storage_file_response
from metrology.rigs.selectors import get_rig


class CaptureSerializer(serializers.ModelSerializer):
    status = serializers.SerializerMethodField()

    class Meta:
        model = Capture
        fields = (
            "id",
            "rig",
            "session",
            "role",
            "z_in_mm",
            "repeat",
            "source",
            "status",
            "original_name",
            "checksum_sha256",
            "size_bytes",
            "bit_depth",
            "height_px",
            "width_px",
            "parameters",
            "codec",
            "exposures",
            "job",
            "created_at",
        )
        read_only_fields = fields

    def get_status(self, capture: Capture) -> str:
        """``stored`` once the stack is in storage; else the status of the job producing it."""
        if capture.ready:
            return "stored"
        return capture.job.status if capture.job else "missing"


class CaptureUploadSerializer(serializers.Serializer):
    file = serializers.FileField(
        help_text=(
            "Zip of GC_0..GC_6, PS_0..PS_3 images (.png/.tif/.tiff/.bmp), or of the frames of any codec with its "
            "codec.json (docs/codecs.md); without codec.json the rig's default codec applies"
        )
    )
    role = serializers.ChoiceField(choices=Capture.Role.choices)
    z_in_mm = RealNumberField(required=False, allow_null=True, help_text="Stage position, mm")
    repeat = serializers.IntegerField(required=False, min_value=0, max_value=1_000_000, default=0)
    session = serializers.IntegerField(required=False, allow_null=True, min_value=1, help_text="Capture session id")
    bit_depth = serializers.ChoiceField(
        choices=[8, 16], required=False, allow_null=True, help_text="Declared bit depth; the images must match"
    )


@extend_schema_field(
    {
        "type": "object",
        "properties": {"name": {"type": "string", "enum": list(SCENES), "description": "The scene"}},
        "required": ["name"],
        "additionalProperties": True,
        "description": (
            'The scene in front of the rig: {"name": ..., plus that scene\'s parameters}, e.g. '
            '{"name": "plane", "z_mm": 20.0}, {"name": "sphere", "radius_mm": 50.0}, '
            '{"name": "block", "top_mm": 40.0}, {"name": "stage"} (at the capture\'s z_in_mm). Heights must lie in '
            "the rig's depth range (-L to 0.95 L)."
        ),
        "example": {"name": "sphere", "radius_mm": 50.0},
    }
)
class SceneField(serializers.DictField):
    """A scene: ``{"name": ..., **parameters}`` (metrology.core.scenes)."""


class SimulateSerializer(serializers.Serializer):
    role = serializers.ChoiceField(choices=Capture.Role.choices)
    scene = SceneField()
    preset = serializers.ChoiceField(
        choices=list(PRESETS),
        default=DEFAULT_PRESET,
        help_text=(
            "Camera preset the options start from: realistic (default; 8-bit, 1.5 grey levels of noise, "
            "0.7 px camera blur, 0.15 code projector blur, 3x3 sub-rays, as the dashboard's default) or "
            "noise-free (16-bit, exact)"
        ),
    )
    options = serializers.DictField(
        required=False,
        default=dict,
        help_text=(
            "Simulation options overriding the preset's: bit_depth (8/16), noise_grey, ambient, projector_gain, "
            "projector_gamma, projector_defocus_codes, camera_defocus_px, square, smoothing_codes, "
            "supersample (1-8), seed"
        ),
    )
    z_in_mm = RealNumberField(required=False, allow_null=True)
    repeat = serializers.IntegerField(required=False, min_value=0, max_value=1_000_000, default=0)
    session = serializers.IntegerField(required=False, allow_null=True, min_value=1)


class SimulateResponseSerializer(CaptureSerializer):
    class Meta(CaptureSerializer.Meta):
        pass


class SessionSerializer(serializers.ModelSerializer):
    class Meta:
        model = CaptureSession
        fields = ("id", "rig", "name", "notes", "created_at")
        read_only_fields = ("id", "rig", "created_at")


class RigCapturesApi(APIView):
    parser_classes = (MultiPartParser, FormParser)

    @extend_schema(responses=CaptureSerializer(many=True), operation_id="rig_captures_list")
    def get(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        return Response(CaptureSerializer(selectors.captures_for(request.user, rig), many=True).data)

    @extend_schema(
        request={"multipart/form-data": CaptureUploadSerializer},
        responses={201: CaptureSerializer},
        operation_id="rig_captures_upload",
    )
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        limit = settings.GCPS_MAX_UPLOAD_BYTES
        try:
            length = int(request.META.get("CONTENT_LENGTH") or 0)
        except ValueError:
            length = 0
        if length > limit + 64 * 1024:  # refuse before reading the body
            raise BadInput(f"upload of {length} bytes exceeds the limit of {limit} bytes (GCPS_MAX_UPLOAD_BYTES)")
        serializer = CaptureUploadSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        capture = services.upload_capture(
            owner=request.user,
            rig=rig,
            upload=data["file"],
            role=data["role"],
            z_in_mm=data.get("z_in_mm"),
            repeat=data.get("repeat", 0),
            session_id=data.get("session"),
            bit_depth=data.get("bit_depth"),
        )
        return Response(CaptureSerializer(capture).data, status=status.HTTP_201_CREATED)


class RigCaptureSimulateApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(request=SimulateSerializer, responses={202: CaptureSerializer}, operation_id="rig_captures_simulate")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = SimulateSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        capture = services.request_simulated_capture(
            owner=request.user,
            rig=rig,
            role=data["role"],
            scene=data["scene"],
            options=preset_options(data["preset"], data.get("options")),
            z_in_mm=data.get("z_in_mm"),
            repeat=data.get("repeat", 0),
            session_id=data.get("session"),
        )
        capture.refresh_from_db()
        return Response(CaptureSerializer(capture).data, status=status.HTTP_202_ACCEPTED)


class RigSessionsApi(APIView):
    parser_classes = (BoundedJSONParser, FormParser, MultiPartParser)

    @extend_schema(responses=SessionSerializer(many=True), operation_id="rig_sessions_list")
    def get(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        return Response(SessionSerializer(selectors.sessions_for(request.user, rig), many=True).data)

    @extend_schema(request=SessionSerializer, responses={201: SessionSerializer}, operation_id="rig_sessions_create")
    def post(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = SessionSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        session = services.create_session(owner=request.user, rig=rig, **serializer.validated_data)
        return Response(SessionSerializer(session).data, status=status.HTTP_201_CREATED)


class CaptureDetailApi(APIView):
    @extend_schema(responses=CaptureSerializer, operation_id="captures_retrieve")
    def get(self, request: Request, capture_id: int) -> Response:
        """The capture, with ``codec_check``: the codec self-check of its stored stack (null until stored)."""
        capture = selectors.get_capture(request.user, capture_id)
        return Response({**CaptureSerializer(capture).data, "codec_check": selectors.capture_codec_check(capture)})


class CaptureFileApi(APIView):
    @extend_schema(
        responses={
            (200, "application/zip"): OpenApiResponse(
                OpenApiTypes.BINARY, description="The stack (Accept-Ranges: bytes; 206 for a Range request)"
            ),
            (206, "application/zip"): OpenApiResponse(OpenApiTypes.BINARY, description="The requested byte range"),
            302: OpenApiResponse(description="With S3 storage: a short-lived presigned URL of the file"),
            416: OpenApiResponse(description="The range starts past the end of the file"),
        },
        operation_id="captures_stack_zip",
    )
    def get(self, request: Request, capture_id: int) -> HttpResponseBase:
        capture = selectors.get_capture(request.user, capture_id)
        if not capture.ready:
            assert capture.job is not None, "a capture not stored yet comes from a job (uploads are stored at once)"
            raise BadInput(f"capture {capture.pk} is not stored yet; its job is {capture.job.status}")
        return storage_file_response(
            request,
            capture.file.storage,
            capture.file.name,
            filename=f"capture-{capture.pk}.zip",
            content_type="application/zip",
        )
