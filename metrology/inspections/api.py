"""REST endpoints for inspections: nominal models (upload, list, delete), inspections of measurements
(request, read, deviations.npy, deviations.ply, report.html) and a rig's inspection plan."""

from __future__ import annotations

from django.conf import settings
from django.core.files.storage import default_storage
from django.http import Http404
from django.http.response import HttpResponseBase
from django.urls import reverse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiResponse, extend_schema
from rest_framework import serializers, status
from rest_framework.parsers import FormParser, MultiPartParser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser
from metrology.errors import BadInput
from metrology.file_serving import storage_file_response
from metrology.inspections import selectors, services
from metrology.inspections.models import Inspection, InspectionPlan, NominalModel
from metrology.jobs.serializers import JobStateMixin
from metrology.measurements.selectors import get_measurement
from metrology.rigs.selectors import get_rig


class NominalSerializer(serializers.ModelSerializer):
    class Meta:
        model = NominalModel
        fields = (
            "id",
            "name",
            "file_format",
            "tessellation",
            "sha256",
            "size_bytes",
            "triangle_count",
            "units",
            "summary",
            "created_at",
        )
        read_only_fields = fields


class NominalUploadSerializer(serializers.Serializer):
    file = serializers.FileField(
        help_text="A triangle mesh in mm (binary or ASCII STL, PLY or OBJ) or a STEP file (.step, .stp; "
        "tessellated at upload, needs the server's optional cadquery-ocp)"
    )
    name = serializers.CharField(required=False, max_length=200, help_text="A name (default: the file's)")


class InspectionSerializer(JobStateMixin, serializers.ModelSerializer):
    files = serializers.SerializerMethodField()

    class Meta:
        model = Inspection
        fields = (
            "id",
            "measurement",
            "nominal",
            "plan",
            "job",
            "status",
            "progress",
            "phase",
            "error",
            "options",
            "report",
            "timings",
            "software_version",
            "files",
            "created_at",
        )
        read_only_fields = fields

    def get_files(self, inspection: Inspection) -> dict[str, str]:
        """Download paths of the result files (none until the job is done)."""
        if not inspection.deviations_npy:
            return {}
        return {
            "deviations.npy": reverse("inspection-deviations", kwargs={"inspection_id": inspection.pk}),
            "deviations.ply": reverse("inspection-deviations-ply", kwargs={"inspection_id": inspection.pk}),
            "report.html": reverse("dashboard:inspection-report", kwargs={"inspection_id": inspection.pk}),
        }


OPTIONS_HELP = (
    'Inspection options (docs/inspection.md), e.g. {"init": "auto", "tolerance_mm": 0.05, "k": 2}; default the defaults'
)


class InspectionRequestSerializer(serializers.Serializer):
    measurement = serializers.IntegerField(min_value=1, help_text="A finished measurement")
    nominal = serializers.IntegerField(min_value=1, help_text="A nominal model")
    options = serializers.JSONField(required=False, help_text=OPTIONS_HELP)


class PlanSerializer(serializers.ModelSerializer):
    class Meta:
        model = InspectionPlan
        fields = ("id", "rig", "nominal", "options", "active", "created_at", "updated_at")
        read_only_fields = fields


class PlanRequestSerializer(serializers.Serializer):
    nominal = serializers.IntegerField(min_value=1)
    options = serializers.JSONField(required=False, help_text=OPTIONS_HELP)
    active = serializers.BooleanField(required=False, default=True)


def _owned(getter, user, pk: int, field: str):
    """A record named in a request body: 400 (not 404) when it is not the user's."""
    try:
        return getter(user, pk)
    except Http404:
        raise BadInput(f"{field}: {field} {pk} does not exist among yours") from None


class NominalListCreateApi(APIView):
    parser_classes = (MultiPartParser, FormParser)

    @extend_schema(responses=NominalSerializer(many=True), operation_id="nominals_list")
    def get(self, request: Request) -> Response:
        return Response(NominalSerializer(selectors.nominals_for(request.user)[:500], many=True).data)

    @extend_schema(
        request={"multipart/form-data": NominalUploadSerializer},
        responses={201: NominalSerializer},
        operation_id="nominals_upload",
    )
    def post(self, request: Request) -> Response:
        limit = settings.GCPS_MAX_UPLOAD_BYTES
        try:
            length = int(request.META.get("CONTENT_LENGTH") or 0)
        except ValueError:
            length = 0
        if length > limit + 64 * 1024:  # refuse before reading the body
            raise BadInput(f"upload of {length} bytes exceeds the limit of {limit} bytes (GCPS_MAX_UPLOAD_BYTES)")
        serializer = NominalUploadSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        nominal = services.upload_nominal(owner=request.user, upload=data["file"], name=data.get("name"))
        return Response(NominalSerializer(nominal).data, status=status.HTTP_201_CREATED)


class NominalDetailApi(APIView):
    @extend_schema(responses=NominalSerializer, operation_id="nominals_retrieve")
    def get(self, request: Request, nominal_id: int) -> Response:
        return Response(NominalSerializer(selectors.get_nominal(request.user, nominal_id)).data)

    @extend_schema(responses={204: None}, operation_id="nominals_destroy")
    def delete(self, request: Request, nominal_id: int) -> Response:
        services.delete_nominal(selectors.get_nominal(request.user, nominal_id))
        return Response(status=status.HTTP_204_NO_CONTENT)


