"""Codecs (gcps-codec/1): any structured-light pattern sequence, as data, decoded to projector coordinates.

- :mod:`~metrology.core.codecs.model`: the codec dataclasses, validation, JSON, built-in ``gcps-v1``;
- :mod:`~metrology.core.codecs.decode`: decoding a stack of any codec to absolute projector coordinates;
- :mod:`~metrology.core.codecs.render`: projector patterns and virtual-rig camera images of any codec;
- :mod:`~metrology.core.codecs.stack`: reading the frames of a capture folder or zip in codec order.

docs/codecs.md describes the file format, the reason codes and the quality file.
"""

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
from metrology.core.codecs.render import codec_patterns, crossed_rig_truth, render_codec

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
    "crossed_rig_truth",
    "gcps_v1_codec",
    "natural_key",
    "read_codec",
    "render_codec",
    "write_codec",
]
