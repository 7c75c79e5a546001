"""The codec an acquisition projects, and its projector images.

A codec is given by name (``gcps-v1`` or ``gcps-v1:WIDTHxHEIGHT``: the paper's eleven patterns on a
projector of that size, default 1024x768), as a gcps-codec/1 document (docs/codecs.md), or as the
path of a codec file (``.json``). This module is the one place that turns a codec into projector images, so
switching to the codec package is a change here only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from metrology.core.patterns import PATTERN_NAMES, projector_patterns

DEFAULT_CODEC = "gcps-v1"


@dataclass(frozen=True)
class ProjectedCodec:
    """A codec ready to project: ``frame_names`` in frame order, projector ``width`` x ``height`` pixels."""

    name: str
    width: int
    height: int
    frame_names: tuple[str, ...]
    spec: str  # the canonical JSON-able spec (the name, or the codec document as JSON text)
    white: tuple[int, ...] = ()
    black: tuple[int, ...] = ()

    @property
    def n_frames(self) -> int:
        return len(self.frame_names)

    @property
    def is_gcps_v1(self) -> bool:
        return self.name == "gcps-v1"

    def images(self) -> np.ndarray:
        """``(n_frames, height, width)`` uint8 projector images, frame order."""
        return _images(self.spec, self.width, self.height)


def resolve_codec(codec: Any) -> ProjectedCodec:
    """The codec named by ``codec`` (a name, ``{"name": ...}``, or a gcps-codec/1 document).

    Raises
    ------
    ValueError
        Naming the option and the value when the codec is unknown or malformed.
    """
    if codec is None or codec == "":
        codec = DEFAULT_CODEC
    if isinstance(codec, dict) and set(codec) == {"name"}:
        codec = codec["name"]
    if isinstance(codec, str) and codec.strip().lower().endswith(".json"):
        import json
        from pathlib import Path

        path = Path(codec.strip())
        try:
            document = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"codec file {codec}: {exc}") from None
        if not isinstance(document, dict):
            raise ValueError(f"codec file {codec}: a gcps-codec/1 JSON object is needed")
        return _document_codec(document)
    if isinstance(codec, str):
        m = re.fullmatch(r"gcps-v1(?::(\d+)x(\d+))?", codec.strip())
        if m is None:
            raise ValueError(
                f"codec {codec!r} is not known; use gcps-v1 or gcps-v1:WIDTHxHEIGHT (e.g. gcps-v1:1280x800)"
            )
        width, height = (int(m.group(1)), int(m.group(2))) if m.group(1) else (1024, 768)
        if not (16 <= width <= 8192 and 16 <= height <= 8192):
            raise ValueError(f"codec {codec!r}: the projector size must be 16..8192 pixels each way")
        return ProjectedCodec("gcps-v1", width, height, PATTERN_NAMES, f"gcps-v1:{width}x{height}")
    if isinstance(codec, dict):
        return _document_codec(codec)
    raise ValueError(f"codec must be a name or a gcps-codec/1 document, got {type(codec).__name__}")


def _document_codec(document: dict) -> ProjectedCodec:
    try:
        from metrology.core.codecs import codec_from_dict  # issue 11's codec package
    except ImportError:
        raise ValueError("codec documents need the codec package (metrology.core.codecs); use gcps-v1") from None
    import json

    parsed = codec_from_dict(document)
    names = tuple(str(n) for n in parsed.frames) if not isinstance(parsed.frames, int) else ()
    if len(names) != parsed.n_frames:
        names = tuple(f"{k:02d}" for k in range(parsed.n_frames))
    return ProjectedCodec(
        parsed.name or "codec",
        parsed.projector_width,
        parsed.projector_height,
        names,
        json.dumps(parsed.to_dict(), sort_keys=True),
        tuple(parsed.white),
        tuple(parsed.black),
    )


@lru_cache(maxsize=4)
def _images(spec: str, width: int, height: int) -> np.ndarray:
    if spec.startswith("gcps-v1:"):
        images = projector_patterns(width, height)
    else:
        import json

        from metrology.core.codecs import codec_from_dict, codec_patterns

        images = codec_patterns(codec_from_dict(json.loads(spec)))
    images.setflags(write=False)
    return images


def frame_label(codec: ProjectedCodec, kind: str, frame: int) -> str:
    """A pattern's name for people: ``white``, ``black``, ``test`` or the codec's frame name."""
    if kind == "frame":
        return codec.frame_names[frame] if 0 <= frame < codec.n_frames else f"frame {frame}"
    return kind
