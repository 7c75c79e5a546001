"""REST endpoints for projector-camera calibrations (docs/procam-calibration.md, "In the application").

POST/GET /api/procam-calibrations/, GET .../{id}/, POST .../{id}/apply/, GET .../{id}/report.json
(REPORT.json as ``gcps calibrate-procam`` writes it) and .../{id}/rig.json (the pinhole rig file).
"""

from __future__ import annotations

from typing import Any

from django.http import Http404, HttpResponse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser
from metrology.calibrations import procam_services, selectors
from metrology.calibrations.models import ProcamCalibration
from metrology.errors import BadInput
from metrology.jobs.models import Job
from metrology.jobs.serializers import JobStateMixin
from metrology.measurements.api import get_rig_for_body

MAX_ID = 2**31 - 1


class ProcamCalibrationRequestSerializer(serializers.Serializer):
    rig = serializers.IntegerField(min_value=1, max_value=MAX_ID)
    poses = serializers.ListField(
        child=serializers.IntegerField(min_value=1, max_value=MAX_ID),
        max_length=procam_services.MAX_POSES,
        help_text="Board captures (role board) of the rig, one per pose, in order; at least 2 (8 to 12 recommended)",
    )
    board = serializers.CharField(
        max_length=100,
        help_text=(
            "KIND:COLSxROWS:SIZE_MM: chessboard (inner corners), circles or acircles; COLSxROWS is OpenCV's "
            "pattern size, points per row first: a board of 10 x 8 squares is chessboard:9x7:SQUARE_MM"
        ),
    )
    options = serializers.DictField(
        required=False,
        help_text=(
            "window (1..200 px, default automatic), min_decoded (0..1, default 0.25), fix_k3 (bool), "
            "joint (bool, default true: refine both devices' intrinsics with the stereo pose), "
            "min_modulation, min_inverse_contrast (grey levels, default the decoder's)"
        ),
    )
    apply = serializers.BooleanField(default=False, help_text="Make the result the rig's calibration when done")


def _report_value(calibration: ProcamCalibration, key: str) -> Any:
    return (calibration.report or {}).get(key)


class ProcamCalibrationSummarySerializer(JobStateMixin, serializers.ModelSerializer):
    """A procam calibration in a list: its poses, options, the report's headline numbers."""

    poses = serializers.SerializerMethodField(help_text="Pose capture ids, in order")
    board = serializers.CharField(read_only=True)
    camera_rms_px = serializers.SerializerMethodField(help_text="Camera reprojection RMS, px (when done)")
    projector_rms_px = serializers.SerializerMethodField(help_text="Projector reprojection RMS, px (when done)")
    stereo_rms_px = serializers.SerializerMethodField(help_text="Stereo RMS over both devices, px (when done)")
    poses_used = serializers.SerializerMethodField(help_text="Poses the calibration used (when done)")
    warnings = serializers.SerializerMethodField(help_text="The report's warning causes (when done)")

    class Meta:
        model = ProcamCalibration
        fields: tuple[str, ...] = (
            "id",
            "rig",
            "poses",
            "board",
            "options",
            "camera_rms_px",
            "projector_rms_px",
            "stereo_rms_px",
            "poses_used",
            "warnings",
            "apply",
            "applied",
            "applied_at",
            "created_at",
            *JobStateMixin.JOB_FIELDS,
        )
        read_only_fields: tuple[str, ...] = fields

    def get_poses(self, calibration: ProcamCalibration) -> list[int]:
        return selectors.procam_pose_ids(calibration)

    def get_camera_rms_px(self, calibration: ProcamCalibration) -> float | None:
        return _report_value(calibration, "camera_rms_px")

    def get_projector_rms_px(self, calibration: ProcamCalibration) -> float | None:
        return _report_value(calibration, "projector_rms_px")

    def get_stereo_rms_px(self, calibration: ProcamCalibration) -> float | None:
        return _report_value(calibration, "stereo_rms_px")

    def get_poses_used(self, calibration: ProcamCalibration) -> int | None:
        return _report_value(calibration, "poses_used")

    def get_warnings(self, calibration: ProcamCalibration) -> list[str]:
        return [str(w.get("cause")) for w in _report_value(calibration, "warnings") or []]


