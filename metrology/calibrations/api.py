"""REST endpoints for calibrations: POST/GET /api/calibrations/, GET .../{id}/, POST .../{id}/apply/."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser, RealNumberField
from metrology.calibrations import selectors, services
from metrology.calibrations.models import Calibration
from metrology.jobs.serializers import JobStateMixin
from metrology.measurements.api import get_rig_for_body


class CalibrationRequestSerializer(serializers.Serializer):
    rig = serializers.IntegerField(min_value=1)
    reference = serializers.IntegerField(min_value=1, help_text="Capture of the reference plane")
    master = serializers.IntegerField(min_value=1, help_text="Capture of the master block on the reference plane")
    master_height_mm = RealNumberField(help_text="Known height of the master's top face, mm")
    method = serializers.ChoiceField(choices=Calibration.Method.choices, default=Calibration.Method.LSQ.value)
    initial = serializers.DictField(
        child=RealNumberField(), required=False, help_text="Starting values: L_mm, alpha_rad, d_mm"
    )
    options = serializers.DictField(
        required=False,
        help_text="paper: delta_z_mm, m_hat, w, max_iterations; lsq: fit_d, use_floor, max_iterations, tolerance",
    )
    apply = serializers.BooleanField(default=False, help_text="Apply the result to the rig when done")


class CalibrationSerializer(JobStateMixin, serializers.ModelSerializer):
    class Meta:
        model = Calibration
        fields = (
            "id",
            "rig",
            "reference",
            "master",
            "master_height_mm",
            "method",
            "parameters",
            "options",
            "rig_values",
            "iterations",
            "result",
            "apply",
            "applied",
            "applied_at",
            "created_at",
            *JobStateMixin.JOB_FIELDS,
        )
        read_only_fields = fields


class CalibrationListCreateApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(responses=CalibrationSerializer(many=True), operation_id="calibrations_list")
    def get(self, request: Request) -> Response:
        return Response(CalibrationSerializer(selectors.calibrations_for(request.user)[:500], many=True).data)

    @extend_schema(
        request=CalibrationRequestSerializer, responses={202: CalibrationSerializer}, operation_id="calibrations_create"
    )
    def post(self, request: Request) -> Response:
        serializer = CalibrationRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        rig = get_rig_for_body(request.user, data["rig"])
        calibration = services.request_calibration(
            owner=request.user,
            rig=rig,
            reference_id=data["reference"],
            master_id=data["master"],
            master_height_mm=data["master_height_mm"],
            method=data["method"],
            initial=data.get("initial"),
            options=data.get("options"),
            apply=data["apply"],
        )
        calibration = selectors.get_calibration(request.user, calibration.pk)
        return Response(CalibrationSerializer(calibration).data, status=status.HTTP_202_ACCEPTED)


class CalibrationDetailApi(APIView):
    @extend_schema(responses=CalibrationSerializer, operation_id="calibrations_retrieve")
    def get(self, request: Request, calibration_id: int) -> Response:
        return Response(CalibrationSerializer(selectors.get_calibration(request.user, calibration_id)).data)


class CalibrationApplyApi(APIView):
    @extend_schema(request=None, responses=CalibrationSerializer, operation_id="calibrations_apply")
    def post(self, request: Request, calibration_id: int) -> Response:
        calibration = selectors.get_calibration(request.user, calibration_id)
        services.apply_calibration(calibration=calibration)
        return Response(CalibrationSerializer(selectors.get_calibration(request.user, calibration_id)).data)
