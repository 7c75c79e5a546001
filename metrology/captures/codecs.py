"""Codecs of captures (docs/codecs.md): the codec a capture's stack was checked with, labels for pages,
and the one codec of a job's captures. Reading the stacks is :mod:`metrology.captures.stacks`'s.

A codec is stored as JSON: a built-in name (``"gcps-v1"``, ``"gcps-v1:1280x800"``) or a
gcps-codec/1 object. A rig has a default codec (``Rig.codec``, gcps-v1 unless set); a capture
stores the codec its stack was validated with (``Capture.codec``: the upload's own
``codec.json``, else the rig's default at upload time; virtual captures are gcps-v1). A
capture without one (stored before codecs existed) has its rig's default.
"""

from __future__ import annotations

from typing import Any

from metrology.core.codecs.model import Codec, CodecError
from metrology.errors import BadInput
from metrology.rigs.codecs import codec_of


def codec_label(value: Any) -> str:
    """A short description of a stored codec for pages: the built-in name, or its frames and axes."""
    if value is None:
        return "the rig's default"
    if isinstance(value, str):
        return value
    try:
        codec = codec_of(value)
    except (CodecError, TypeError, ValueError):
        return "invalid codec"
    axes = ", ".join(sorted(codec.axes))
    size = f"{codec.projector_width}x{codec.projector_height}"
    return f"gcps-codec/1: {codec.n_frames} frames, axes {axes}, projector {size}"


def capture_codec_value(capture: Any) -> Any:
    """The stored codec of a capture: its own, else its rig's default."""
    return capture.codec if capture.codec is not None else capture.rig.codec


def capture_codec(capture: Any) -> Codec:
    """The :class:`Codec` of a capture's stack (its own, else its rig's default)."""
    return codec_of(capture_codec_value(capture))


def captures_codec_value(model: Any, reference: Any, other: Any, *, what: str = "object") -> Any:
    """The stored codec value that a job's captures share (each its own, else its rig's default),
    checked for the rig's ``model``; ``reference`` may be None.

    Raises
    ------
    BadInput
        When they differ, or the model cannot measure with the codec.
    """
    from metrology.core.geometry import GeometryError

    value = capture_codec_value(other)
    codec = codec_of(value)
    if reference is not None and codec_of(capture_codec_value(reference)) != codec:
        raise BadInput(
            f"{what}: capture {other.pk} has another codec than the reference capture {reference.pk} "
            "(the captures of one job must use one codec)"
        )
    try:
        model.check_codec((codec.projector_width, codec.projector_height), tuple(codec.axes))
    except GeometryError as exc:
        raise BadInput(f"{what}: the codec of capture {other.pk}: {exc}") from None
    return value
