"""REST endpoints for measurements: POST/GET /api/measurements/, GET .../{id}/ and its result files."""

from __future__ import annotations

from django.core.files.storage import default_storage
from django.http import Http404, HttpResponse, StreamingHttpResponse
from django.http.response import HttpResponseBase
from django.urls import reverse
from django.utils.html import format_html
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiParameter, OpenApiResponse, extend_schema
from rest_framework import serializers, status
from rest_framework.parsers import FormParser, MultiPartParser
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser
from metrology.errors import BadInput
from metrology.file_serving import storage_file_response
from metrology.jobs.serializers import JobStateMixin
from metrology.measurements import acceptance, derived, selectors, services
from metrology.measurements.models import RESULT_FILES, Measurement
from metrology.rigs.selectors import get_rig

CONTENT_TYPES = {
    "height.npy": "application/octet-stream",
    "height.tiff": "image/tiff",
    "gray_only_height.npy": "application/octet-stream",
    "mesh.ply": "application/octet-stream",
    "mesh.stl": "model/stl",
    "mesh.obj": "model/obj",
    "sigma.npy": "application/octet-stream",
    "points.npy": "application/octet-stream",
    "exposure.npy": "application/octet-stream",
    "pairs.npy": "application/octet-stream",
    "points.e57": "application/octet-stream",
}


class MeasurementRequestSerializer(serializers.Serializer):
    rig = serializers.IntegerField(min_value=1)
    reference = serializers.IntegerField(
        min_value=1,
        required=False,
        allow_null=True,
        help_text="Capture of the reference plane (optional for a pinhole rig: then depths)",
    )
    object = serializers.IntegerField(min_value=1, help_text="Capture of the object")
    options = serializers.JSONField(
        required=False,
        help_text='Pipeline options, e.g. {"decode": {"edge_band_px": 3}} (docs/command-line.md); default the defaults',
    )


class MeasurementSerializer(JobStateMixin, serializers.ModelSerializer):
    files = serializers.SerializerMethodField()

    class Meta:
        model = Measurement
        fields = (
            "id",
            "rig",
            "reference",
            "object",
            "job",
            "status",
            "progress",
            "phase",
            "error",
            "statistics",
            "options",
            "rig_values",
            "timings",
            "software_version",
            "files",
            "created_at",
        )
        read_only_fields = fields

    def get_files(self, measurement: Measurement) -> dict[str, str]:
        """Download paths of the result files, stored or derived on request (none until the job is done)."""
        return {
            name: reverse(f"measurement-{name}", kwargs={"measurement_id": measurement.pk})
            for name in derived.available_files(measurement)
        }


class MeasurementListCreateApi(APIView):
    parser_classes = (BoundedJSONParser, FormParser, MultiPartParser)

    @extend_schema(responses=MeasurementSerializer(many=True), operation_id="measurements_list")
    def get(self, request: Request) -> Response:
        return Response(MeasurementSerializer(selectors.measurements_for(request.user)[:500], many=True).data)

    @extend_schema(
        request=MeasurementRequestSerializer, responses={202: MeasurementSerializer}, operation_id="measurements_create"
    )
    def post(self, request: Request) -> Response:
        serializer = MeasurementRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        rig = get_rig_for_body(request.user, data["rig"])
        measurement = services.request_measurement(
            owner=request.user,
            rig=rig,
            reference_id=data.get("reference"),
            object_id=data["object"],
            options=data.get("options"),
        )
        measurement = selectors.get_measurement(request.user, measurement.pk)
        return Response(MeasurementSerializer(measurement).data, status=status.HTTP_202_ACCEPTED)


def pending_response(request: Request, job, filename: str) -> HttpResponseBase:
    """202: the derived file ``filename`` is being built by ``job`` (failed jobs answer 409 with the reason).

    A browser following a download link (``Accept: text/html``) gets a small page that asks again
    every 2 s (``Refresh``), so the link ends in the download; API clients get JSON and poll the job.
    """
    job_url = reverse("job", args=[job.pk])
    if job.status == job.Status.FAILED:
        return Response({"error": f"{filename} could not be built: {job.error}", "job": job.pk}, status=409)
    headers = {"Location": job_url, "Retry-After": "2"}
    if "text/html" in request.headers.get("Accept", ""):
        page = format_html(
            "<!doctype html><title>Building {0}</title><p>{0} is being built (job {1}, {2}); "
            "this page asks again every 2 seconds and the download starts when it is ready.</p>",
            filename,
            job.pk,
            job.status,
        )
        html = HttpResponse(page, status=202, content_type="text/html; charset=utf-8", headers=headers)
        html["Refresh"] = "2"
        return html
    body = {"job": job.pk, "status": job.status, "job_url": job_url, "detail": f"{filename} is being built"}
    return Response(body, status=202, headers=headers)


