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

Each model's module is imported when its class is first asked for (:data:`MODELS`).

:data:`MODELS` is the registry: a new model is one module here and one entry there.
:func:`model_from_dict` builds the model a rig file's JSON object describes.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

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

if TYPE_CHECKING:
    from metrology.core.geometry.crossed_axes import Rig
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.core.geometry.stereo import StereoRig

MODEL_CLASSES: dict[str, tuple[str, str]] = {
    "crossed_axes": ("metrology.core.geometry.crossed_axes", "Rig"),
    "pinhole": ("metrology.core.geometry.pinhole", "PinholeRig"),
    "stereo": ("metrology.core.geometry.stereo", "StereoRig"),
}
"""Where each model's class lives (module, class name), keyed by its ``model`` value (the class's
``model`` attribute): a model's module is imported when its class is first asked for, so that a
process measuring with one model does not import the others (the pinhole and stereo modules with
their kernels: 20-50 ms of ``gcps measure``'s start-up on a crossed-axes rig)."""


class _Models(Mapping[str, "type[GeometryModel]"]):
    """The registry: a read-only mapping of :data:`MODEL_CLASSES`'s keys to the classes, each
    imported on first access."""

    def __getitem__(self, name: str) -> type[GeometryModel]:
        module, cls = MODEL_CLASSES[name]
        model: type[GeometryModel] = getattr(importlib.import_module(module), cls)
        return model

    def __iter__(self) -> Iterator[str]:
        return iter(MODEL_CLASSES)

    def __len__(self) -> int:
        return len(MODEL_CLASSES)


MODELS: Mapping[str, type[GeometryModel]] = _Models()
"""Every geometric model, keyed by the rig file's ``model`` value (imported on first access)."""


def __getattr__(name: str) -> Any:
    """The model classes (``Rig``, ``PinholeRig``, ``StereoRig``), imported on first use (PEP 562)."""
    for key, (_, cls) in MODEL_CLASSES.items():
        if cls == name:
            value = MODELS[key]
            globals()[name] = value
            return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
