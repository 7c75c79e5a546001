"""A Characterization of a rig's linearity and accuracy with a plane moved along Z (paper section 5)."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class Characterization(models.Model):
    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="characterizations")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="characterizations")
    reference = models.ForeignKey("captures.Capture", on_delete=models.PROTECT, related_name="+")
    session = models.ForeignKey(
        "captures.CaptureSession", null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    series = models.JSONField(
        default=list, help_text='Stage positions: [{"z_in_mm": 4.0, "captures": [capture ids]}, ...]'
    )
    parameters = models.JSONField(default=dict, blank=True)
    rig_values = models.JSONField(default=dict, blank=True)
    options = models.JSONField(
        default=dict, blank=True, help_text="Pipeline options the result was computed with (decoding included)"
    )
    results = models.JSONField(default=dict, blank=True, help_text="Every figure of the paper's section 5")
    overall_mean_error_mm = models.FloatField(null=True, blank=True)
    overall_std_error_mm = models.FloatField(null=True, blank=True)
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="characterization")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"characterization {self.pk}"
