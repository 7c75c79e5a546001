"""REST endpoints for rigs: POST/GET /api/rigs/, GET /api/rigs/{id}/ (a rig file of any model)."""

from __future__ import annotations

from django.conf import settings
from drf_spectacular.utils import extend_schema, extend_schema_field
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser, RealNumberField
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
    """A rig file (its schema, for the API's documentation; the core validates every value): the flat
    crossed-axes values of docs/file-formats.md (further keys kept in ``extra``), or a rig file
    with ``model`` (``"pinhole"``: docs/pinhole.md), plus the optional ``name``, ``notes``, ``codec``."""

    name = serializers.CharField(required=False, allow_blank=True, max_length=200)
    notes = serializers.CharField(required=False, allow_blank=True, max_length=10000)
    model = serializers.CharField(required=False, help_text="The geometric model (default crossed_axes)")
    L_mm = RealNumberField(required=False, help_text="crossed_axes: height of the pupils above the reference plane, mm")
    d_mm = RealNumberField(required=False, help_text="crossed_axes: projector-camera baseline, mm, > 0")
    alpha_rad = RealNumberField(required=False, help_text="crossed_axes: projector tilt, rad, in (0, pi/2)")
    fw_mm = RealNumberField(required=False, help_text="crossed_axes: camera field width on the reference plane, mm")
    nlp = serializers.IntegerField(required=False, min_value=1, max_value=128, help_text="crossed_axes: light codes")
    width_px = serializers.IntegerField(
        required=False, min_value=1, max_value=settings.GCPS_MAX_IMAGE_SIDE_PX, help_text="crossed_axes: camera columns"
    )
    height_px = serializers.IntegerField(
        required=False, min_value=1, max_value=settings.GCPS_MAX_IMAGE_SIDE_PX, help_text="crossed_axes: camera rows"
    )
    camera = serializers.JSONField(required=False, help_text="pinhole: width_px, height_px, K, dist")
    projector = serializers.JSONField(required=False, help_text="pinhole: width, height, K, dist (gamma, response)")
    R = serializers.JSONField(required=False, help_text="pinhole: rotation, X_p = R X_c + T")
    T = serializers.JSONField(required=False, help_text="pinhole: translation, mm")
    codec = CodecField(required=False)


class RigHistorySerializer(serializers.ModelSerializer):
    class Meta:
        model = RigParameters
        fields = ("id", "values", "source", "calibration", "procam_calibration", "restored_from", "created_at")


class LegacyValue(serializers.Field):
    """A key the rigs API answered before rigs stored their model's parameters
    (:meth:`~metrology.rigs.models.Rig.legacy_values`), read-only."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(source="*", read_only=True, **kwargs)  # type: ignore[arg-type]

    def to_representation(self, value: Rig) -> object:
        return value.legacy_values()[str(self.field_name)]


@extend_schema_field({"type": "number", "nullable": True})
class LegacyNumber(LegacyValue):
    """A crossed-axes value; null for a model without it."""


@extend_schema_field({"type": "integer", "nullable": True})
class LegacyInteger(LegacyValue):
    """An integer crossed-axes value (null for a model without it), or the camera's size."""


@extend_schema_field({"type": "object", "nullable": True, "additionalProperties": True})
class LegacyRigFile(LegacyValue):
    """A pinhole rig's file (docs/pinhole.md); null for another model."""


class RigSerializer(serializers.ModelSerializer):
    """A rig: its model and parameters, and the keys the API answered before (the crossed-axes
    values at the top level, null for a model without them; ``pinhole``, a pinhole rig's file)."""

    history = RigHistorySerializer(many=True, read_only=True)
    L_mm = LegacyNumber()
    d_mm = LegacyNumber()
    alpha_rad = LegacyNumber()
    fw_mm = LegacyNumber()
    nlp = LegacyInteger()
    width_px = LegacyInteger()
    height_px = LegacyInteger()
    pinhole = LegacyRigFile()

    class Meta:
        model = Rig
        fields: tuple[str, ...] = (
            "id",
            "name",
            "notes",
            "model",
            "parameters",
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
        read_only_fields: tuple[str, ...] = fields


RIG_DETAIL_ONLY: tuple[str, ...] = ("extra", "history", "pinhole")
"""Fields of a rig's own URL that a list leaves out (``pinhole`` is the legacy key of a pinhole rig's file)."""


class RigSummarySerializer(RigSerializer):
    """A rig in a list: its values, without ``extra``, ``history`` and ``pinhole`` (see the rig's own URL)."""

    pinhole = None  # type: ignore[assignment]

    class Meta(RigSerializer.Meta):
        fields: tuple[str, ...] = tuple(name for name in RigSerializer.Meta.fields if name not in RIG_DETAIL_ONLY)
        read_only_fields: tuple[str, ...] = fields


class RigListCreateApi(APIView):
    @extend_schema(responses=RigSummarySerializer(many=True), operation_id="rigs_list")
    def get(self, request: Request) -> Response:
        return Response(RigSummarySerializer(selectors.rigs_for(request.user), many=True).data)

    @extend_schema(request=RigInputSerializer, responses={201: RigSerializer}, operation_id="rigs_create")
    def post(self, request: Request) -> Response:
        if not isinstance(request.data, dict):
            raise serializers.ValidationError({"non_field_errors": ["Send the rig as a JSON object."]})
        rig = services.create_rig(owner=request.user, data=dict(request.data))
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
