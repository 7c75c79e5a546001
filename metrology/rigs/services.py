"""Writes for rigs: create a rig from its JSON (validated by the core), change its geometry."""

from __future__ import annotations

import json
from typing import Any

from django.conf import settings
from django.db import transaction

from metrology.core.rig import Rig as CoreRig
from metrology.core.rig import RigError
from metrology.errors import BadInput
from metrology.rigs.codecs import validate_codec
from metrology.rigs.models import DEFAULT_CODEC, GEOMETRY_FIELDS, Rig, RigParameters


def validate_geometry(values: dict[str, Any]) -> dict[str, Any]:
    """The seven values normalised by the core's :class:`Rig`; raises :class:`BadInput` naming the problem.

    The image sides are also bounded by ``GCPS_MAX_IMAGE_SIDE_PX`` (every capture, measurement and
    simulation of the rig is that size).
    """
    try:
        core = CoreRig.from_dict(values)
    except RigError as exc:
        raise BadInput(str(exc)) from None
    except (TypeError, OverflowError) as exc:  # e.g. a list where a number belongs
        raise BadInput(f"rig values are not numbers: {exc}") from None
    limit = settings.GCPS_MAX_IMAGE_SIDE_PX
    for name in ("width_px", "height_px"):
        if getattr(core, name) > limit:
            raise BadInput(f"{name} must be at most {limit} pixels (GCPS_MAX_IMAGE_SIDE_PX), got {getattr(core, name)}")
    return {name: getattr(core, name) for name in GEOMETRY_FIELDS}


def validate_extra(extra: dict[str, Any]) -> dict[str, Any]:
    """The rig file's further keys: no NUL character anywhere, at most ``GCPS_MAX_RIG_EXTRA_BYTES`` of JSON.

    Raises :class:`BadInput` naming the key (PostgreSQL refuses NUL in JSON; a large blob would be
    stored and sent back with the rig).
    """
    stack: list[tuple[str, Any]] = [("", extra)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, dict):
            for key, item in value.items():
                if "\x00" in str(key):
                    raise BadInput(f"extra key {key!r} contains a NUL character")
                stack.append((f"{where}.{key}" if where else str(key), item))
        elif isinstance(value, list):
            stack.extend((f"{where}[{index}]", item) for index, item in enumerate(value))
        elif isinstance(value, str) and "\x00" in value:
            raise BadInput(f"extra value {where} contains a NUL character")
    size = len(json.dumps(extra, ensure_ascii=False).encode())
    limit = settings.GCPS_MAX_RIG_EXTRA_BYTES
    if size > limit:
        raise BadInput(
            f"extra (the rig file's further keys) holds {size} bytes of JSON, more than the limit of {limit} bytes "
            "(GCPS_MAX_RIG_EXTRA_BYTES)"
        )
    return extra


@transaction.atomic
def create_rig(*, owner, data: dict[str, Any]) -> Rig:
    """Create a rig from the rig-file JSON (docs/file-formats.md); ``name``, ``notes`` and ``codec`` (its
    captures' default codec, docs/codecs.md; gcps-v1 when absent) are optional keys."""
    geometry = validate_geometry({name: data.get(name) for name in GEOMETRY_FIELDS if name in data})
    extra = validate_extra(
        {key: value for key, value in data.items() if key not in (*GEOMETRY_FIELDS, "name", "notes", "codec")}
    )
    codec = validate_codec(data["codec"]) if data.get("codec") is not None else DEFAULT_CODEC
    rig = Rig.objects.create(
        owner=owner,
        name=str(data.get("name") or ""),
        notes=str(data.get("notes") or ""),
        extra=extra,
        codec=codec,
        **geometry,
    )
    RigParameters.objects.create(rig=rig, values=rig.geometry(), source=RigParameters.Source.CREATED)
    return rig


@transaction.atomic
def update_rig_geometry(
    *, rig: Rig, changes: dict[str, Any], source: str, calibration=None, restored_from: RigParameters | None = None
) -> Rig:
    """Replace some geometric values (e.g. a calibration's L and alpha) and record them in the history.

    The rig is a crossed-axes rig afterwards: the seven values are that model's (a pinhole rig's
    ``changes`` must give all seven, as a restored crossed-axes entry does; its rig file stays in
    the history). ``restored_from`` is the history entry the values come back from, if any.
    """
    geometry = validate_geometry({**rig.geometry(), **changes})
    rig = Rig.objects.select_for_update().get(pk=rig.pk)
    rig.model = Rig.Model.CROSSED_AXES
    rig.pinhole = None
    for name, value in geometry.items():
        setattr(rig, name, value)
    rig.save()
    RigParameters.objects.create(
        rig=rig, values=rig.geometry(), source=source, calibration=calibration, restored_from=restored_from
    )
    return rig


@transaction.atomic
def set_rig_codec(*, rig: Rig, codec: Any) -> Rig:
    """Set the default codec of a rig's captures (a built-in name or a gcps-codec/1 object), validated;
    :class:`BadInput` naming the problem. Stored captures keep the codec they were validated with."""
    value = validate_codec(codec)
    Rig.objects.filter(pk=rig.pk).update(codec=value)
    rig.refresh_from_db()
    return rig


