"""REST endpoints for jobs: GET /api/jobs/, GET /api/jobs/{id}/ (status, progress, error)."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema
from rest_framework import serializers
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from metrology.jobs import selectors
from metrology.jobs.models import Job


class JobSerializer(serializers.ModelSerializer):
    class Meta:
        model = Job
        fields = (
            "id",
            "kind",
            "status",
            "progress",
            "phase",
            "error",
            "parameters",
            "timings",
            "software_version",
            "attempts",
            "created_at",
            "started_at",
            "heartbeat_at",
            "finished_at",
        )
        read_only_fields = fields


class JobListApi(APIView):
    @extend_schema(responses=JobSerializer(many=True), operation_id="jobs_list")
    def get(self, request: Request) -> Response:
        return Response(JobSerializer(selectors.jobs_for(request.user)[:200], many=True).data)


class JobDetailApi(APIView):
    @extend_schema(responses=JobSerializer, operation_id="jobs_retrieve")
    def get(self, request: Request, job_id: int) -> Response:
        return Response(JobSerializer(selectors.get_job(request.user, job_id)).data)
