"""Writes for rigs: create a rig from a rig file of any model (validated by the core), change its
values, keep their history.

Every change of a rig's values goes through :func:`set_rig_model`, which records the new values in
the rig's history with what set them (creation, a calibration, an edit, a restore).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from django.conf import settings
from django.db import transaction

from metrology.errors import BadInput
from metrology.rigs.codecs import default_codec_for, validate_codec
from metrology.rigs.models import Rig, RigParameters

RIG_FIELDS: tuple[str, ...] = ("name", "notes", "codec")
"""Keys of a rig file that are the application's, not the model's."""


def validate_model(rig_file: Mapping[str, Any]) -> Any:
    """The core's geometric model of a rig file (any model; the paper's when ``model`` is absent),
    its camera bounded by ``GCPS_MAX_IMAGE_SIDE_PX`` (every capture, measurement and simulation of
    the rig is that size). :class:`BadInput` naming the problem (the core's message)."""
    from metrology.core.geometry import GeometryError, model_from_dict

    try:
        model = model_from_dict(rig_file)
    except GeometryError as exc:
        raise BadInput(str(exc)) from None
    except (TypeError, ValueError, OverflowError) as exc:  # e.g. a list where a number belongs
        raise BadInput(f"rig values refused: {exc}") from None
    limit = settings.GCPS_MAX_IMAGE_SIDE_PX
    height, width = model.shape
    for name, value in (("width_px", width), ("height_px", height)):
        if value > limit:
            raise BadInput(f"camera {name} must be at most {limit} pixels (GCPS_MAX_IMAGE_SIDE_PX), got {value}")
    return model


def validate_extra(extra: dict[str, Any]) -> dict[str, Any]:
    """The rig file's further keys: no NUL character anywhere, only finite numbers, at most
    ``GCPS_MAX_RIG_EXTRA_BYTES`` of JSON.

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
        elif isinstance(value, float) and not math.isfinite(value):
            raise BadInput(f"extra value {where} must be a finite number, got {value!r}")
    size = len(json.dumps(extra, ensure_ascii=False).encode())
    limit = settings.GCPS_MAX_RIG_EXTRA_BYTES
    if size > limit:
        raise BadInput(
            f"extra (the rig file's further keys) holds {size} bytes of JSON, more than the limit of {limit} bytes "
            "(GCPS_MAX_RIG_EXTRA_BYTES)"
        )
    return extra


def history_values(model: Any) -> dict[str, Any]:
    """What a history entry (and a measurement) records of a model: its rig file with the model's name."""
    return {"model": model.model, **model.parameters()}


@transaction.atomic
def create_rig(*, owner, data: Mapping[str, Any]) -> Rig:
    """Create a rig from a rig file of any model (docs/file-formats.md, docs/pinhole.md): the flat
    crossed-axes values (further keys kept in ``extra``) or a file with ``model``; ``name``,
    ``notes`` and ``codec`` (its captures' default codec, docs/codecs.md; when absent, gcps-v1 at the
    model's projector size where it has one, :func:`~metrology.rigs.codecs.default_codec_for`) are
    optional keys. :class:`BadInput` naming the problem."""
    if not isinstance(data, Mapping):
        raise BadInput(f"a rig file is a JSON object, got {type(data).__name__}")
    rig_file = {key: value for key, value in data.items() if key not in RIG_FIELDS}
    model = validate_model(rig_file)
    parameters = model.parameters()
    extra = validate_extra({k: v for k, v in rig_file.items() if k not in parameters and k != "model"})
    name, notes = data.get("name") or "", data.get("notes") or ""
    if not isinstance(name, str) or not isinstance(notes, str):
        raise BadInput("name and notes must be text")
    if len(name) > 200:
        raise BadInput(f"name must be at most 200 characters, got {len(name)}")
    codec = validate_codec(data["codec"]) if data.get("codec") is not None else default_codec_for(model)
    rig = Rig.objects.create(
        owner=owner, name=name, notes=notes, model=model.model, parameters=parameters, extra=extra, codec=codec
    )
    RigParameters.objects.create(rig=rig, values=history_values(model), source=RigParameters.Source.CREATED)
    return rig


@transaction.atomic
def set_rig_model(
    *,
    rig: Rig,
    model: Any,
    source: str,
    calibration=None,
    procam=None,
    restored_from: RigParameters | None = None,
) -> Rig:
    """Give ``rig`` the values of ``model`` (a core geometric model, of the rig's model or another:
    a projector-camera calibration turns a crossed-axes rig into a pinhole one) and record them in
    its history with what set them: ``source``, the ``calibration`` or ``procam`` calibration, the
    history entry ``restored_from``."""
    model = validate_model(history_values(model))
    rig = Rig.objects.select_for_update().get(pk=rig.pk)
    rig.model, rig.parameters = model.model, model.parameters()
    rig.save()
    RigParameters.objects.create(
        rig=rig,
        values=history_values(model),
        source=source,
        calibration=calibration,
        procam_calibration=procam,
        restored_from=restored_from,
    )
    return rig


def update_rig_parameters(*, rig: Rig, changes: Mapping[str, Any], source: str, calibration=None) -> Rig:
    """Replace some of the rig's parameters (e.g. a calibration's L and alpha) and record them
    (:func:`set_rig_model`); :class:`BadInput` naming a parameter the rig's model does not have."""
    unknown = sorted(set(changes) - set(rig.parameters))
    if unknown:
        raise BadInput(f"a {rig.to_core().short_label} rig has no parameter {', '.join(unknown)}")
    model = validate_model({**rig.rig_file(), **changes})
    return set_rig_model(rig=rig, model=model, source=source, calibration=calibration)


@transaction.atomic
def set_rig_codec(*, rig: Rig, codec: Any) -> Rig:
    """Set the default codec of a rig's captures (a built-in name or a gcps-codec/1 object), validated;
    :class:`BadInput` naming the problem. Stored captures keep the codec they were validated with."""
    value = validate_codec(codec)
    Rig.objects.filter(pk=rig.pk).update(codec=value)
    rig.refresh_from_db()
    return rig


def require_capability(rig: Rig, able: bool, what: str, instead: str = "") -> None:
    """BadInput saying that the rig's model cannot do ``what`` (``able`` False), and what to do ``instead``."""
    if not able:
        label = rig.to_core().short_label
        raise BadInput(f"rig {rig.pk} is a {label} rig: {what}" + (f" ({instead})" if instead else ""))


@transaction.atomic
def restore_rig_entry(*, rig: Rig, entry_id: Any) -> Rig:
    """Make an earlier entry of the rig's history its current values again, as a new entry (source
    ``restored``, pointing to the entry and to the calibration that had set it).

    The entry's model becomes the rig's (a rig converted by a projector-camera calibration goes
    back to its crossed-axes values, and forth). The default codec is kept. Measurements made
    before keep the values they were made with.

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
    return set_rig_model(
        rig=rig,
        model=validate_model(entry.values),
        source=RigParameters.Source.RESTORED,
        calibration=entry.calibration,
        procam=entry.procam_calibration,
        restored_from=entry,
    )


def read_calibration_upload(
    upload: Any, *, projector_size: tuple[float, float], camera_size: tuple[int, int] | None = None
) -> tuple[Any, dict[str, Any]]:
    """The pinhole rig of an uploaded OpenCV FileStorage calibration file (YAML or XML), read as
    ``gcps rig import --opencv FILE`` reads it (:func:`metrology.core.rig_import.import_rig`: the
    same recognition of node names, the same messages), and what was read (``read``: each value's
    node, ``camera_size``, ``triangulate_auto``), sources named by the uploaded file's name.
    :class:`BadInput` with the import's message."""
    import tempfile
    from pathlib import Path

    from metrology.core.rig_import import RigImportError, import_rig

    filename = Path(str(getattr(upload, "name", "") or "calibration.yml")).name
    if Path(filename).suffix.lower() not in (".yml", ".yaml", ".xml"):
        raise BadInput(f"{filename}: expected an OpenCV FileStorage .yml, .yaml or .xml file")
    size = getattr(upload, "size", None)
    if size is not None and size > settings.GCPS_MAX_RIG_FILE_BYTES:
        raise BadInput(f"{filename}: a calibration file is at most {settings.GCPS_MAX_RIG_FILE_BYTES} bytes")
    with tempfile.TemporaryDirectory(prefix="gcps-rig-import-") as tmp:
        path = Path(tmp) / filename
        with path.open("wb") as out:
            for chunk in upload.chunks() if hasattr(upload, "chunks") else [upload.read()]:
                out.write(chunk)
        try:
            imported = import_rig(projector_size=projector_size, camera_size=camera_size, opencv=str(path))
        except (RigImportError, ValueError) as exc:
            raise BadInput(str(exc).replace(f"{tmp}/", "")) from None
        summary = json.loads(json.dumps(imported.summary()).replace(f"{tmp}/", ""))
    return imported.rig, summary


def import_calibration_file(
    *,
    owner,
    upload: Any,
    projector_size: tuple[float, float],
    camera_size: tuple[int, int] | None = None,
    name: str = "",
    codec: Any = None,
) -> tuple[Rig, dict[str, Any]]:
    """Create a rig from an uploaded calibration file (:func:`read_calibration_upload`); returns the
    rig and what was read."""
    model, summary = read_calibration_upload(upload, projector_size=projector_size, camera_size=camera_size)
    rig = create_rig(owner=owner, data={**model.to_dict(), "name": name, "codec": codec})
    return rig, summary


def import_calibration_into_rig(
    *,
    rig: Rig,
    upload: Any,
    projector_size: tuple[float, float],
    camera_size: tuple[int, int] | None = None,
) -> tuple[Rig, dict[str, Any]]:
    """Give an existing rig the values of an uploaded calibration file (:func:`read_calibration_upload`),
    recorded in its history as ``imported`` (a crossed-axes rig becomes a pinhole rig; its former
    values stay in the history, and Restore brings them back). The default codec is kept. Returns
    the rig and what was read."""
    model, summary = read_calibration_upload(upload, projector_size=projector_size, camera_size=camera_size)
    return set_rig_model(rig=rig, model=model, source=RigParameters.Source.IMPORTED), summary
