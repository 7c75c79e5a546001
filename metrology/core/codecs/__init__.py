"""Codecs (gcps-codec/1): any structured-light pattern sequence, as data, decoded to projector coordinates.

- :mod:`~metrology.core.codecs.model`: the codec dataclasses, validation, JSON, built-in ``gcps-v1``;
- :mod:`~metrology.core.codecs.decode`: decoding a stack of any codec to absolute projector coordinates;
- :mod:`~metrology.core.codecs.render`: projector patterns and virtual-rig camera images of any codec
  (loaded when first used);
- :mod:`~metrology.core.codecs.stack`: reading the frames of a capture folder or zip in codec order,
  and multi-exposure captures (one stack per exposure, docs/exposures.md);
- :mod:`~metrology.core.codecs.exposures`: multi-exposure captures decoded and fused per pixel.

docs/codecs.md describes the file format, the reason codes and the quality file.
"""

from typing import Any

from metrology.core.codecs.model import (
    AXES,
    CODEC_FORMAT,
    Axis,
    Codec,
    CodecError,
    GrayCode,
    PhaseSequence,
    builtin_codec,
    codec_from_dict,
    codec_from_json,
    gcps_v1_codec,
    natural_key,
    read_codec,
    write_codec,
)

__all__ = [
    "AXES",
    "CODEC_FORMAT",
    "Axis",
    "Codec",
    "CodecError",
    "GrayCode",
    "PhaseSequence",
    "builtin_codec",
    "codec_from_dict",
    "codec_from_json",
    "codec_patterns",
    "gcps_v1_codec",
    "natural_key",
    "read_codec",
    "render_codec",
    "write_codec",
]

_RENDERING = {"codec_patterns", "render_codec"}
"""Names of :mod:`.render`, loaded when first used (it imports scipy; decoding needs none of it)."""


def __getattr__(name: str) -> Any:
    if name in _RENDERING:
        from metrology.core.codecs import render

        return getattr(render, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
