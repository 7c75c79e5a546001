"""Writes for rigs: create a rig from its JSON (validated by the core), change its geometry."""

from __future__ import annotations

from typing import Any

from django.db import transaction

from metrology.api_errors import BadInput
from metrology.core.rig import Rig as CoreRig
from metrology.core.rig import RigError
from metrology.rigs.models import GEOMETRY_FIELDS, Rig, RigParameters


def validate_geometry(values: dict[str, Any]) -> dict[str, Any]:
    """The seven values normalised by the core's :class:`Rig`; raises :class:`BadInput` naming the problem."""
    try:
        core = CoreRig.from_dict(values)
    except RigError as exc:
        raise BadInput(str(exc)) from None
    except (TypeError, OverflowError) as exc:  # e.g. a list where a number belongs
        raise BadInput(f"rig values are not numbers: {exc}") from None
    return {name: getattr(core, name) for name in GEOMETRY_FIELDS}


@transaction.atomic
def create_rig(*, owner, data: dict[str, Any]) -> Rig:
    """Create a rig from the rig-file JSON (docs/file-formats.md); ``name`` and ``notes`` are optional keys."""
    geometry = validate_geometry({name: data.get(name) for name in GEOMETRY_FIELDS if name in data})
    extra = {key: value for key, value in data.items() if key not in (*GEOMETRY_FIELDS, "name", "notes")}
    rig = Rig.objects.create(
        owner=owner, name=str(data.get("name") or ""), notes=str(data.get("notes") or ""), extra=extra, **geometry
    )
    RigParameters.objects.create(rig=rig, values=rig.geometry(), source=RigParameters.Source.CREATED)
    return rig


@transaction.atomic
def update_rig_geometry(*, rig: Rig, changes: dict[str, Any], source: str, calibration=None) -> Rig:
    """Replace some geometric values (e.g. a calibration's L and alpha) and record them in the history."""
    geometry = validate_geometry({**rig.geometry(), **changes})
    rig = Rig.objects.select_for_update().get(pk=rig.pk)
    for name, value in geometry.items():
        setattr(rig, name, value)
    rig.save()
    RigParameters.objects.create(rig=rig, values=rig.geometry(), source=source, calibration=calibration)
    return rig
