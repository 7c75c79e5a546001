"""Reads for rigs, always scoped to the user (another user's rig is not found)."""

from __future__ import annotations

from dataclasses import dataclass

from django.db.models import QuerySet
from django.http import Http404

from metrology.rigs.models import Rig


def rigs_for(user) -> QuerySet[Rig]:
    """The user's rigs. Their history is read when asked for (``rig.history``: the rig's own page and
    URL show it, one query); lists and the views of a rig's captures, sessions and jobs never do,
    and prefetching it loaded every entry's rig file with every rig they read."""
    return Rig.objects.filter(owner=user)


def get_rig(user, rig_id) -> Rig:
    rig = rigs_for(user).filter(pk=rig_id).first() if str(rig_id).isdigit() else None
    if rig is None:
        raise Http404(f"No rig {rig_id} among yours.")
    return rig


@dataclass(frozen=True)
class RigCapabilities:
    """What a rig's model can do, for the pages (they offer only what works on that rig).

    Attributes
    ----------
    model : str
        The model's label.
    paper_calibration : bool
        The paper's master-block calibration applies (the model has L and alpha).
    sensitivity : bool
        The paper's sensitivity study (Figs. 4-6) applies (same parameters).
    requires_reference : bool
        Measurements need a capture of the reference plane.
    unreferenced_result : str
        What a measurement without a reference gives (``height`` or ``depth``).
    scalar_parameters : tuple
        The model's single-number values (a form edits them one by one; else import a file).
    simulation_refused : str
        Why the virtual rig cannot simulate captures of the rig's default codec (the model does not
        measure with it), or empty: the virtual rig renders every model.
    suggested_codec : str
        A built-in codec the model measures with, to offer as the default codec where the rig's
        does not do (:func:`~metrology.rigs.codecs.default_codec_for`), or empty.
    """

    model: str
    paper_calibration: bool
    sensitivity: bool
    requires_reference: bool
    unreferenced_result: str
    scalar_parameters: tuple
    simulation_refused: str
    suggested_codec: str = ""


def rig_capabilities(rig: Rig) -> RigCapabilities:
    """What ``rig``'s model can do (:class:`RigCapabilities`), from the core's model."""
    from metrology.core.codecs.model import CodecError
    from metrology.core.geometry import GeometryError
    from metrology.rigs.codecs import capture_default, codec_of, default_codec_for

    model = rig.to_core()
    refused = suggested = ""
    try:
        codec = codec_of(capture_default(rig))
        model.check_codec((codec.projector_width, codec.projector_height), tuple(codec.axes))
    except (CodecError, GeometryError) as exc:
        refused = str(exc)
        suggested = default_codec_for(model)
        if suggested == capture_default(rig):
            suggested = ""
    return RigCapabilities(
        model=model.label,
        paper_calibration=bool(model.calibration_parameters),
        sensitivity=bool(model.calibration_parameters),
        requires_reference=model.requires_reference,
        unreferenced_result=model.unreferenced_result,
        scalar_parameters=model.scalar_parameters,
        simulation_refused=refused,
        suggested_codec=suggested,
    )


def rig_history(rig: Rig) -> list[dict]:
    """The rig's values over time, oldest first: ``id``, ``values`` (the rig file), ``model`` (its
    model's label), ``summary`` (the values in one line), ``source``, ``calibration`` /
    ``procam_calibration`` (the id of the calibration that set them, or None), ``restored_from``
    (the entry a restore copied), ``restored_from_at`` (that entry's date), ``at`` and ``current``
    (True for the latest entry, the rig's values now)."""
    entries = list(rig.history.all())
    dates = {entry.pk: entry.created_at for entry in entries}
    rows = []
    for index, entry in enumerate(entries):
        try:
            model = entry.to_core()
            label, summary = model.label, model.summary()
        except ValueError:  # an entry the core no longer reads: shown as stored
            label, summary = "unreadable", str(entry.values)[:200]
        rows.append(
            {
                "id": entry.pk,
                "values": entry.values,
                "model": label,
                "summary": summary,
                "source": entry.source,
                "calibration": entry.calibration_id,
                "procam_calibration": entry.procam_calibration_id,
                "restored_from": entry.restored_from_id,
                "restored_from_at": dates.get(entry.restored_from_id) if entry.restored_from_id else None,
                "at": entry.created_at,
                "current": index == len(entries) - 1,
            }
        )
    return rows


def rig_value_rows(values: dict) -> list[tuple[str, str]]:
    """A stored rig file (the values a result was made with) as ``(name, value with its unit)`` rows
    for a page: the model's label, then the model's :meth:`value_rows`; a file the core no longer
    reads is shown as stored."""
    from metrology.core.geometry import model_from_dict

    try:
        model = model_from_dict(values)
    except (TypeError, ValueError):  # GeometryError is a ValueError
        return [(str(key), str(value)[:200]) for key, value in (values or {}).items()]
    return [("model", model.label), *model.value_rows()]
