"""REST endpoints for rigs: POST/GET /api/rigs/, GET /api/rigs/{id}/."""

from __future__ import annotations

from django.conf import settings
from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser, RealNumberField
from metrology.errors import BadInput
from metrology.rigs import selectors, services
from metrology.rigs.models import Rig, RigParameters


@extend_schema_field(
    {
        "oneOf": [
            {"type": "string", "description": "A built-in codec: gcps-v1 or gcps-v1:WIDTHxHEIGHT"},
            {
                "type": "object",
                "description": "A gcps-codec/1 codec file (docs/codecs.md)",
                "additionalProperties": True,
            },
        ],
        "example": "gcps-v1",
    }
)
class CodecField(serializers.JSONField):
    """A codec: a built-in name or a gcps-codec/1 object (validated by the service)."""


class RigInputSerializer(serializers.Serializer):
    """The rig file of docs/file-formats.md; further keys are kept in ``extra``. A pinhole rig file
    (``"model": "pinhole"``, docs/pinhole.md) is read by the core's pinhole model instead."""

    name = serializers.CharField(required=False, allow_blank=True, max_length=200)
    notes = serializers.CharField(required=False, allow_blank=True, max_length=10000)
    L_mm = RealNumberField(help_text="Height of the pupils above the reference plane, mm, > 0")
    d_mm = RealNumberField(help_text="Projector-camera baseline, mm, > 0")
    alpha_rad = RealNumberField(help_text="Projector tilt, rad, in (0, pi/2)")
    fw_mm = RealNumberField(help_text="Camera field width on the reference plane, mm, > 0")
    nlp = serializers.IntegerField(min_value=1, max_value=128, help_text="Light codes across the field")
    width_px = serializers.IntegerField(
        min_value=1, max_value=settings.GCPS_MAX_IMAGE_SIDE_PX, help_text="Camera columns (GCPS_MAX_IMAGE_SIDE_PX)"
    )
    height_px = serializers.IntegerField(
        min_value=1, max_value=settings.GCPS_MAX_IMAGE_SIDE_PX, help_text="Camera rows (GCPS_MAX_IMAGE_SIDE_PX)"
    )
    codec = CodecField(required=False)


class RigHistorySerializer(serializers.ModelSerializer):
    class Meta:
        model = RigParameters
        fields = ("id", "values", "source", "calibration", "procam_calibration", "restored_from", "created_at")


class RigSerializer(serializers.ModelSerializer):
    history = RigHistorySerializer(many=True, read_only=True)

    class Meta:
        model = Rig
        fields = (
            "id",
            "name",
            "notes",
            "model",
            "L_mm",
            "d_mm",
            "alpha_rad",
            "fw_mm",
            "nlp",
            "width_px",
            "height_px",
            "extra",
            "codec",
            "pinhole",
            "created_at",
            "updated_at",
            "history",
        )
        read_only_fields = fields


class RigSummarySerializer(serializers.ModelSerializer):
    """A rig in a list: its geometry, without ``extra`` and ``history`` (see the rig's own URL)."""

    class Meta:
        model = Rig
        fields = tuple(name for name in RigSerializer.Meta.fields if name not in ("extra", "history", "pinhole"))
        read_only_fields = fields


class RigListCreateApi(APIView):
    @extend_schema(responses=RigSummarySerializer(many=True), operation_id="rigs_list")
    def get(self, request: Request) -> Response:
        return Response(RigSummarySerializer(selectors.rigs_for(request.user), many=True).data)

    @extend_schema(request=RigInputSerializer, responses={201: RigSerializer}, operation_id="rigs_create")
    def post(self, request: Request) -> Response:
        if not isinstance(request.data, dict):
            raise serializers.ValidationError({"non_field_errors": ["Send the rig as a JSON object."]})
        if request.data.get("model") == "pinhole":  # a pinhole rig file (docs/pinhole.md)
            rig = services.create_pinhole_rig(owner=request.user, data=dict(request.data))
            return Response(RigSerializer(rig).data, status=status.HTTP_201_CREATED)
        if request.data.get("model", "crossed_axes") != "crossed_axes":
            raise BadInput(f"model must be crossed_axes or pinhole, got {request.data.get('model')!r}")
        serializer = RigInputSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        extra = {key: value for key, value in request.data.items() if key not in serializer.fields and key != "model"}
        rig = services.create_rig(owner=request.user, data={**extra, **serializer.validated_data})
        return Response(RigSerializer(rig).data, status=status.HTTP_201_CREATED)


class RigDetailApi(APIView):
    @extend_schema(responses=RigSerializer, operation_id="rigs_retrieve")
    def get(self, request: Request, rig_id: int) -> Response:
        return Response(RigSerializer(selectors.get_rig(request.user, rig_id)).data)


class RigHistoryRestoreApi(APIView):
    """Make an earlier history entry the rig's current values again (a new ``restored`` entry)."""

    @extend_schema(request=None, responses=RigSerializer, operation_id="rigs_history_restore")
    def post(self, request: Request, rig_id: int, entry_id: int) -> Response:
        rig = services.restore_rig_entry(rig=selectors.get_rig(request.user, rig_id), entry_id=entry_id)
        return Response(RigSerializer(selectors.get_rig(request.user, rig.pk)).data)


class RigCodecSerializer(serializers.Serializer):
    codec = CodecField(help_text="Default codec of the rig's captures (uploads without their own codec.json)")


class RigCodecApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(responses=RigCodecSerializer, operation_id="rigs_codec_retrieve")
    def get(self, request: Request, rig_id: int) -> Response:
        return Response({"codec": selectors.get_rig(request.user, rig_id).codec})

    @extend_schema(request=RigCodecSerializer, responses=RigCodecSerializer, operation_id="rigs_codec_update")
    def put(self, request: Request, rig_id: int) -> Response:
        rig = selectors.get_rig(request.user, rig_id)
        if not isinstance(request.data, dict):
            raise serializers.ValidationError({"non_field_errors": ['Send {"codec": ...} as a JSON object.']})
        serializer = RigCodecSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        rig = services.set_rig_codec(rig=rig, codec=serializer.validated_data["codec"])
        return Response({"codec": rig.codec})
