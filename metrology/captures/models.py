"""Capture sessions and captures: stored image stacks (docs/file-formats.md) with their provenance."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class CaptureSession(models.Model):
    """Captures taken together on one rig: a reference and its objects, a master, a stage series."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="capture_sessions")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="sessions")
    name = models.CharField(max_length=200, blank=True)
    notes = models.TextField(blank=True)
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("id",)

    def __str__(self) -> str:
        return self.name or f"session {self.pk}"


class Capture(models.Model):
    class Role(models.TextChoices):
        REFERENCE = "reference", "Reference plane"
        OBJECT = "object", "Object"
        MASTER = "master", "Calibration master"
        STAGE = "stage", "Stage position"
        BOARD = "board", "Calibration board pose"

    class Source(models.TextChoices):
        UPLOAD = "upload", "Uploaded"
        VIRTUAL = "virtual", "Virtual rig"
        RIG = "rig", "Rig (capture agent)"

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="captures")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="captures")
    session = models.ForeignKey(CaptureSession, on_delete=models.CASCADE, related_name="captures")
    role = models.CharField(max_length=16, choices=Role.choices)
    z_in_mm = models.FloatField(null=True, blank=True, help_text="Stage position Z_in, mm (stage captures)")
    repeat = models.PositiveIntegerField(default=0, help_text="Repeat index at one stage position")
    source = models.CharField(max_length=16, choices=Source.choices)
    file = models.FileField(max_length=300, blank=True, help_text="The stack as a zip of eleven images")
    truth = models.FileField(max_length=300, blank=True, help_text="Simulator truth height map (.npy), virtual only")
    original_name = models.CharField(max_length=255, blank=True)
    checksum_sha256 = models.CharField(max_length=64, blank=True)
    size_bytes = models.PositiveBigIntegerField(null=True, blank=True)
    bit_depth = models.PositiveSmallIntegerField(null=True, blank=True)
    height_px = models.PositiveIntegerField(null=True, blank=True)
    width_px = models.PositiveIntegerField(null=True, blank=True)
    parameters = models.JSONField(default=dict, blank=True, help_text="Scene and simulation options (virtual)")
    codec = models.JSONField(
        null=True,
        blank=True,
        help_text="The stack's codec: built-in name or gcps-codec/1 object (null: the rig's)",
    )
    exposures = models.JSONField(
        null=True,
        blank=True,
        help_text="A multi-exposure capture's exposures.json entries, least exposed first (null: one exposure)",
    )
    job = models.OneToOneField("jobs.Job", null=True, blank=True, on_delete=models.SET_NULL, related_name="capture")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("id",)
        indexes = (models.Index(fields=["rig", "role", "z_in_mm"]),)

    def __str__(self) -> str:
        return f"capture {self.pk} ({self.role})"

    @property
    def ready(self) -> bool:
        """True once the stack is stored (uploads at once, virtual captures when their job is done)."""
        return bool(self.file)