class NominalFileApi(APIView):
    @extend_schema(
        responses={(200, "application/octet-stream"): OpenApiResponse(OpenApiTypes.BINARY)},
        operation_id="nominals_file",
    )
    def get(self, request: Request, nominal_id: int) -> HttpResponseBase:
        nominal = selectors.get_nominal(request.user, nominal_id)
        return storage_file_response(
            request,
            default_storage,
            nominal.file.name,
            filename=f"nominal-{nominal.pk}.{nominal.file_format}",
            content_type="application/octet-stream",
        )


class InspectionListCreateApi(APIView):
    parser_classes = (BoundedJSONParser, FormParser, MultiPartParser)

    @extend_schema(responses=InspectionSerializer(many=True), operation_id="inspections_list")
    def get(self, request: Request) -> Response:
        return Response(InspectionSerializer(selectors.inspections_for(request.user)[:500], many=True).data)

    @extend_schema(
        request=InspectionRequestSerializer, responses={202: InspectionSerializer}, operation_id="inspections_create"
    )
    def post(self, request: Request) -> Response:
        serializer = InspectionRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        measurement = _owned(get_measurement, request.user, data["measurement"], "measurement")
        nominal = _owned(selectors.get_nominal, request.user, data["nominal"], "nominal")
        inspection = services.request_inspection(
            owner=request.user, measurement=measurement, nominal=nominal, options=data.get("options")
        )
        inspection = selectors.get_inspection(request.user, inspection.pk)
        return Response(InspectionSerializer(inspection).data, status=status.HTTP_202_ACCEPTED)


class InspectionDetailApi(APIView):
    @extend_schema(responses=InspectionSerializer, operation_id="inspections_retrieve")
    def get(self, request: Request, inspection_id: int) -> Response:
        return Response(InspectionSerializer(selectors.get_inspection(request.user, inspection_id)).data)


def _finished(request: Request, inspection_id: int) -> Inspection:
    """The user's inspection ``inspection_id`` once it has deviations (404 naming its job's status before)."""
    inspection = selectors.get_inspection(request.user, inspection_id)
    if not inspection.deviations_npy:
        raise Http404(f"inspection {inspection.pk} has no deviations: its job is {inspection.job.status}")
    return inspection


class InspectionDeviationsApi(APIView):
    @extend_schema(
        responses={(200, "application/octet-stream"): OpenApiResponse(OpenApiTypes.BINARY)},
        operation_id="inspections_deviations_npy",
        summary="Signed deviations (H, W) float32 mm, NaN where no point (positive outside the material)",
    )
    def get(self, request: Request, inspection_id: int) -> HttpResponseBase:
        inspection = _finished(request, inspection_id)
        return storage_file_response(
            request,
            default_storage,
            inspection.deviations_npy.name,
            filename=f"inspection-{inspection.pk}-deviations.npy",
            content_type="application/octet-stream",
        )


class InspectionDeviationsPlyApi(APIView):
    @extend_schema(
        responses={(200, "application/octet-stream"): OpenApiResponse(OpenApiTypes.BINARY)},
        operation_id="inspections_deviations_ply",
        summary="The points with a deviation in the nominal's frame (mm): deviation_mm and, when known, sigma_mm",
    )
    def get(self, request: Request, inspection_id: int) -> HttpResponseBase:
        inspection = _finished(request, inspection_id)
        return storage_file_response(
            request,
            default_storage,
            services.deviations_ply(inspection),
            filename=f"inspection-{inspection.pk}-deviations.ply",
            content_type="application/octet-stream",
        )


class RigInspectionPlanApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(responses=PlanSerializer, operation_id="rig_inspection_plan_retrieve")
    def get(self, request: Request, rig_id: int) -> Response:
        plan = selectors.plan_of_rig(get_rig(request.user, rig_id))
        if plan is None:
            raise Http404(f"rig {rig_id} has no inspection plan")
        return Response(PlanSerializer(plan).data)

    @extend_schema(request=PlanRequestSerializer, responses=PlanSerializer, operation_id="rig_inspection_plan_set")
    def put(self, request: Request, rig_id: int) -> Response:
        rig = get_rig(request.user, rig_id)
        serializer = PlanRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        nominal = _owned(selectors.get_nominal, request.user, data["nominal"], "nominal")
        plan = services.set_plan(
            owner=request.user, rig=rig, nominal=nominal, options=data.get("options"), active=data["active"]
        )
        return Response(PlanSerializer(plan).data)

    @extend_schema(responses={204: None}, operation_id="rig_inspection_plan_destroy")
    def delete(self, request: Request, rig_id: int) -> Response:
        plan = selectors.plan_of_rig(get_rig(request.user, rig_id))
        if plan is None:
            raise Http404(f"rig {rig_id} has no inspection plan")
        services.delete_plan(plan)
        return Response(status=status.HTTP_204_NO_CONTENT)