def validate_pinhole_file(rig_file: dict[str, Any]) -> Any:
    """The core's :class:`~metrology.core.geometry.pinhole.PinholeRig` of a pinhole rig file
    (docs/pinhole.md); :class:`BadInput` naming the problem (the core's message) when it is refused."""
    from metrology.core.geometry import GeometryError
    from metrology.core.geometry.pinhole import PinholeRig

    try:
        return PinholeRig.from_dict(rig_file)
    except GeometryError as exc:
        raise BadInput(str(exc)) from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise BadInput(f"pinhole rig refused: {exc}") from None


@transaction.atomic
def create_pinhole_rig(*, owner, data: dict[str, Any]) -> Rig:
    """Create a pinhole rig from its rig file (docs/pinhole.md: ``model``, ``camera``, ``projector``, ``R``
    or ``rvec``... as the core reads it); ``name``, ``notes`` and ``codec`` are optional further keys.
    Raises :class:`BadInput` naming the problem (the core's message)."""
    rig_file = {key: value for key, value in data.items() if key not in ("name", "notes", "codec")}
    core = validate_pinhole_file(rig_file)
    limit = settings.GCPS_MAX_IMAGE_SIDE_PX
    for name, value in (("camera width_px", core.camera.width_px), ("camera height_px", core.camera.height_px)):
        if value > limit:
            raise BadInput(f"{name} must be at most {limit} pixels (GCPS_MAX_IMAGE_SIDE_PX), got {value}")
    codec = validate_codec(data["codec"]) if data.get("codec") is not None else DEFAULT_CODEC
    values = core.to_dict()
    rig = Rig.objects.create(
        owner=owner,
        name=str(data.get("name") or "")[:200],
        notes=str(data.get("notes") or ""),
        model=Rig.Model.PINHOLE,
        pinhole=values,
        width_px=core.camera.width_px,
        height_px=core.camera.height_px,
        codec=codec,
    )
    RigParameters.objects.create(rig=rig, values=values, source=RigParameters.Source.CREATED)
    return rig


def require_crossed_axes(rig: Rig, what: str) -> None:
    """BadInput when ``rig`` is a pinhole rig and ``what`` (a calibration, a simulated capture...) needs
    the crossed-axes model."""
    if rig.is_pinhole:
        raise BadInput(f"rig {rig.pk} is a pinhole rig: {what} needs a crossed-axes rig (docs/pinhole.md)")


@transaction.atomic
def set_pinhole_rig_file(
    *, rig: Rig, rig_file: dict[str, Any], source: str, procam=None, restored_from: RigParameters | None = None
) -> Rig:
    """Make ``rig`` a pinhole rig with ``rig_file`` (docs/pinhole.md), recorded in its history.

    The model becomes ``pinhole``, the image size the camera's and the crossed-axes values are
    cleared (a crossed-axes rig is converted; its values stay in the history). ``procam`` is the
    projector-camera calibration that produced the file, if any; ``restored_from`` the history entry
    it comes back from, if any. :class:`BadInput` naming the problem when the core refuses the file.
    """
    core = validate_pinhole_file(rig_file)
    values = core.to_dict()
    rig = Rig.objects.select_for_update().get(pk=rig.pk)
    rig.model = Rig.Model.PINHOLE
    rig.pinhole = values
    rig.width_px, rig.height_px = core.camera.width_px, core.camera.height_px
    for name in ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp"):
        setattr(rig, name, None)
    rig.save()
    RigParameters.objects.create(
        rig=rig, values=values, source=source, procam_calibration=procam, restored_from=restored_from
    )
    return rig


@transaction.atomic
def restore_rig_entry(*, rig: Rig, entry_id: Any) -> Rig:
    """Make an earlier entry of the rig's history its current values again, as a new entry (source
    ``restored``, pointing to the entry and to the calibration that had set it).

    A pinhole entry makes the rig a pinhole rig with that rig file; a crossed-axes entry makes it a
    crossed-axes rig with those seven values (a pinhole rig is converted back; its rig file stays in
    the history). The default codec is kept: a crossed-axes rig measures with any codec coding u.
    Measurements made before keep the values they were made with.

    Raises
    ------
    BadInput
        When the entry is not one of this rig's, or already holds its current values (the latest
        entry).
    """
    rig = Rig.objects.select_for_update().get(pk=rig.pk)
    entries = RigParameters.objects.filter(rig=rig)
    entry = entries.filter(pk=entry_id).first() if str(entry_id).isdigit() else None
    if entry is None:
        raise BadInput(f"rig {rig.pk} has no history entry {entry_id}")
    latest = entries.order_by("-created_at", "-id").first()
    if latest is not None and latest.pk == entry.pk:
        raise BadInput(f"history entry {entry.pk} already holds rig {rig.pk}'s current values")
    source = RigParameters.Source.RESTORED
    if entry.values.get("model") == "pinhole":
        return set_pinhole_rig_file(
            rig=rig, rig_file=entry.values, source=source, procam=entry.procam_calibration, restored_from=entry
        )
    return update_rig_geometry(
        rig=rig,
        changes={name: entry.values.get(name) for name in GEOMETRY_FIELDS},
        source=source,
        calibration=entry.calibration,
        restored_from=entry,
    )
