"""Geometric models of projector-camera rigs behind one interface (:mod:`.base`).

Files:

- :mod:`.base`: the seam's conventions (frames, units, axes, NaN), :class:`GeometryModel`,
  :class:`PreparedGeometry`, :class:`ReferenceSurface`, :class:`GeometryOptions`, and
  :func:`triangulate_frame`;
- :mod:`.crossed_axes`: the paper's crossed-optical-axes rig (``"model": "crossed_axes"``, the
  default of a rig file without a ``model`` key);
- :mod:`.pinhole`: a calibrated pinhole camera and projector with lens distortion
  (``"model": "pinhole"``, docs/pinhole.md);
- :mod:`.stereo`: two calibrated cameras and a projector that only labels the surface
  (``"model": "stereo"``, docs/stereo.md); :mod:`.stereo_match` prepares it (rectification,
  matching along epipolar lines, triangulation of the two rays);
- :mod:`.rig_file`: parsing and validating calibrated rig files' values (K, dist, R, T);
- :mod:`.projector_grid`: a distorted projector's undistortion sampled on a grid.

:data:`MODELS` is the registry: a new model is one module here and one entry there.
:func:`model_from_dict` builds the model a rig file's JSON object describes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from metrology.core.geometry.base import (
    AXES,
    CameraRays,
    CombinedMaps,
    GeometryError,
    GeometryModel,
    GeometryOptions,
    ImageAxes,
    ParameterField,
    PlaneCoordinates,
    PreparedGeometry,
    ReferenceSurface,
    Triangulation,
    model_name,
    triangulate_frame,
)
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.geometry.stereo import StereoRig

MODELS: dict[str, type[GeometryModel]] = {Rig.model: Rig, PinholeRig.model: PinholeRig, StereoRig.model: StereoRig}
"""Every geometric model, keyed by the rig file's ``model`` value."""


def model_class(name: str) -> type[GeometryModel]:
    """The model class registered as ``name``; :class:`GeometryError` listing the models otherwise."""
    cls = MODELS.get(name)
    if cls is None:
        raise GeometryError(f"rig model must be one of {', '.join(sorted(MODELS))}, got {name!r}")
    return cls


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
    return model_class(model_name(data)).from_dict(data)


def model_from_parameters(name: str, parameters: Mapping[str, Any]) -> GeometryModel:
    """The model ``name`` with the values :meth:`GeometryModel.parameters` gave (a rig file
    without its ``model`` key)."""
    if not isinstance(parameters, Mapping):
        raise GeometryError(f"rig parameters must be a JSON object, got {type(parameters).__name__}")
    return model_from_dict({**parameters, "model": name})


__all__ = [
    "AXES",
    "MODELS",
    "CameraRays",
    "CombinedMaps",
    "GeometryError",
    "GeometryModel",
    "GeometryOptions",
    "ImageAxes",
    "ParameterField",
    "PinholeRig",
    "PlaneCoordinates",
    "PreparedGeometry",
    "ReferenceSurface",
    "Rig",
    "StereoRig",
    "Triangulation",
    "model_class",
    "model_from_dict",
    "model_from_parameters",
    "triangulate_frame",
]
