"""A Calibration of a rig's geometry on a master block (paper section 4, or least squares), and a
ProcamCalibration of its camera and projector from board poses (a pinhole rig)."""

from __future__ import annotations

from typing import Any

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


class ProcamCalibration(models.Model):
    """A projector-camera calibration of a rig from board poses (docs/procam-calibration.md).

    ``poses`` are the board captures in the order given (:class:`ProcamCalibrationPose`); the job
    calls :func:`metrology.pipeline.calibrate_procam.calibrate_procam_stacks` on their stacks and
    stores the report (``gcps-procam-report/1``) and the pinhole rig file; applying it makes the rig
    a pinhole rig with that file (its state before is kept in ``rig_before`` and in its history).
    """

    owner = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="procam_calibrations")
    rig = models.ForeignKey("rigs.Rig", on_delete=models.CASCADE, related_name="procam_calibrations")
    poses: models.ManyToManyField[Any, Any] = models.ManyToManyField(
        "captures.Capture", through="ProcamCalibrationPose", related_name="+", help_text="Board captures, in order"
    )
    options = models.JSONField(default=dict, help_text="ProcamOptions.to_dict(): board spec, window, thresholds")
    report = models.JSONField(
        default=dict, blank=True, help_text="The report (gcps-procam-report/1), non-finite numbers as null"
    )
    report_json = models.TextField(blank=True, help_text="REPORT.json exactly as `gcps calibrate-procam` writes it")
    rig_file = models.JSONField(null=True, blank=True, help_text="The calibrated pinhole rig file")
    rig_before = models.JSONField(
        default=dict, blank=True, help_text="The rig's model and rig file when the calibration was requested"
    )
    apply = models.BooleanField(default=False, help_text="Apply the result to the rig when done")
    applied = models.BooleanField(default=False)
    applied_at = models.DateTimeField(null=True, blank=True)
    job = models.OneToOneField("jobs.Job", on_delete=models.PROTECT, related_name="procam_calibration")
    created_at = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ("-created_at", "-id")

    def __str__(self) -> str:
        return f"procam calibration {self.pk}"

    @property
    def board(self) -> str:
        """The board spec, e.g. ``chessboard:9x7:25``."""
        return str(self.options.get("board", ""))


class ProcamCalibrationPose(models.Model):
    """One board pose of a procam calibration: the capture and its place (0, 1, ...) in the order given."""

    calibration = models.ForeignKey(ProcamCalibration, on_delete=models.CASCADE, related_name="pose_links")
    capture = models.ForeignKey("captures.Capture", on_delete=models.PROTECT, related_name="+")
    index = models.PositiveSmallIntegerField()

    class Meta:
        ordering = ("calibration", "index")
        constraints = (
            models.UniqueConstraint(fields=("calibration", "index"), name="procam_pose_index_unique"),
            models.UniqueConstraint(fields=("calibration", "capture"), name="procam_pose_capture_unique"),
        )

    def __str__(self) -> str:
        return f"pose {self.index} of {self.calibration}: capture {self.capture_id}"
