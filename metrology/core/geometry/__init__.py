"""Geometric models of projector-camera rigs behind one interface (:mod:`.base`).

- :mod:`.pinhole`: a calibrated pinhole camera and projector with lens distortion
  (``"model": "pinhole"``, docs/pinhole.md).
- :mod:`.crossed_axes`: the paper's crossed-optical-axes rig (``"model": "crossed_axes"``,
  the default of a rig file without a ``model`` key).

:func:`model_from_dict` builds the model a rig file's JSON object describes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from metrology.core.geometry.base import (
    AXES,
    CameraRays,
    GeometryError,
    GeometryModel,
    PreparedGeometry,
    ReferenceSurface,
    Triangulation,
    model_name,
    triangulate_frame,
)
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.geometry.pinhole import PinholeRig

MODEL_READERS: dict[str, Callable[[Mapping[str, Any]], GeometryModel]] = {
    "crossed_axes": Rig.from_dict,
    "pinhole": PinholeRig.from_dict,
}
"""Rig-file reader of each model, keyed by the rig file's ``model`` value."""


def model_from_dict(data: Mapping[str, Any]) -> GeometryModel:
    """The geometric model of a rig file's JSON object, dispatching on ``data.get("model", "crossed_axes")``.

    Raises
    ------
    GeometryError
        If the object is not a mapping, names an unknown model, or the model refuses it
        (the message names the key and the value).
    """
    if not isinstance(data, Mapping):
        raise GeometryError(f"rig must be a JSON object, got {type(data).__name__}")
    name = model_name(data)
    reader = MODEL_READERS.get(name)
    if reader is None:
        raise GeometryError(f"rig model must be one of {', '.join(sorted(MODEL_READERS))}, got {name!r}")
    return reader(data)


__all__ = [
    "AXES",
    "MODEL_READERS",
    "CameraRays",
    "GeometryError",
    "GeometryModel",
    "PinholeRig",
    "PreparedGeometry",
    "ReferenceSurface",
    "Rig",
    "Triangulation",
    "model_from_dict",
    "triangulate_frame",
]
