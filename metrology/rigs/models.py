"""A Rig: its geometric model (the core's registry name) and the model's parameters, the default codec
of its captures, and the history of its values.

:meth:`Rig.to_core` is the one place of the application that turns a stored rig into the core's
model; everything else asks the model what it can do (:class:`metrology.core.geometry.base.GeometryModel`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import models

if TYPE_CHECKING:  # pragma: no cover
    from metrology.core.geometry.base import GeometryModel

DEFAULT_CODEC = "gcps-v1"
"""A rig's default codec: the paper's eleven named patterns (docs/codecs.md)."""

DEFAULT_MODEL = "crossed_axes"
"""The model of a rig file without a ``model`` key: the paper's (docs/conventions.md)."""

LEGACY_FIELDS: tuple[str, ...] = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp")
"""The crossed-axes values that the rigs API has always answered at the top level (None where the
rig's model has no such parameter)."""


def default_codec() -> str:
    return DEFAULT_CODEC


def model_choices() -> list[tuple[str, str]]:
    """``(name, label)`` of every geometric model of the core's registry."""
    from metrology.core.geometry import MODELS

    return [(name, cls.label) for name, cls in MODELS.items()]


class Rig(models.Model):
    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="rigs")
    name = models.CharField(max_length=200, blank=True)
    notes = models.TextField(blank=True)
    model = models.CharField(
        max_length=32, choices=model_choices, default=DEFAULT_MODEL, help_text="The rig's geometric model"
    )
    parameters = models.JSONField(
        default=dict, help_text="The model's values: its rig file without the model key (validated by the core)"
    )
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

    def to_core(self) -> GeometryModel:
        """The core's frozen geometric model of these values (cached per instance while they stay the same)."""
        from metrology.core.geometry import model_from_parameters

        key = (self.model, repr(self.parameters))
        cached = getattr(self, "_core", None)
        if cached is None or cached[0] != key:
            cached = (key, model_from_parameters(self.model, self.parameters))
            self._core = cached
        return cached[1]

    def rig_file(self) -> dict[str, Any]:
        """The rig file of the model's values: ``{"model": ..., **parameters}`` (what measurements
        record as the values they were made with; the core reads it back)."""
        return {"model": self.model, **self.parameters}

    @property
    def shape(self) -> tuple[int, int]:
        """Camera frame ``(height_px, width_px)``."""
        return self.to_core().shape

    @property
    def width_px(self) -> int:
        return self.shape[1]

    @property
    def height_px(self) -> int:
        return self.shape[0]

    def legacy_values(self) -> dict[str, Any]:
        """The keys the rigs API answered before rigs stored their model's parameters: the
        crossed-axes values (None where the model has none), the image size, and ``pinhole``, the
        rig file of a pinhole rig (None otherwise)."""
        values: dict[str, Any] = {name: self.parameters.get(name) for name in LEGACY_FIELDS}
        values.update(width_px=self.width_px, height_px=self.height_px)
        values["pinhole"] = self.rig_file() if self.model == "pinhole" else None
        return values


class RigParameters(models.Model):
    """One entry of a rig's history: the values it had from ``created_at`` on."""

    class Source(models.TextChoices):
        CREATED = "created", "Created"
        CALIBRATION = "calibration", "Calibration applied"
        MANUAL = "manual", "Edited"
        RESTORED = "restored", "Restored from history"
        IMPORTED = "imported", "Imported from a calibration file"

    rig = models.ForeignKey(Rig, on_delete=models.CASCADE, related_name="history")
    values = models.JSONField(
        help_text="The rig file of the values (read by the core; a crossed-axes file may lack its model key)"
    )
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

    def to_core(self) -> GeometryModel:
        """The core's model of this entry's values."""
        from metrology.core.geometry import model_from_dict

        return model_from_dict(self.values)
