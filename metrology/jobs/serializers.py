"""Serializer fields shared by every result that a job produces."""

from __future__ import annotations

from rest_framework import serializers


class JobStateMixin(serializers.Serializer):
    """``status``, ``progress``, ``phase``, ``error``, ``timings``, ``software_version`` of the result's job."""

    status = serializers.CharField(source="job.status", read_only=True, help_text="queued, running, done or failed")
    progress = serializers.IntegerField(source="job.progress", read_only=True, help_text="0-100")
    phase = serializers.CharField(source="job.phase", read_only=True)
    error = serializers.CharField(source="job.error", read_only=True, help_text="Why the job failed")
    timings = serializers.JSONField(source="job.timings", read_only=True, help_text="Seconds per phase")
    software_version = serializers.CharField(source="job.software_version", read_only=True)

    JOB_FIELDS = ("job", "status", "progress", "phase", "error", "timings", "software_version")
