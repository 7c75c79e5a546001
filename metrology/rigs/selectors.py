"""Reads for rigs, always scoped to the user (another user's rig is not found)."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.rigs.models import Rig


def rigs_for(user) -> QuerySet[Rig]:
    return Rig.objects.filter(owner=user).prefetch_related("history")


def get_rig(user, rig_id) -> Rig:
    rig = rigs_for(user).filter(pk=rig_id).first() if str(rig_id).isdigit() else None
    if rig is None:
        raise Http404(f"No rig {rig_id} among yours.")
    return rig


def rig_history(rig: Rig) -> list[dict]:
    """The rig's geometry over time, oldest first: ``id``, ``values`` (the seven values or a pinhole rig
    file), ``pinhole`` (True for a pinhole rig file), ``source``, ``calibration`` / ``procam_calibration``
    (the id of the calibration that set them, or None), ``restored_from`` (the entry a restore copied),
    ``restored_from_at`` (that entry's date), ``at`` and ``current`` (True for the latest entry, the
    rig's values now)."""
    entries = list(rig.history.all())
    dates = {entry.pk: entry.created_at for entry in entries}
    return [
        {
            "id": entry.pk,
            "values": entry.values,
            "pinhole": entry.values.get("model") == "pinhole",
            "source": entry.source,
            "calibration": entry.calibration_id,
            "procam_calibration": entry.procam_calibration_id,
            "restored_from": entry.restored_from_id,
            "restored_from_at": dates.get(entry.restored_from_id) if entry.restored_from_id else None,
            "at": entry.created_at,
            "current": index == len(entries) - 1,
        }
        for index, entry in enumerate(entries)
    ]
