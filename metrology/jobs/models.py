"""A Job records one background run: its state, progress, parameters, timings and failure reason."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class Job(models.Model):
    class Status(models.TextChoices):
        QUEUED = "queued", "Queued"
        RUNNING = "running", "Running"
        DONE = "done", "Done"
        FAILED = "failed", "Failed"

    class Kind(models.TextChoices):
        SIMULATE_CAPTURE = "simulate_capture", "Simulate capture"
        MEASUREMENT = "measurement", "Measurement"
        CALIBRATION = "calibration", "Calibration"
        CHARACTERIZATION = "characterization", "Characterization"
        REPORT = "report", "Characterization report"
        ACQUIRE_CAPTURE = "acquire_capture", "Acquire capture"
        PROCAM_CALIBRATION = "procam_calibration", "Projector-camera calibration"
        DERIVED_FILE = "derived_file", "Derived result file"
        INSPECTION = "inspection", "Inspection against a nominal model"

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="jobs")
    kind = models.CharField(max_length=32, choices=Kind.choices)
    status = models.CharField(max_length=16, choices=Status.choices, default=Status.QUEUED, db_index=True)
    progress = models.PositiveSmallIntegerField(default=0, help_text="0-100")
    phase = models.CharField(max_length=64, blank=True, help_text="What the job is doing now")
    error = models.TextField(blank=True, help_text="Why the job failed, in words")
    parameters = models.JSONField(default=dict, blank=True, help_text="The parameters the job ran with")
    timings = models.JSONField(default=dict, blank=True, help_text="Seconds per phase")
    software_version = models.CharField(max_length=64, blank=True)
    celery_task_id = models.CharField(max_length=64, blank=True)
    attempts = models.PositiveSmallIntegerField(default=0)
    run_token = models.UUIDField(null=True, blank=True, help_text="Identifies the attempt that owns the job")
    created_at = models.DateTimeField(auto_now_add=True)
    started_at = models.DateTimeField(null=True, blank=True)
    heartbeat_at = models.DateTimeField(null=True, blank=True)
    enqueued_at = models.DateTimeField(
        null=True, blank=True, help_text="When the job's message was last sent to the workers"
    )
    finished_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ("-created_at", "-id")
        constraints = (models.CheckConstraint(condition=models.Q(progress__lte=100), name="job_progress_at_most_100"),)

    def __str__(self) -> str:
        return f"job {self.pk} {self.kind} {self.status}"

    @property
    def finished(self) -> bool:
        return self.status in (self.Status.DONE, self.Status.FAILED)
