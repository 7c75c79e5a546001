"""Reads for calibrations, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.calibrations.models import Calibration, ProcamCalibration


def calibrations_for(user) -> QuerySet[Calibration]:
    return Calibration.objects.filter(owner=user).select_related("job", "rig")


def get_calibration(user, calibration_id) -> Calibration:
    calibration = calibrations_for(user).filter(pk=calibration_id).first() if str(calibration_id).isdigit() else None
    if calibration is None:
        raise Http404(f"No calibration {calibration_id} among yours.")
    return calibration


def procam_calibrations_for(user, rig=None) -> QuerySet[ProcamCalibration]:
    """The user's projector-camera calibrations (of ``rig`` when given), newest first."""
    calibrations = ProcamCalibration.objects.filter(owner=user).select_related("job", "rig")
    return calibrations.filter(rig=rig) if rig is not None else calibrations


def get_procam_calibration(user, calibration_id) -> ProcamCalibration:
    calibration = (
        procam_calibrations_for(user).filter(pk=calibration_id).first() if str(calibration_id).isdigit() else None
    )
    if calibration is None:
        raise Http404(f"No procam calibration {calibration_id} among yours.")
    return calibration


def procam_pose_ids(calibration: ProcamCalibration) -> list[int]:
    """The ids of the calibration's pose captures, in order."""
    return list(calibration.pose_links.order_by("index").values_list("capture_id", flat=True))
