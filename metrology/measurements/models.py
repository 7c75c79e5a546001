"""A Measurement: reference + object capture -> height map, meshes and statistics."""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.conf import settings
from django.db import models

if TYPE_CHECKING:
    from django.db.models.fields.files import FieldFile

RESULT_FILES: dict[str, str | None] = {
    "height.npy": "height_npy",
    "height.tiff": "height_tiff",
    "gray_only_height.npy": "gray_only_npy",
    "mesh.ply": "mesh_ply",
    "mesh.stl": "mesh_stl",
    "mesh.obj": "mesh_obj",
    "sigma.npy": "sigma_npy",
    "points.npy": "points_npy",
    "exposure.npy": "exposure_npy",
    "pairs.npy": "pairs_npy",
    "points.e57": None,
}
"""Each result file's model field, None for a file that is only ever derived (never stored by a
measurement job: ``points.e57``)."""


def stored_file(measurement: Measurement, filename: str) -> FieldFile | None:
    """The stored file ``filename`` of ``measurement`` (a FieldFile that may be empty), None when the
    file is only ever derived."""
    field = RESULT_FILES[filename]
    return None if field is None else getattr(measurement, field)


class Measurement(models.Model):
    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="measurements")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="measurements")
    reference = models.ForeignKey("captures.Capture", null=True, blank=True, on_delete=models.PROTECT, related_name="+")
    object = models.ForeignKey("captures.Capture", on_delete=models.PROTECT, related_name="+")
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="measurement")
    rig_values = models.JSONField(default=dict, blank=True, help_text="Rig geometry the heights were computed with")
    height_npy = models.FileField(max_length=300, blank=True)
    height_tiff = models.FileField(max_length=300, blank=True)
    gray_only_npy = models.FileField(max_length=300, blank=True)
    mesh_ply = models.FileField(max_length=300, blank=True)
    mesh_stl = models.FileField(max_length=300, blank=True)
    mesh_obj = models.FileField(max_length=300, blank=True)
    points_npy = models.FileField(max_length=300, blank=True, help_text="Points (H, W, 3), mm (pinhole rigs)")
    sigma_npy = models.FileField(
        max_length=300, blank=True, help_text="Per-point height uncertainty, mm (options.sigma)"
    )
    exposure_npy = models.FileField(
        max_length=300,
        blank=True,
        help_text="Which exposure measured each point, uint8 (H, W), 255 none (multi-exposure objects)",
    )
    pairs_npy = models.FileField(
        max_length=300,
        blank=True,
        help_text="Which pairs of devices measured each point, uint8 (H, W) bits, 0 none (stereo rigs)",
    )
    statistics = models.JSONField(default=dict, blank=True)
    options = models.JSONField(
        default=dict, blank=True, help_text="Pipeline options the result was computed with (decoding included)"
    )
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"measurement {self.pk}"
