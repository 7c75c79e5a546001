"""Nominal models (a part's triangle mesh, mm), inspections of measurements against them, and a rig's
inspection plan (applied to each new measurement of the rig)."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class NominalModel(models.Model):
    """An uploaded nominal model in mm: a triangle mesh (STL, PLY or OBJ) or a STEP solid, validated by
    :func:`metrology.core.inspection.nominal.read_nominal` when it was stored.

    ``file``, ``file_format``, ``sha256`` and ``size_bytes`` describe the uploaded file. A STEP file is
    tessellated once, at upload, with the tolerances recorded in ``tessellation``; its triangles are
    kept in ``mesh_file`` (binary PLY), which inspections read as they read an uploaded mesh
    (:attr:`mesh`)."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="nominal_models")
    name = models.CharField(max_length=200)
    file = models.FileField(max_length=300, help_text="The uploaded file")
    file_format = models.CharField(max_length=8, help_text="The uploaded file's format: stl, ply, obj or step")
    mesh_file = models.FileField(
        max_length=300, blank=True, help_text="A STEP upload's tessellation (binary PLY, mm); empty for a mesh upload"
    )
    tessellation = models.JSONField(
        null=True,
        blank=True,
        help_text="How a STEP upload became triangles (method, linear and angular tolerances, faces)",
    )
    sha256 = models.CharField(max_length=64)
    size_bytes = models.PositiveBigIntegerField()
    triangle_count = models.PositiveIntegerField()
    units = models.CharField(max_length=8, default="mm")
    summary = models.JSONField(default=dict, blank=True, help_text="Bounds, size, orientation and warnings")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"{self.name} (nominal {self.pk})"

    @property
    def mesh(self) -> tuple[models.fields.files.FieldFile, str]:
        """The triangles an inspection reads and their format: ``(mesh_file, "ply")`` for a STEP
        upload, ``(file, file_format)`` for a mesh upload."""
        return (self.mesh_file, "ply") if self.mesh_file else (self.file, self.file_format)


class Inspection(models.Model):
    """A measurement's points aligned to a nominal model, their signed deviations and, with a
    tolerance, the conformance decision (``report`` is the ``gcps-inspection/1`` document)."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="inspections")
    measurement = models.ForeignKey("measurements.Measurement", on_delete=models.CASCADE, related_name="inspections")
    nominal = models.ForeignKey(NominalModel, on_delete=models.PROTECT, related_name="inspections")
    plan = models.ForeignKey(
        "InspectionPlan", null=True, blank=True, on_delete=models.SET_NULL, related_name="inspections"
    )
    options = models.JSONField(default=dict, blank=True, help_text="Inspection options (InspectOptions.to_dict)")
    report = models.JSONField(default=dict, blank=True, help_text="The gcps-inspection/1 report")
    deviations_npy = models.FileField(max_length=300, blank=True, help_text="Signed deviations (H, W) float32, mm")
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="inspection")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"inspection {self.pk}"


class InspectionPlan(models.Model):
    """What to inspect on every new measurement of a rig: the nominal, the alignment's start, the
    tolerance and the inspection options. One plan per rig."""

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="inspection_plans")
    rig = models.OneToOneField("rigs.Rig", on_delete=models.CASCADE, related_name="inspection_plan")
    nominal = models.ForeignKey(NominalModel, on_delete=models.PROTECT, related_name="plans")
    options = models.JSONField(default=dict, blank=True, help_text="Inspection options applied to each measurement")
    active = models.BooleanField(default=True)
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    def __str__(self) -> str:
        return f"inspection plan of rig {self.rig_id}"
