"""A Report: one characterization of a rig rendered as a self-contained HTML page, with drift.

Reports are produced on demand (``manage.py characterization_report``) or on a schedule: Celery beat
with django-celery-beat's DatabaseScheduler runs ``metrology.reports.tasks.scheduled_characterization_report``
from a ``PeriodicTask`` (editable in the admin) made by :func:`metrology.reports.services.schedule_report`.
"""

from __future__ import annotations

from django.conf import settings
from django.db import models


class Report(models.Model):
    class Source(models.TextChoices):
        VIRTUAL_STAGE = "virtual_stage", "Virtual stage"
        UPLOADED_SERIES = "uploaded_series", "Uploaded series"

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="reports")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="reports")
    source = models.CharField(max_length=16, choices=Source.choices)
    parameters = models.JSONField(
        default=dict, blank=True, help_text="Stage range, repeats, noise, drift tolerances the report ran with"
    )
    session = models.ForeignKey(
        "captures.CaptureSession",
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
        help_text="The stage series characterized (simulated for a virtual stage)",
    )
    characterization = models.ForeignKey(
        "characterizations.Characterization",
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="reports",
    )
    html = models.FileField(max_length=300, blank=True, help_text="The self-contained HTML report")
    summary = models.JSONField(
        default=dict, blank=True, help_text="Overall figures, per-position errors, rig parameters, software version"
    )
    drift = models.JSONField(default=dict, blank=True, help_text="Changes against the previous report of the rig")
    previous = models.ForeignKey(
        "self", null=True, blank=True, on_delete=models.SET_NULL, related_name="+", help_text="Compared against"
    )
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="report")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")
        indexes = (models.Index(fields=["rig", "-created_at"]),)

    def __str__(self) -> str:
        return f"report {self.pk} of {self.rig}"

    @property
    def ready(self) -> bool:
        return bool(self.html)

    @property
    def drifted(self) -> list[str]:
        """Labels of the figures that moved beyond their tolerance since the previous report."""
        return [item["label"] for item in self.drift.get("items", []) if item.get("beyond")]
