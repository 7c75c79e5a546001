"""REST endpoints for characterizations: POST/GET /api/characterizations/, results as JSON and CSV."""

from __future__ import annotations

from django.http import Http404, HttpResponse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema
from rest_framework import serializers, status
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.api_input import BoundedJSONParser, RealNumberField
from metrology.characterizations import selectors, services
from metrology.characterizations.models import Characterization
from metrology.jobs.serializers import JobStateMixin
from metrology.measurements.api import get_rig_for_body


class SeriesPositionSerializer(serializers.Serializer):
    z_in_mm = RealNumberField(help_text="Stage position, mm")
    captures = serializers.ListField(
        child=serializers.IntegerField(min_value=1), max_length=10_000, help_text="Stage capture ids (repeats)"
    )


class CharacterizationRequestSerializer(serializers.Serializer):
    rig = serializers.IntegerField(min_value=1)
    reference = serializers.IntegerField(min_value=1, help_text="Capture of the reference plane")
    series = SeriesPositionSerializer(many=True, required=False, help_text="Stage positions and their captures")
    session = serializers.IntegerField(
        min_value=1, required=False, help_text="Or: a session whose stage captures form the series"
    )
    options = serializers.DictField(required=False, help_text="n_points, rows, patch_px, margin_frac")


class CharacterizationSerializer(JobStateMixin, serializers.ModelSerializer):
    class Meta:
        model = Characterization
        fields = (
            "id",
            "rig",
            "reference",
            "session",
            "series",
            "parameters",
            "options",
            "rig_values",
            "results",
            "overall_mean_error_mm",
            "overall_std_error_mm",
            "created_at",
            *JobStateMixin.JOB_FIELDS,
        )
        read_only_fields = fields


class CharacterizationListCreateApi(APIView):
    parser_classes = (BoundedJSONParser,)

    @extend_schema(responses=CharacterizationSerializer(many=True), operation_id="characterizations_list")
    def get(self, request: Request) -> Response:
        found = selectors.characterizations_for(request.user)[:500]
        return Response(CharacterizationSerializer(found, many=True).data)

    @extend_schema(
        request=CharacterizationRequestSerializer,
        responses={202: CharacterizationSerializer},
        operation_id="characterizations_create",
    )
    def post(self, request: Request) -> Response:
        serializer = CharacterizationRequestSerializer(data=request.data)
        serializer.is_valid(raise_exception=True)
        data = serializer.validated_data
        rig = get_rig_for_body(request.user, data["rig"])
        characterization = services.request_characterization(
            owner=request.user,
            rig=rig,
            reference_id=data["reference"],
            series=[dict(position) for position in data["series"]] if "series" in data else None,
            session_id=data.get("session"),
            options=data.get("options"),
        )
        characterization = selectors.get_characterization(request.user, characterization.pk)
        return Response(CharacterizationSerializer(characterization).data, status=status.HTTP_202_ACCEPTED)


class CharacterizationDetailApi(APIView):
    @extend_schema(responses=CharacterizationSerializer, operation_id="characterizations_retrieve")
    def get(self, request: Request, characterization_id: int) -> Response:
        found = selectors.get_characterization(request.user, characterization_id)
        return Response(CharacterizationSerializer(found).data)


def csv_view(table: str) -> type[APIView]:
    """A view serving one table of a characterization's results as CSV (404 until done)."""
    render = {"positions": services.positions_csv, "test_points": services.test_points_csv}[table]

    class CharacterizationCsvApi(APIView):
        @extend_schema(responses={(200, "text/csv"): OpenApiTypes.STR}, operation_id=f"characterizations_{table}_csv")
        def get(self, request: Request, characterization_id: int) -> HttpResponse:
            found: Characterization = selectors.get_characterization(request.user, characterization_id)
            if found.job.status != "done":
                raise Http404(f"characterization {found.pk} has no results yet: its job is {found.job.status}")
            response = HttpResponse(render(found), content_type="text/csv; charset=utf-8")
            response["Content-Disposition"] = f'attachment; filename="characterization-{found.pk}-{table}.csv"'
            return response

    CharacterizationCsvApi.__name__ = f"Characterization{table.title().replace('_', '')}CsvApi"
    return CharacterizationCsvApi