class ProcamCalibrationSerializer(ProcamCalibrationSummarySerializer):
    """A procam calibration with its report (gcps-procam-report/1), rig file and the rig's state before."""

    class Meta(ProcamCalibrationSummarySerializer.Meta):
        fields = (*ProcamCalibrationSummarySerializer.Meta.fields, "report", "rig_file", "rig_before")
        read_only_fields = fields


class ProcamCalibrationListCreateApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(
        parameters=[OpenApiParameter("rig", int, description="Only this rig's calibrations")],
        responses=ProcamCalibrationSummarySerializer(many=True),
        operation_id="procam_calibrations_list",
    )
    def get(self, request: Request) -> Response:
        rig = None
        if "rig" in request.query_params:
            value = request.query_params["rig"]
            if not value.isdigit() or not 0 < int(value) <= MAX_ID:
                raise BadInput(f"rig: expected a rig id, got {value!r}")
            rig = get_rig_for_body(request.user, int(value))
        calibrations = selectors.procam_calibrations_for(request.user, rig)[:500]
        return Response(ProcamCalibrationSummarySerializer(calibrations, many=True).data)

    @extend_schema(
        request=ProcamCalibrationRequestSerializer,
        responses={202: ProcamCalibrationSerializer},
        operation_id="procam_calibrations_create",
    )
    def post(self, request: Request) -> Response:
        serializer = ProcamCalibrationRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        rig = get_rig_for_body(request.user, data["rig"])
        calibration = procam_services.request_procam_calibration(
            owner=request.user,
            rig=rig,
            pose_ids=data["poses"],
            board=data["board"],
            options=data.get("options"),
            apply=data["apply"],
        )
        calibration = selectors.get_procam_calibration(request.user, calibration.pk)
        return Response(ProcamCalibrationSerializer(calibration).data, status=status.HTTP_202_ACCEPTED)


class ProcamCalibrationDetailApi(APIView):
    @extend_schema(responses=ProcamCalibrationSerializer, operation_id="procam_calibrations_retrieve")
    def get(self, request: Request, calibration_id: int) -> Response:
        return Response(
            ProcamCalibrationSerializer(selectors.get_procam_calibration(request.user, calibration_id)).data
        )


class ProcamCalibrationApplyApi(APIView):
    @extend_schema(request=None, responses=ProcamCalibrationSerializer, operation_id="procam_calibrations_apply")
    def post(self, request: Request, calibration_id: int) -> Response:
        calibration = selectors.get_procam_calibration(request.user, calibration_id)
        procam_services.apply_procam_calibration(calibration=calibration)
        return Response(
            ProcamCalibrationSerializer(selectors.get_procam_calibration(request.user, calibration_id)).data
        )


def _done(calibration: ProcamCalibration, what: str) -> None:
    if calibration.job.status != Job.Status.DONE:
        raise Http404(
            f"{what} of procam calibration {calibration.pk} is not available: its job is {calibration.job.status}"
        )


def _json_file(text: str, filename: str) -> HttpResponse:
    response = HttpResponse(text, content_type="application/json")
    response["Content-Disposition"] = f'attachment; filename="{filename}"'
    return response


class ProcamCalibrationReportApi(APIView):
    @extend_schema(
        responses={(200, "application/json"): OpenApiTypes.OBJECT}, operation_id="procam_calibrations_report_json"
    )
    def get(self, request: Request, calibration_id: int) -> HttpResponse:
        """REPORT.json (gcps-procam-report/1) exactly as ``gcps calibrate-procam --report`` writes it."""
        calibration = selectors.get_procam_calibration(request.user, calibration_id)
        _done(calibration, "report.json")
        return _json_file(calibration.report_json, f"procam-calibration-{calibration.pk}-report.json")


class ProcamCalibrationRigFileApi(APIView):
    @extend_schema(
        responses={(200, "application/json"): OpenApiTypes.OBJECT}, operation_id="procam_calibrations_rig_json"
    )
    def get(self, request: Request, calibration_id: int) -> HttpResponse:
        """The calibrated pinhole rig file (docs/pinhole.md) exactly as ``gcps calibrate-procam --out`` writes it."""
        from metrology.core.geometry import model_from_dict

        calibration = selectors.get_procam_calibration(request.user, calibration_id)
        _done(calibration, "rig.json")
        if not calibration.rig_file:
            raise Http404(f"procam calibration {calibration.pk} has no rig file")
        text = model_from_dict(calibration.rig_file).to_json()
        return _json_file(text, f"procam-calibration-{calibration.pk}-rig.json")
