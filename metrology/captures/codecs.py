"""Codecs of rigs and captures (docs/codecs.md): stored values, validation, reading stacks of any codec.

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
from metrology.rigs.codecs import MAX_CODEC_FRAMES, codec_of, validate_codec
from metrology.rigs.models import DEFAULT_CODEC

__all__ = ["MAX_CODEC_FRAMES", "codec_of", "validate_codec"]  # stored-codec values live with the rig's default codec


def is_gcps_v1(codec: Codec) -> bool:
    """True for the built-in gcps-v1 (any projector size): the paper's eleven named patterns."""
    return codec.name == "gcps-v1"


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


def read_upload_stack(
    upload: Any, rig: Any, *, expected_bit_depth: int | None = None, codec: Any = None
) -> tuple[Any, Any]:
    """Validate an uploaded zip for ``rig`` with its codec: returns ``(stored codec value, stack)``.

    The codec is the zip's own ``codec.json``, else the rig's default; or, when ``codec`` is given
    (the codec an acquisition projected), that one, and a ``codec.json`` in the zip must then be
    the same codec. gcps-v1 stacks are read by
    the gcps-v1 reader as before (the eleven named patterns); any other codec by the codec reader,
    which checks the frames against the codec; the frames must be the rig's camera size and the
    codec must code the projector's u axis (what the crossed-axes rig triangulates). A pinhole
    rig's uploads are all read by the codec reader (gcps-v1 too), and the codec's projector size
    must be the rig's. ``stack`` has ``images`` ``(frames, H, W)`` and ``bit_depth``.

    Raises
    ------
    BadInput
        Naming the problem (bad codec.json, a stack that does not match its codec, ...).
    """
    from metrology.captures.services import read_capture_stack
    from metrology.core.codecs.stack import read_capture_codec, read_codec_stack
    from metrology.core.io import StackError

    try:
        own = read_capture_codec(upload, max_bytes=codec_stack_limits(rig, MAX_CODEC_FRAMES)["max_bytes"])
    except CodecError as exc:
        raise BadInput(f"capture codec refused: {exc}") from None
    except StackError as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    if codec is not None:
        value = validate_codec(codec)
        if own is not None and own.to_dict() != codec_of(value).to_dict():
            raise BadInput("capture codec refused: the zip's codec.json is not the codec that was projected")
    else:
        value = validate_codec(own.to_dict()) if own is not None else capture_default(rig)
    codec = codec_of(value)
    pinhole = bool(getattr(rig, "is_pinhole", False))
    if is_gcps_v1(codec) and not pinhole:
        return value, read_capture_stack(upload, rig, expected_bit_depth=expected_bit_depth)
    check_codec_for_rig(codec, rig)
    upload.seek(0)
    limits = codec_stack_limits(rig, codec.n_frames)
    try:
        stack = read_codec_stack(upload, codec, max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"])
    except (StackError, CodecError) as exc:
        raise BadInput(f"capture stack refused: {exc}") from None
    height, width = stack.images.shape[1:]
    if (height, width) != (rig.height_px, rig.width_px):
        raise BadInput(
            f"capture stack refused: the frames are {width}x{height} px "
            f"but the rig is {rig.width_px}x{rig.height_px} px"
        )
    if expected_bit_depth is not None and stack.bit_depth != expected_bit_depth:
        raise BadInput(
            f"capture stack refused: the images are {stack.bit_depth}-bit "
            f"but bit_depth {expected_bit_depth} was declared"
        )
    return value, stack


def check_codec_for_rig(codec: Codec, rig: Any) -> None:
    """Raise :class:`BadInput` unless ``rig`` can measure with ``codec``: a pinhole rig needs the codec's
    projector size to be its projector's; a crossed-axes rig needs the u axis coded (it triangulates u).
    gcps-v1 on a crossed-axes rig always passes."""
    if getattr(rig, "is_pinhole", False):
        projector = (rig.pinhole or {}).get("projector", {})
        size = (float(projector.get("width", 0)), float(projector.get("height", 0)))
        if (float(codec.projector_width), float(codec.projector_height)) != size:
            raise BadInput(
                f"capture codec refused: its projector is {codec.projector_width}x{codec.projector_height} "
                f"but the rig's projector is {size[0]:g}x{size[1]:g}"
            )
    elif "u" not in codec.axes:
        raise BadInput("capture codec refused: it does not code the projector's u axis, which the rig triangulates")


def capture_default(rig: Any) -> Any:
    """The rig's default codec value (gcps-v1 when unset)."""
    return rig.codec if rig.codec is not None else DEFAULT_CODEC


def load_codec_stack(capture: Any) -> Any:
    """The stored stack of a capture of any codec, in codec order (a :class:`CodecStack`); in a worker.

    Raises ``ValueError`` if it is not stored or does not match its codec.
    """
    from metrology.core.codecs.stack import read_codec_stack

    if not capture.file:
        raise ValueError(f"capture {capture.pk} has no stored stack yet (its simulation has not finished)")
    codec = capture_codec(capture)
    limits = codec_stack_limits(capture.rig, codec.n_frames)
    with capture.file.open("rb") as handle:
        return read_codec_stack(handle, codec, max_pixels=limits["max_pixels"], max_bytes=limits["max_bytes"])


def codec_stack_limits(rig: Any, frames: int) -> dict[str, int]:
    """Bounds for the codec reader: pixels per image, and expanded bytes of a zip of ``frames`` images
    (as :func:`metrology.captures.services.stack_limits` for eleven)."""
    from django.conf import settings

    from metrology.captures.services import MIB

    pixels = rig.width_px * rig.height_px
    expanded = (frames + 1) * (pixels * 8 + MIB)
    return {
        "max_pixels": min(pixels, settings.GCPS_MAX_STACK_PIXELS),
        "max_bytes": min(expanded, max(settings.GCPS_MAX_UPLOAD_BYTES, 64 * MIB) * 4),
    }
