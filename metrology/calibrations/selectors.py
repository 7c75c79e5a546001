"""Reads for calibrations, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.calibrations.models import Calibration


def calibrations_for(user) -> QuerySet[Calibration]:
    return Calibration.objects.filter(owner=user).select_related("job", "rig")


def get_calibration(user, calibration_id) -> Calibration:
    calibration = calibrations_for(user).filter(pk=calibration_id).first() if str(calibration_id).isdigit() else None
    if calibration is None:
        raise Http404(f"No calibration {calibration_id} among yours.")
    return calibration
