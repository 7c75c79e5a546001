"""A Calibration of a rig's geometry on a master block (paper section 4, or least squares)."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class Calibration(models.Model):
    class Method(models.TextChoices):
        PAPER = "paper", "Paper (iterative L and alpha)"
        LSQ = "lsq", "Least squares"

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="calibrations")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="calibrations")
    reference = models.ForeignKey("captures.Capture", on_delete=models.PROTECT, related_name="+")
    master = models.ForeignKey("captures.Capture", on_delete=models.PROTECT, related_name="+")
    master_height_mm = models.FloatField()
    method = models.CharField(max_length=16, choices=Method.choices, default=Method.PAPER)
    parameters = models.JSONField(default=dict, blank=True, help_text="Starting values and options")
    rig_values = models.JSONField(default=dict, blank=True, help_text="Rig geometry before calibration")
    options = models.JSONField(
        default=dict, blank=True, help_text="Pipeline options the result was computed with (decoding included)"
    )
    iterations = models.JSONField(default=list, blank=True, help_text="Every iteration of the fit")
    result = models.JSONField(default=dict, blank=True, help_text="The calibrated values and residuals")
    residual_npy = models.FileField(max_length=300, blank=True, help_text="Residual map of the master, mm (.npy)")
    apply = models.BooleanField(default=False, help_text="Apply the result to the rig when done")
    applied = models.BooleanField(default=False)
    applied_at = models.DateTimeField(null=True, blank=True)
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="calibration")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"calibration {self.pk} ({self.method})"