def get_rig_for_body(user, rig_id: int):
    """A rig named in a request body: 400 (not 404) when it is not the user's."""
    from django.http import Http404

    try:
        return get_rig(user, rig_id)
    except Http404:
        raise BadInput(f"rig: rig {rig_id} does not exist among yours") from None


class MeasurementDetailApi(APIView):
    @extend_schema(responses=MeasurementSerializer, operation_id="measurements_retrieve")
    def get(self, request: Request, measurement_id: int) -> Response:
        return Response(MeasurementSerializer(selectors.get_measurement(request.user, measurement_id)).data)


ACCEPTANCE_PARAMETERS = [
    OpenApiParameter(
        "test", str, required=True, enum=["flatness", "probing", "spacing"], description="The VDI/VDE 2634-2 test"
    ),
    OpenApiParameter("diameter", float, description="probing: the sphere's calibrated diameter, mm (required)"),
    OpenApiParameter("spacing", float, description="spacing: the calibrated centre distance, mm (required)"),
    OpenApiParameter(
        "min_height", float, description="probing/spacing: pixels this high above the reference are spheres, mm (1)"
    ),
]


class MeasurementAcceptanceApi(APIView):
    @extend_schema(
        parameters=ACCEPTANCE_PARAMETERS,
        responses={
            200: OpenApiResponse(
                OpenApiTypes.OBJECT,
                description="The body of `gcps acceptance --json`: the quantities (mm) with and without the "
                "0.3 % outlier rejection, options, software version, timings; plus the measurement id",
            ),
            409: OpenApiResponse(
                {"$ref": "#/components/schemas/Error"},
                description="The measurement is not done (queued, running or failed): no stored result to fit",
            ),
        },
        operation_id="measurements_acceptance",
        summary="VDI/VDE 2634-2 acceptance of a stored measurement (flatness, probing, spacing)",
    )
    def get(self, request: Request, measurement_id: int) -> Response:
        measurement = selectors.get_measurement(request.user, measurement_id)
        return Response(acceptance.measurement_acceptance(measurement, request.query_params))


class DerivedFilePendingSerializer(serializers.Serializer):
    """202 answer of a result file that a job is building: poll ``job_url``, then ask again."""

    job = serializers.IntegerField(help_text="The derived-file job building it")
    status = serializers.CharField(help_text="The job's status: queued, running, done or failed")
    job_url = serializers.CharField(help_text="GET it until status is done, then download the file again")
    detail = serializers.CharField()


def file_view(filename: str) -> type[APIView]:
    """A view class serving one result file of a measurement (404 until the job is done).

    Stored files and built derived files are sent from the storage
    (:func:`metrology.file_serving.storage_file_response`: ranges, X-Accel-Redirect, presigned S3
    URLs); a derived file not built yet queues its job and answers 202 with the job to poll
    (``Location``, ``Retry-After``); compactly stored points are streamed as the dense ``.npy``.
    """
    field = RESULT_FILES[filename] or filename.replace(".", "_")
    content_type = CONTENT_TYPES[filename]
    operation_id = "measurements_" + filename.replace(".", "_")

    class MeasurementFileApi(APIView):
        @extend_schema(
            responses={
                (200, content_type): OpenApiResponse(
                    OpenApiTypes.BINARY, description="The file (Accept-Ranges: bytes; 206 for a Range request)"
                ),
                (206, content_type): OpenApiResponse(OpenApiTypes.BINARY, description="The requested byte range"),
                202: OpenApiResponse(
                    DerivedFilePendingSerializer,
                    description="A job is building the file: poll the job (Location header), then ask again",
                ),
                302: OpenApiResponse(description="With S3 storage: a short-lived presigned URL of the file"),
                416: OpenApiResponse(description="The range starts past the end of the file"),
            },
            operation_id=operation_id,
        )
        def get(self, request: Request, measurement_id: int) -> HttpResponseBase:
            measurement = selectors.get_measurement(request.user, measurement_id)
            result = derived.open_result_file(measurement, filename)
            attachment = f"measurement-{measurement.pk}-{filename}"
            if result is None:
                job = measurement.job
                raise Http404(f"{filename} of measurement {measurement.pk} is not available: its job is {job.status}")
            if result.chunks is not None:
                response = StreamingHttpResponse(result.chunks, content_type=content_type)
                response["Content-Disposition"] = f'attachment; filename="{attachment}"'
                return response
            assert result.name is not None
            if not result.ready:
                derived.check_buildable(filename)
                job = services.request_derived_file(measurement, filename)
                if job.status != job.Status.DONE or not default_storage.exists(result.name):
                    return pending_response(request, job, filename)
            return storage_file_response(
                request, default_storage, result.name, filename=attachment, content_type=content_type
            )

    MeasurementFileApi.__name__ = f"Measurement{field.title().replace('_', '')}Api"
    return MeasurementFileApi
