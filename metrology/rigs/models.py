"""A Rig: the seven geometric values of docs/file-formats.md and the history of its calibrated values."""

from __future__ import annotations

from django.conf import settings
from django.db import models

GEOMETRY_FIELDS: tuple[str, ...] = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")


class Rig(models.Model):
    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="rigs")
    name = models.CharField(max_length=200, blank=True)
    notes = models.TextField(blank=True)
    L_mm = models.FloatField(help_text="Height of the pupils above the reference plane, mm")
    d_mm = models.FloatField(help_text="Projector-camera baseline, mm")
    alpha_rad = models.FloatField(help_text="Tilt of the projector sensor plane, rad, in (0, pi/2)")
    fw_mm = models.FloatField(help_text="Camera field width on the reference plane, mm")
    nlp = models.PositiveIntegerField(help_text="Light codes across the field (<= 128)")
    width_px = models.PositiveIntegerField()
    height_px = models.PositiveIntegerField()
    extra = models.JSONField(default=dict, blank=True, help_text="Further keys of the rig file")
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ("id",)

    def __str__(self) -> str:
        return self.name or f"rig {self.pk}"

    def geometry(self) -> dict:
        """The seven values of the rig file."""
        return {name: getattr(self, name) for name in GEOMETRY_FIELDS}

    def to_core(self):
        """The core's frozen :class:`metrology.core.rig.Rig` for these values."""
        from metrology.core.rig import Rig as CoreRig

        return CoreRig.from_dict(self.geometry())


class RigParameters(models.Model):
    """One entry of a rig's history: the geometry it had from ``created_at`` on."""

    class Source(models.TextChoices):
        CREATED = "created", "Created"
        CALIBRATION = "calibration", "Calibration applied"
        MANUAL = "manual", "Edited"

    rig = models.ForeignKey(Rig, on_delete=models.CASCADE, related_name="history")
    values = models.JSONField(help_text="The seven geometric values")
    source = models.CharField(max_length=16, choices=Source.choices)
    calibration = models.ForeignKey(
        "calibrations.Calibration", null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("created_at", "id")
        verbose_name_plural = "rig parameters"

    def __str__(self) -> str:
        return f"{self.rig} {self.source} {self.created_at:%Y-%m-%d %H:%M}"
