"""Reads for characterizations, scoped to the user."""

from __future__ import annotations

from django.db.models import QuerySet
from django.http import Http404

from metrology.characterizations.models import Characterization


def characterizations_for(user) -> QuerySet[Characterization]:
    return Characterization.objects.filter(owner=user).select_related("job", "rig")


def get_characterization(user, characterization_id) -> Characterization:
    found = (
        characterizations_for(user).filter(pk=characterization_id).first()
        if str(characterization_id).isdigit()
        else None
    )
    if found is None:
        raise Http404(f"No characterization {characterization_id} among yours.")
    return found


def characterizations_of_rig(rig) -> QuerySet[Characterization]:
    """A rig's finished characterizations, newest first (for reports and drift)."""
    return Characterization.objects.filter(rig=rig, job__status="done").select_related("job")
