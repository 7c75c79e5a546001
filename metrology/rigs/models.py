"""A Rig: the seven geometric values of docs/file-formats.md and the history of its calibrated values."""

from __future__ import annotations

from django.conf import settings
from django.db import models

GEOMETRY_FIELDS: tuple[str, ...] = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")

DEFAULT_CODEC = "gcps-v1"
"""A rig's default codec: the paper's eleven named patterns (docs/codecs.md)."""


def default_codec() -> str:
    return DEFAULT_CODEC


class Rig(models.Model):
    class Model(models.TextChoices):
        CROSSED_AXES = "crossed_axes", "Crossed optical axes (the paper's model)"
        PINHOLE = "pinhole", "Calibrated pinhole camera and projector"

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="rigs")
    name = models.CharField(max_length=200, blank=True)
    notes = models.TextField(blank=True)
    model = models.CharField(max_length=16, choices=Model.choices, default=Model.CROSSED_AXES)
    pinhole = models.JSONField(null=True, blank=True, help_text="The pinhole rig file (model pinhole)")
    L_mm = models.FloatField(null=True, blank=True, help_text="Height of the pupils above the reference plane, mm")
    d_mm = models.FloatField(null=True, blank=True, help_text="Projector-camera baseline, mm")
    alpha_rad = models.FloatField(null=True, blank=True, help_text="Tilt of the projector sensor plane, rad")
    fw_mm = models.FloatField(null=True, blank=True, help_text="Camera field width on the reference plane, mm")
    nlp = models.PositiveIntegerField(null=True, blank=True, help_text="Light codes across the field (<= 128)")
    width_px = models.PositiveIntegerField()
    height_px = models.PositiveIntegerField()
    extra = models.JSONField(default=dict, blank=True, help_text="Further keys of the rig file")
    codec = models.JSONField(
        default=default_codec,
        help_text="Default codec of its captures: built-in name or gcps-codec/1 object",
    )
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ("id",)

    def __str__(self) -> str:
        return self.name or f"rig {self.pk}"

    def geometry(self) -> dict:
        """The seven values of the rig file."""
        return {name: getattr(self, name) for name in GEOMETRY_FIELDS}

    @property
    def is_pinhole(self) -> bool:
        return self.model == self.Model.PINHOLE

    def rig_file(self) -> dict:
        """The rig file's values: the pinhole rig file, or the seven crossed-axes values."""
        return dict(self.pinhole) if self.is_pinhole and self.pinhole else self.geometry()

    def to_core(self):
        """The core's frozen geometric model: :class:`metrology.core.rig.Rig` for these values, or the
        :class:`~metrology.core.geometry.pinhole.PinholeRig` of a pinhole rig."""
        if self.is_pinhole:
            from metrology.core.geometry.pinhole import PinholeRig

            return PinholeRig.from_dict(self.pinhole or {})
        from metrology.core.rig import Rig as CoreRig

        return CoreRig.from_dict(self.geometry())


class RigParameters(models.Model):
    """One entry of a rig's history: the geometry it had from ``created_at`` on."""

    class Source(models.TextChoices):
        CREATED = "created", "Created"
        CALIBRATION = "calibration", "Calibration applied"
        MANUAL = "manual", "Edited"
        RESTORED = "restored", "Restored from history"

    rig = models.ForeignKey(Rig, on_delete=models.CASCADE, related_name="history")
    values = models.JSONField(help_text="The seven geometric values, or the pinhole rig file")
    source = models.CharField(max_length=16, choices=Source.choices)
    calibration = models.ForeignKey(
        "calibrations.Calibration", null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    procam_calibration = models.ForeignKey(
        "calibrations.ProcamCalibration",
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
        help_text="The projector-camera calibration that set these values",
    )
    restored_from = models.ForeignKey(
        "self",
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="+",
        help_text="The earlier entry whose values were restored (source restored)",
    )
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("created_at", "id")
        verbose_name_plural = "rig parameters"

    def __str__(self) -> str:
        return f"{self.rig} {self.source} {self.created_at:%Y-%m-%d %H:%M}"
