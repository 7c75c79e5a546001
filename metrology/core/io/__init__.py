"""File formats of gcps-v1 (docs/file-formats.md): capture stacks, rigs, heights, series.

Capture stacks
--------------
A capture stack is a folder or a .zip holding exactly one image per pattern of
:data:`~metrology.core.patterns.PATTERN_NAMES`, named ``GC_0.png`` .. ``PS_3.png``
with extension ``.png``, ``.tif``, ``.tiff`` or ``.bmp`` (extension case-insensitive,
pattern name case-sensitive). :func:`read_stack` refuses anything else with a
:class:`StackError` whose one-line message names the problem.

- A zip may hold the eleven files at its top level or inside one single folder; a folder
  may likewise hold them directly or inside one single sub-folder.
- Junk that operating systems add is ignored, and nothing else: the ``__MACOSX/`` tree,
  AppleDouble files ``._*``, ``.DS_Store``, ``Thumbs.db`` and ``desktop.ini``
  (see :data:`JUNK_NAMES`). Directory entries of a zip are ignored.
- Zips are read into memory (``cv2.imdecode``), never extracted. Before anything is
  decompressed, member names with ``..`` components or absolute paths are refused, and so
  are archives whose declared uncompressed sizes add up beyond ``max_bytes`` or whose
  members claim a compression ratio beyond ``max_ratio`` (zip bombs).
- Each image's width and height are parsed from its header (PNG IHDR, BMP info header,
  TIFF first IFD) and checked against ``max_pixels`` and the expected shape *before* it
  is decoded, so a small file claiming enormous dimensions is refused cheaply.
- Colour images are converted to grey (alpha ignored); samples must be 8- or 16-bit
  unsigned integers, and all eleven images must share one bit depth and one shape.

Other files
-----------
Rig files are JSON (:func:`read_rig`, :func:`write_rig`; :func:`read_model` for any geometric
model); height maps are float32
``.npy`` or float32 TIFF (:func:`write_height_npy`, :func:`write_height_tiff`); the application's stored
point maps are the measured pixels' points and a bit mask (:func:`write_point_map`,
:func:`read_point_map`, to and from file objects and bytes); stage
series are ``SERIES.json`` files (:func:`read_series`, :func:`write_series`). Every
writer is atomic: it writes a temporary file in the destination folder and renames it
into place (``os.replace``), so no partial output is ever visible under the final name.

Modules: :mod:`.atomic` (atomic writes), :mod:`.images` (image headers and decoding),
:mod:`.archives` (folder and zip reading, zip-bomb checks), :mod:`.stacks` (capture stacks),
:mod:`.exposures` (the ``exposures.json`` manifest of multi-exposure captures, read with their
stacks by :func:`metrology.core.codecs.stack.read_exposure_stack`),
:mod:`.rigs`, :mod:`.heights`, :mod:`.points` and :mod:`.series`; every public name is importable from
``metrology.core.io`` as before (those of :mod:`.rigs`, :mod:`.points` and :mod:`.series` on first
use: :data:`LAZY_NAMES`).
"""

from __future__ import annotations

# ``os`` and ``cv2`` stay reachable as attributes (tests patch ``metrology.core.io.os.replace``).
import importlib
import os
from typing import TYPE_CHECKING, Any

import cv2

from metrology.core.io.archives import (
    DEFAULT_MAX_BYTES,
    DEFAULT_MAX_RATIO,
    IMAGE_EXTENSIONS,
    JUNK_NAMES,
    MAX_ARCHIVE_MEMBERS,
)
from metrology.core.io.atomic import atomic_path, write_text_atomic
from metrology.core.io.errors import StackError
from metrology.core.io.heights import read_height_npy, write_height_npy, write_height_tiff
from metrology.core.io.images import DEFAULT_MAX_PIXELS, checked_header, decode_grey_image, image_header_size
from metrology.core.io.stacks import CaptureStack, encode_stack, read_stack, read_verified_stack, write_stack

if TYPE_CHECKING:
    from metrology.core.io.points import read_point_map, write_point_map
    from metrology.core.io.rigs import read_model, read_rig, write_rig
    from metrology.core.io.series import StagePosition, StageSeries, read_series, series_capture_name, write_series

LAZY_NAMES = {
    **dict.fromkeys(("read_model", "read_rig", "write_rig"), "rigs"),
    **dict.fromkeys(("read_point_map", "write_point_map"), "points"),
    **dict.fromkeys(("StagePosition", "StageSeries", "read_series", "series_capture_name", "write_series"), "series"),
}
"""The names of :mod:`.rigs`, :mod:`.points` and :mod:`.series` (name -> module), imported on first
use (:func:`__getattr__`): reading a capture stack does not import the geometry package (every
model's module), so that ``gcps measure`` decodes the object's images while its main thread imports
the models, nor the point maps' and stage series' modules, which measuring does not use."""


def __getattr__(name: str) -> Any:
    """:data:`LAZY_NAMES` from their modules, imported here on first use (PEP 562)."""
    if name in LAZY_NAMES:
        module = importlib.import_module(f"{__name__}.{LAZY_NAMES[name]}")
        value = getattr(module, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_MAX_BYTES",
    "DEFAULT_MAX_PIXELS",
    "DEFAULT_MAX_RATIO",
    "IMAGE_EXTENSIONS",
    "JUNK_NAMES",
    "MAX_ARCHIVE_MEMBERS",
    "CaptureStack",
    "StackError",
    "StagePosition",
    "StageSeries",
    "atomic_path",
    "checked_header",
    "cv2",
    "decode_grey_image",
    "encode_stack",
    "image_header_size",
    "os",
    "read_height_npy",
    "read_model",
    "read_point_map",
    "read_rig",
    "read_series",
    "read_stack",
    "read_verified_stack",
    "series_capture_name",
    "write_height_npy",
    "write_height_tiff",
    "write_point_map",
    "write_rig",
    "write_series",
    "write_stack",
    "write_text_atomic",
]
