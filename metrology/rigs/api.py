"""REST endpoints for rigs: POST/GET /api/rigs/, GET /api/rigs/{id}/."""

from __future__ import annotations

from django.conf import settings
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import RealNumberField
from metrology.rigs import selectors, services
from metrology.rigs.models import Rig, RigParameters


class RigInputSerializer(serializers.Serializer):
    """The rig file of docs/file-formats.md; further keys are kept in ``extra``."""

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


class RigHistorySerializer(serializers.ModelSerializer):
    class Meta:
        model = RigParameters
        fields = ("values", "source", "calibration", "created_at")


class RigSerializer(serializers.ModelSerializer):
    history = RigHistorySerializer(many=True, read_only=True)

    class Meta:
        model = Rig
        fields = (
            "id",
            "name",
            "notes",
            "L_mm",
            "d_mm",
            "alpha_rad",
            "fw_mm",
            "nlp",
            "width_px",
            "height_px",
            "extra",
            "created_at",
            "updated_at",
            "history",
        )
        read_only_fields = fields


class RigSummarySerializer(serializers.ModelSerializer):
    """A rig in a list: its geometry, without ``extra`` and ``history`` (see the rig's own URL)."""

    class Meta:
        model = Rig
        fields = tuple(name for name in RigSerializer.Meta.fields if name not in ("extra", "history"))
        read_only_fields = fields


class RigListCreateApi(APIView):
    @extend_schema(responses=RigSummarySerializer(many=True), operation_id="rigs_list")
    def get(self, request: Request) -> Response:
        return Response(RigSummarySerializer(selectors.rigs_for(request.user), many=True).data)

    @extend_schema(request=RigInputSerializer, responses={201: RigSerializer}, operation_id="rigs_create")
    def post(self, request: Request) -> Response:
        if not isinstance(request.data, dict):
            raise serializers.ValidationError({"non_field_errors": ["Send the rig as a JSON object."]})
        serializer = RigInputSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        extra = {key: value for key, value in request.data.items() if key not in serializer.fields}
        rig = services.create_rig(owner=request.user, data={**extra, **serializer.validated_data})
        return Response(RigSerializer(rig).data, status=status.HTTP_201_CREATED)


class RigDetailApi(APIView):
    @extend_schema(responses=RigSerializer, operation_id="rigs_retrieve")
    def get(self, request: Request, rig_id: int) -> Response:
        return Response(RigSerializer(selectors.get_rig(request.user, rig_id)).data)
