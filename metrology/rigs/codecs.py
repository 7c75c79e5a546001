"""Stored codec values (docs/codecs.md): a built-in name (``"gcps-v1"``, ``"gcps-v1:1280x800"``) or a
gcps-codec/1 object, parsed and validated for storing. A rig's default codec (``Rig.codec``) and a
capture's codec (:mod:`metrology.captures.codecs`) are such values.
"""

from __future__ import annotations

from typing import Any

from metrology.core.codecs.model import Codec, CodecError, builtin_codec, codec_from_dict
from metrology.errors import BadInput
from metrology.rigs.models import DEFAULT_CODEC

MAX_CODEC_FRAMES = 256
"""Most frames a stored codec may have (a capture's zip of that many images must fit the upload limit anyway)."""


def codec_of(value: Any) -> Codec:
    """The :class:`Codec` of a stored value (a built-in name or a gcps-codec/1 object).

    Raises
    ------
    CodecError
        Naming the problem (unknown name, bad field...).
    """
    if isinstance(value, str):
        return builtin_codec(value)
    if isinstance(value, dict):
        return codec_from_dict(value)
    raise CodecError(f"a codec is a built-in name (e.g. {DEFAULT_CODEC!r}) or a gcps-codec/1 object, got {value!r}")


def validate_codec(value: Any) -> Any:
    """A codec value checked and normalised for storing: a built-in name as given, an object as its
    canonical gcps-codec/1 form. Raises :class:`BadInput` naming the problem."""
    try:
        codec = codec_of(value)
    except CodecError as exc:
        raise BadInput(f"codec: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise BadInput(f"codec: {exc}") from None
    if codec.n_frames > MAX_CODEC_FRAMES:
        raise BadInput(f"codec: {codec.n_frames} frames, more than the limit of {MAX_CODEC_FRAMES}")
    return value if isinstance(value, str) else codec.to_dict()


def capture_default(rig: Any) -> Any:
    """The rig's default codec value (gcps-v1 when unset)."""
    return rig.codec if rig.codec is not None else DEFAULT_CODEC


def check_codec_for_rig(codec: Codec, rig: Any) -> None:
    """Raise :class:`BadInput` unless ``rig``'s model can measure captures of ``codec`` (the model's
    :meth:`~metrology.core.geometry.base.GeometryModel.check_codec`: a projector of the model's own
    size, the triangulated axis coded)."""
    from metrology.core.geometry import GeometryError

    try:
        rig.to_core().check_codec((codec.projector_width, codec.projector_height), tuple(codec.axes))
    except GeometryError as exc:
        raise BadInput(f"capture codec refused: {exc}") from None


def default_codec_for(model: Any) -> str:
    """The default codec of a new rig of ``model`` (a core geometric model) when its file names none:
    the paper's gcps-v1, at the model's own projector size where it has one (a pinhole rig's
    projector, e.g. ``gcps-v1:1280x800``) and measures with it; else plain gcps-v1 (the rig's pages
    then say what to set)."""
    from metrology.core.geometry import GeometryError

    size = model.projector_size  # the model's own (no table is built: a rig's creation stays cheap)
    if size is None or not all(float(x).is_integer() for x in size):
        return DEFAULT_CODEC
    name = f"{DEFAULT_CODEC}:{int(size[0])}x{int(size[1])}"
    codec = builtin_codec(name)
    try:
        model.check_codec((codec.projector_width, codec.projector_height), tuple(codec.axes))
    except GeometryError:
        return DEFAULT_CODEC
    return name
