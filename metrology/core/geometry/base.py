"""The geometric-model seam: what every rig model gives the measurement pipeline.

A *geometric model* (a :class:`GeometryModel`) is the serialisable description of a
projector-camera rig: the paper's crossed-optical-axes rig
(:mod:`metrology.core.geometry.crossed_axes`, ``"model": "crossed_axes"``, the default of a rig
file without a ``model`` key) or a calibrated pinhole rig (``"model": "pinhole"``). The
pipeline never computes geometry itself: it asks the model to :meth:`~GeometryModel.prepare`
for a frame size, which returns a :class:`PreparedGeometry` holding the per-pixel tables
(computed once, cached per model and frame size), and then calls
:meth:`PreparedGeometry.triangulate_rows` tile by tile.

Conventions shared by every model
---------------------------------
- Camera frames are ``(H, W)`` = ``(height_px, width_px)`` arrays, row ``k``, column ``j``.
- **Projector coordinates** are decoded per camera pixel, one float32 map per coded projector
  axis: ``u`` runs across the projector's columns (a projector column ``j`` is centred at
  ``u = j``, OpenCV convention), ``v`` across its rows; both in projector units (the codec's:
  projector pixels, or the unit of the projector calibration); NaN where not decoded. A
  model is prepared with the projector's size in those units. A crossed-axes model prepared
  *without* a projector size reads ``u`` as the paper's light code ``l`` (code units, 0 on
  ray PS, ``nlp`` on ray PT); with a projector of width ``w`` it maps ``u`` to
  ``l = (u + 0.5) nlp / w``.
- **Points** are ``(..., 3)`` float32 millimetres in the *model frame*, NaN where not
  triangulated: for the crossed-axes model the paper's frame (X from Q on the reference plane
  R, Y, Z the height above R; points are ``(X_H, Y_H, z)``), for a pinhole model the camera
  frame.
- **Heights** are float32 millimetres above a reference surface, positive towards the rig
  (the camera), NaN where not triangulated. A model with a modelled reference plane (the
  crossed-axes rig's R) gives heights without a reference capture; any model gives heights
  above a :class:`ReferenceSurface` prepared from a capture of the reference plane.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

AXES: tuple[str, ...] = ("u", "v")
"""Projector axes a codec may code: ``u`` across projector columns, ``v`` across rows."""


class GeometryError(ValueError):
    """A geometric model is malformed, or is asked for something it cannot compute
    (an axis it needs is not coded, a frame of the wrong size...)."""


@dataclass(frozen=True)
class CameraRays:
    """The camera's viewing rays in the model frame.

    Attributes
    ----------
    origin_mm : (3,) float64 array
        The camera's pupil (centre of projection), mm, model frame.
    direction : (H, W, 3) float64 array
        Unit vector from the pupil along the ray of each pixel (towards the scene).
    """

    origin_mm: np.ndarray
    direction: np.ndarray


class ReferenceSurface(ABC):
    """A reference surface prepared from a capture of the reference plane, kept for many
    measurements. Model-specific and opaque to callers: build it with
    :meth:`PreparedGeometry.reference`, pass it back to :meth:`PreparedGeometry.triangulate_rows`.
    """

    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """Camera frame shape ``(H, W)`` it was prepared for."""


class PreparedGeometry(ABC):
    """A model prepared for one camera frame size and one projector coordinate system.

    Holds the per-pixel tables (camera rays, modelled reference codes...) so that each tile
    of rows is triangulated without recomputing them. Instances are read-only and safe to
    share between threads.
    """

    model: GeometryModel
    """The model it was prepared from."""
    shape: tuple[int, int]
    """Camera frame shape ``(H, W)``."""
    projector_size: tuple[float, float] | None
    """Projector size ``(width, height)`` in projector units, or None (see the module's conventions)."""

    @property
    @abstractmethod
    def required_axes(self) -> tuple[str, ...]:
        """Projector axes that must be coded to triangulate: a subset of :data:`AXES`, e.g.
        ``("u",)`` for the crossed-axes rig. Axes not listed are used when given (or ignored)."""

    @property
    @abstractmethod
    def has_model_plane(self) -> bool:
        """True when the model defines a reference plane itself (heights need no reference capture)."""

    @abstractmethod
    def camera_rays(self) -> CameraRays:
        """The camera ray of every pixel of the frame (see :class:`CameraRays`)."""

    @abstractmethod
    def reference(self, u: np.ndarray | None, v: np.ndarray | None, threads: int | None = None) -> ReferenceSurface:
        """Prepare the reference surface from the decoded projector coordinates of a capture of
        the reference plane.

        Parameters
        ----------
        u, v : (H, W) float32 arrays or None
            Decoded projector coordinates of the reference capture (NaN where not decoded);
            None for an axis that is not coded. Every axis of :attr:`required_axes` is required.
        threads : int, optional
            Threads over row tiles.

        Raises
        ------
        GeometryError
            If a required axis is missing or a map's shape differs from :attr:`shape`.
        """

    @abstractmethod
    def triangulate_rows(
        self,
        rows: slice,
        u: np.ndarray | None,
        v: np.ndarray | None,
        *,
        reference: ReferenceSurface | None = None,
        points_out: np.ndarray | None = None,
        height_out: np.ndarray | None = None,
    ) -> None:
        """Triangulate the camera rows ``rows`` (a tile) of decoded projector coordinates.

        Parameters
        ----------
        rows : slice
            Rows of the frame, ``start < stop``, step 1, within ``[0, H)``.
        u, v : (n, W) float32 arrays or None
            The projector coordinates of those rows (``n = rows.stop - rows.start``), NaN
            where not decoded; None for an axis that is not coded.
        reference : ReferenceSurface, optional
            With it, heights are measured relative to the captured reference (for the
            crossed-axes rig: Eqs. 16-17 from the reference codes); without it, the
            triangulation is absolute (from the model alone).
        points_out : (n, W, 3) float32 array, optional
            Receives the 3D points, mm, model frame, NaN where not triangulated.
        height_out : (n, W) float32 array, optional
            Receives the heights above the reference surface (or above the model plane when
            there is no reference), mm, NaN where not triangulated.

        Raises
        ------
        GeometryError
            If a required axis is None, or ``height_out`` is asked without a reference from
            a model that has no model plane.
        """

    @abstractmethod
    def points_from_heights(self, z_mm: np.ndarray, reference: ReferenceSurface | None = None) -> np.ndarray:
        """3D points of a height map: each pixel's camera ray at height ``z`` above the
        reference surface (or the model plane when ``reference`` is None).

        Parameters
        ----------
        z_mm : (H, W) float array
            Heights, mm, NaN where not measured.

        Returns
        -------
        (H, W, 3) float64 array
            Points, mm, model frame; NaN where ``z`` is NaN.
        """


class GeometryModel(ABC):
    """A rig's geometric model: serialisable, immutable, hashable.

    Implementations: :class:`metrology.core.geometry.crossed_axes.Rig` (``"crossed_axes"``)
    and the pinhole model (``"pinhole"``). :func:`metrology.core.geometry.model_from_dict`
    builds the right one from a rig file's JSON object.
    """

    model: ClassVar[str]
    """The ``model`` key of the rig file: ``"crossed_axes"`` or ``"pinhole"``."""

    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """Camera frame shape ``(height_px, width_px)`` the model describes."""

    @abstractmethod
    def prepare(
        self, shape: tuple[int, int] | None = None, projector_size: tuple[float, float] | None = None
    ) -> PreparedGeometry:
        """The model prepared for frames of ``shape`` (default :attr:`shape`), with projector
        coordinates in a projector of ``projector_size = (width, height)`` projector units.

        Cached: preparing the same model for the same sizes again returns the same object.

        Raises
        ------
        GeometryError
            If ``shape`` differs from the model's camera size, or the projector size is
            not positive (or does not match the model's own projector size).
        """

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object; :func:`~metrology.core.geometry.model_from_dict` reads it back
        to an equal model."""


def check_axes(prepared: PreparedGeometry, u: object, v: object) -> None:
    """Raise :class:`GeometryError` naming the first of ``prepared.required_axes`` that is None."""
    given = {"u": u is not None, "v": v is not None}
    for axis in prepared.required_axes:
        if not given[axis]:
            raise GeometryError(
                f"the {prepared.model.model} model needs the projector's {axis} axis coded; the capture lacks it"
            )


def check_frame(prepared: PreparedGeometry, name: str, array: np.ndarray | None) -> None:
    """Raise :class:`GeometryError` when ``array`` is given and its shape is not ``prepared.shape``."""
    if array is not None and tuple(array.shape[:2]) != tuple(prepared.shape):
        raise GeometryError(f"{name} has shape {tuple(array.shape)}, the model's frames are {tuple(prepared.shape)}")


def model_name(data: Mapping[str, Any]) -> str:
    """The ``model`` of a rig file's JSON object (``"crossed_axes"`` when absent)."""
    name = data.get("model", "crossed_axes")
    if not isinstance(name, str):
        raise GeometryError(f"rig model must be a string, got {name!r}")
    return name


@dataclass(frozen=True)
class Triangulation:
    """Output of :func:`triangulate_frame`.

    Attributes
    ----------
    points_mm : (H, W, 3) float32 array or None
        3D points, mm, model frame, NaN where not triangulated.
    height_mm : (H, W) float32 array or None
        Heights above the reference surface (or the model plane), mm, NaN where not triangulated.
    """

    points_mm: np.ndarray | None
    height_mm: np.ndarray | None


def triangulate_frame(
    prepared: PreparedGeometry,
    u: np.ndarray | None,
    v: np.ndarray | None,
    *,
    reference: ReferenceSurface | None = None,
    points: bool = True,
    heights: bool = True,
    threads: int | None = None,
) -> Triangulation:
    """Triangulate a whole frame of projector coordinates, tile by tile
    (:meth:`PreparedGeometry.triangulate_rows` over :func:`~metrology.core.tiling.run_tiled`).

    Parameters
    ----------
    u, v : (H, W) float32 arrays or None
        Decoded projector coordinates, NaN where not decoded; None for an axis not coded.
    reference : ReferenceSurface, optional
    points, heights : bool
        Which outputs to compute.
    threads : int, optional

    Returns
    -------
    Triangulation
    """
    from metrology.core.tiling import run_tiled

    check_axes(prepared, u, v)
    check_frame(prepared, "u", u)
    check_frame(prepared, "v", v)
    height, width = prepared.shape
    xyz = np.empty((height, width, 3), np.float32) if points else None
    z = np.empty((height, width), np.float32) if heights else None

    def run(rows: slice) -> None:
        prepared.triangulate_rows(
            rows,
            None if u is None else u[rows],
            None if v is None else v[rows],
            reference=reference,
            points_out=None if xyz is None else xyz[rows],
            height_out=None if z is None else z[rows],
        )

    run_tiled(run, height, width, threads)
    return Triangulation(points_mm=xyz, height_mm=z)
