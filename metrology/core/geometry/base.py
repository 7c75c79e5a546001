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
  above a :class:`ReferenceSurface` prepared from a capture of the reference plane. Without
  a reference, a model's ``z`` is what :attr:`GeometryModel.unreferenced_result` says: heights
  above its model plane, or depths (camera Z, mm) for a model without one.
- **Sigma** (``sigma_in`` / ``sigma_out`` of :meth:`PreparedGeometry.triangulate_rows`): the
  standard uncertainty of the triangulated axis's coordinate (projector units, or light codes
  where the model reads them) propagated to the point to first order, mm; what direction it
  is taken along is the model's (:attr:`GeometryModel.sigma_direction`).

What differs between models is said by the model itself, never by a caller testing its name:
:attr:`GeometryModel.requires_reference`, :attr:`~GeometryModel.unreferenced_result`,
:attr:`~GeometryModel.calibration_parameters` (what the paper's master-block calibration may
adjust), :attr:`~GeometryModel.scalar_parameters` (the values a form edits one by one),
:attr:`~GeometryModel.light_codes` (the paper's light codes, which the fused gcps-v1 kernel
triangulates directly), and, once prepared, :meth:`PreparedGeometry.used_axes`,
:meth:`~PreparedGeometry.code_scale` (the unit of the code-space filters) and
:meth:`~PreparedGeometry.plane_coordinates` (where characterization test points sit).
"""

from __future__ import annotations

import json
import math
from abc import ABC, abstractmethod
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

AXES: tuple[str, ...] = ("u", "v")
"""Projector axes a codec may code: ``u`` across projector columns, ``v`` across rows."""
TRIANGULATE_CHOICES: tuple[str, ...] = ("auto", *AXES)
""":attr:`GeometryOptions.triangulate` values: ``auto`` lets the model choose its axis."""
METHOD_CHOICES: tuple[str, ...] = ("plane", "midpoint")
MATCH_CHOICES: tuple[str, ...] = ("epipolar", "2d")
""":attr:`GeometryOptions.method` values."""


class GeometryError(ValueError):
    """A geometric model is malformed, or is asked for something it cannot compute
    (an axis it needs is not coded, a frame of the wrong size...)."""


@dataclass(frozen=True)
class GeometryOptions:
    """How a prepared model triangulates (each model accepts what it can do, and refuses the rest
    naming the option).

    Attributes
    ----------
    triangulate : {'auto', 'u', 'v'}
        The projector axis whose light planes are intersected with the camera rays; ``auto``
        (default) lets the model choose (a pinhole model: the axis its baseline crosses most
        steeply; the crossed-axes model has only ``u``).
    method : {'plane', 'midpoint'}
        ``plane``: camera ray meets the light plane of the decoded coordinate (default);
        ``midpoint``: the midpoint of the camera ray and the projector ray (both axes, or one
        axis and its epipolar line).
    match : {'epipolar', '2d'}
        How a model with two cameras finds corresponding pixels: along epipolar lines (default), or
        in 2-D without rectification when both projector axes are coded (``2d``). Models with one
        camera accept ``epipolar`` only.
    """

    triangulate: str = "auto"
    method: str = "plane"
    match: str = "epipolar"

    def __post_init__(self) -> None:
        if self.triangulate not in TRIANGULATE_CHOICES:
            raise ValueError(f"triangulate must be one of {', '.join(TRIANGULATE_CHOICES)}, got {self.triangulate!r}")
        if self.method not in METHOD_CHOICES:
            raise ValueError(f"method must be one of {', '.join(METHOD_CHOICES)}, got {self.method!r}")
        if self.match not in MATCH_CHOICES:
            raise ValueError(f"match must be one of {', '.join(MATCH_CHOICES)}, got {self.match!r}")

    def to_dict(self) -> dict[str, Any]:
        """``{"triangulate", "method"}``, and ``"match"`` when it is not the default ``epipolar`` (so the
        JSON of every single-camera measurement stays as it was)."""
        data: dict[str, Any] = {"triangulate": self.triangulate, "method": self.method}
        if self.match != "epipolar":
            data["match"] = self.match
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GeometryOptions:
        unknown = sorted(set(data) - {"triangulate", "method", "match"})
        if unknown:
            raise ValueError(f"unknown geometry option(s): {', '.join(unknown)}; accepted: match, method, triangulate")
        return cls(**data)


@dataclass(frozen=True)
class ParameterField:
    """One scalar value of a rig file, as a form shows it (:attr:`GeometryModel.scalar_parameters`).

    Attributes
    ----------
    name : str
        The rig file's key (``L_mm``).
    label : str
        What it is, in a few words (``Height of the pupils above the reference plane``).
    unit : str
        ``mm``, ``rad``, ``px`` or ``""`` (a count).
    integer : bool
        An integer value (``nlp``, pixel sizes).
    """

    name: str
    label: str
    unit: str
    integer: bool = False


@dataclass(frozen=True)
class ImageAxes:
    """The coordinates a map of the result is drawn against: one per image column and row.

    Attributes
    ----------
    x, y : (W,), (H,) float64 arrays
        The value at each column and row (the paper's X and Y on R, mm; or pixel indices).
    x_label, y_label : str
        Axis titles with their units (``"X (mm)"``, ``"camera column (px)"``).
    unit : str
        ``"mm"`` or ``"px"`` (what a hover shows).
    """

    x: np.ndarray
    y: np.ndarray
    x_label: str
    y_label: str
    unit: str


@dataclass(frozen=True)
class PlaneCoordinates:
    """Where each pixel's ray meets the reference plane, in the model frame's plane coordinates
    (the positions of characterization test points, :mod:`metrology.core.characterize`).

    Attributes
    ----------
    x_mm, y_mm : (H, W) float64 arrays
        The plane's coordinates of the point each pixel sees, mm: the paper's ``(x_A, Y_A)`` on R
        for the crossed-axes rig, the camera-frame ``X, Y`` of the reference plane's point for a
        pinhole rig.
    centre_x_mm : float
        X of the field centre (test points are ranked by ``|x - centre_x_mm|``).
    """

    __test__ = False  # not a pytest class
    x_mm: np.ndarray
    y_mm: np.ndarray
    centre_x_mm: float

    def __post_init__(self) -> None:
        if np.shape(self.x_mm) != np.shape(self.y_mm) or np.ndim(self.x_mm) != 2:
            shapes = f"{np.shape(self.x_mm)}, {np.shape(self.y_mm)}"
            raise ValueError(f"x_mm and y_mm must be equal (H, W) arrays, got {shapes}")

    @property
    def shape(self) -> tuple[int, int]:
        h, w = np.shape(self.x_mm)
        return (int(h), int(w))

    @property
    def height_px(self) -> int:
        return self.shape[0]

    @property
    def width_px(self) -> int:
        return self.shape[1]


@dataclass(frozen=True)
class CameraRays:
    """The camera's viewing rays in the model frame.

    Attributes
    ----------
    origin_mm : (3,) float64 array
        The camera's pupil (centre of projection), mm, model frame.
    direction : (H, W, 3) float64 array
        Unit vector from the pupil along the ray of each pixel (towards the scene); ``(H s, W s, 3)``
        for ``s x s`` sub-pixels (:meth:`PreparedGeometry.camera_rays`).
    """

    origin_mm: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class CombinedMaps:
    """What :meth:`PreparedGeometry.combine` makes of every camera's decoded maps: the inputs of
    :meth:`PreparedGeometry.triangulate_rows` on camera 0's pixel grid.

    Attributes
    ----------
    u, v : (H, W) float32 arrays or None
        Read by ``triangulate_rows`` as its ``u``, ``v``: a single camera's decoded projector
        coordinates as they are; for a model of several cameras what its ``combine`` documents (a
        stereo rig: the disparity of the matched cameras as ``u``). NaN where not measured.
    sigma : (H, W) float32 array or None
        Its ``sigma_in``: the standard deviation of what ``u`` (the triangulated axis) holds.
    pairs : (H, W) uint8 array or None
        For a model of several devices: which of its pairs measured each pixel (bits; a stereo rig's
        are in :mod:`~metrology.core.geometry.stereo_fusion`), 0 where none did; None for one camera.
    """

    u: np.ndarray | None
    v: np.ndarray | None
    sigma: np.ndarray | None = None
    pairs: np.ndarray | None = None


@dataclass(frozen=True)
class HeightTerms:
    """The closed form of heights from light codes over a frame (Eqs. 14, 16, 17), for a kernel
    that decodes and triangulates in one pass (:mod:`metrology.core.decode_kernels`):
    ``D = slope (l - r) / (1 + q l)``, ``z = L D / (d + D)`` for a light code ``l``, float32 in that
    order of operations (:meth:`PreparedGeometry.height_terms`).

    Attributes
    ----------
    ref_codes : (H, W) float32 array
        The reference codes ``r``, code units, NaN where the reference is not measured.
    slope_mm : (H, W) float32 array
        ``slope``, mm per code.
    q : numpy.float32
        ``q``, per code.
    d_mm, L_mm : numpy.float32
        ``d`` and ``L``, mm.
    """

    ref_codes: np.ndarray
    slope_mm: np.ndarray
    q: np.float32
    d_mm: np.float32
    L_mm: np.float32


class ReferenceSurface(ABC):
    """A reference surface prepared from a capture of the reference plane, kept for many
    measurements. Model-specific and opaque to callers: build it with
    :meth:`PreparedGeometry.reference`, pass it back to :meth:`PreparedGeometry.triangulate_rows`.
    """

    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """Camera frame shape ``(H, W)`` it was prepared for."""

    @property
    def per_pixel(self) -> bool:
        """True when the surface is a map of the capture's own pixels (an object pixel measured where
        the reference's was unreliable is unreliable too); False for a fitted surface (a plane)."""
        return True

    def describe(self) -> dict[str, Any] | None:
        """What a result reports of the surface (JSON-ready), or None when it has nothing to say
        (a captured map of codes has no summary; a fitted plane has its centroid and normal)."""
        return None


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
    axis: str
    """The projector axis triangulated (``u`` or ``v``): the one whose coordinate's sigma
    ``sigma_in`` of :meth:`triangulate_rows` is."""
    method: str
    """How it triangulates (:attr:`GeometryOptions.method`)."""

    @property
    @abstractmethod
    def required_axes(self) -> tuple[str, ...]:
        """Projector axes that must be coded to triangulate: a subset of :data:`AXES`, e.g.
        ``("u",)`` for the crossed-axes rig. Axes not listed are used when given (or ignored)."""

    def used_axes(self, decoded: Collection[str]) -> tuple[str, ...]:
        """The axes of ``decoded`` (the coded axes of a capture) that :meth:`triangulate_rows`
        reads: the code-space filters run on these, and a pixel missing any of them is not
        triangulated. Default: :attr:`required_axes`."""
        return tuple(axis for axis in AXES if axis in self.required_axes)

    def code_scale(self, axis: str) -> float | None:
        """Code units per projector unit of ``axis``, for a model that has codes of its own: the
        code-space filters read ``c = (x + 0.5) * scale``. The crossed-axes rig's are the paper's
        light codes (``nlp / width``); None (the default) leaves the unit to the caller (a quarter
        of the codec's finest phase period: gcps-v1's ratio of codes to periods)."""
        return None

    @property
    def noise_axes(self) -> tuple[str, ...]:
        """The axes whose decoder sigma :meth:`combine` reads, :attr:`axis` first: ``(axis,)``, or
        both axes for a model that matches on both (the 2-D stereo match), whose second one's sigma
        it takes as ``other_sigma``."""
        return (self.axis,)

    def combine(
        self,
        coordinates: Sequence[Mapping[str, np.ndarray | None]],
        sigma: Sequence[np.ndarray | None] | None = None,
        threads: int | None = None,
        other_sigma: Sequence[np.ndarray | None] | None = None,
    ) -> CombinedMaps:
        """The inputs of :meth:`triangulate_rows` from every camera's decoded maps, camera 0 first
        (:attr:`GeometryModel.cameras` of them), once per frame.

        Parameters
        ----------
        coordinates : sequence of mappings ``{axis: (H_c, W_c) float32 array or None}``
            Each camera's decoded, filtered projector coordinates (projector units), NaN where not
            decoded; None (or absent) for an axis not read.
        sigma : sequence of (H_c, W_c) float32 arrays or None, optional
            Each camera's standard deviation of the :attr:`axis` coordinate.
        other_sigma : sequence of (H_c, W_c) float32 arrays or None, optional
            Each camera's standard deviation of the second of :attr:`noise_axes`, for a model that
            reads two; None: taken equal to ``sigma``.

        The default (one camera) hands camera 0's maps through unchanged.
        """
        if len(coordinates) != 1:
            raise GeometryError(f"the {self.model.model} model reads one camera's maps, got {len(coordinates)}")
        first = coordinates[0]
        return CombinedMaps(u=first.get("u"), v=first.get("v"), sigma=None if sigma is None else sigma[0])

    @property
    def points_on_rays(self) -> bool:
        """True when every triangulated point lies on its camera ray, so that the points are a
        function of ``z`` (:meth:`points_from_heights`); False for a method that moves them off
        the ray (a midpoint), whose points :meth:`triangulate_rows` must write."""
        return True

    @abstractmethod
    def plane_coordinates(self, reference: ReferenceSurface | None = None) -> PlaneCoordinates:
        """Where each pixel's ray meets the reference plane (:class:`PlaneCoordinates`): the
        captured reference's, or the model plane's when ``reference`` is None.

        Raises
        ------
        GeometryError
            When the model has no model plane and no reference is given.
        """

    @property
    @abstractmethod
    def has_model_plane(self) -> bool:
        """True when the model defines a reference plane itself (heights need no reference capture)."""

    @abstractmethod
    def camera_rays(self, supersample: int = 1) -> CameraRays:
        """The camera ray of every pixel of the frame (see :class:`CameraRays`); with
        ``supersample = s > 1`` the rays of an ``s x s`` grid of sub-pixel centres in each pixel,
        ``(H s, W s, 3)`` (the virtual rig's area sampling)."""

    @property
    @abstractmethod
    def projector_centre_mm(self) -> np.ndarray:
        """The projector's centre of projection, ``(3,)`` float64 mm in the model frame (where a
        surface point's light comes from: shadows)."""

    @abstractmethod
    def projector_coordinates(self, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The projector coordinates ``(u, v)`` that light ``points_mm`` (``(..., 3)`` mm, model
        frame): float64 arrays of the points' shape, projector units (light codes for ``u`` when
        prepared without a projector size, and NaN for ``v`` then); NaN for a point behind the
        projector or NaN itself. Points outside the projector's image keep their coordinates
        (the caller tests ``[-0.5, size - 0.5]``)."""

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
        sigma_in: np.ndarray | None = None,
        sigma_out: np.ndarray | None = None,
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
        sigma_in : (n, W) float32 array, optional
            Standard deviation of the :attr:`axis` coordinate, in the unit ``u`` is read in.
        sigma_out : (n, W) float32 array, optional
            With ``sigma_in``: receives each point's standard uncertainty, mm (first-order
            propagation through the triangulation; :attr:`GeometryModel.sigma_direction`).

        Raises
        ------
        GeometryError
            If a required axis is None, or ``height_out`` is asked without a reference from
            a model that has no model plane.
        """

    def height_terms(self, reference: ReferenceSurface | None) -> HeightTerms | None:
        """The closed form of :meth:`triangulate_rows`' heights for ``u`` read as light codes over
        the frame against ``reference`` (:class:`HeightTerms`), giving the same float32 heights; None
        (the default) when the model has none, or reads ``u`` otherwise: the caller then calls
        :meth:`triangulate_rows`."""
        return None

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

    Implementations are registered in :data:`metrology.core.geometry.MODELS`;
    :func:`metrology.core.geometry.model_from_dict` builds the right one from a rig file's JSON
    object.
    """

    model: ClassVar[str]
    """The ``model`` key of the rig file (the registry's key, :data:`metrology.core.geometry.MODELS`)."""
    label: ClassVar[str]
    """What the model is, in a few words, for lists and forms."""
    short_label: ClassVar[str]
    """The model in a word or two, for sentences: "a {short_label} rig" ("a pinhole rig")."""
    requires_reference: ClassVar[bool]
    """True when a measurement needs a capture of the reference plane (the crossed-axes rig's
    Eq. 16 measures against it); False when the model alone triangulates (depths)."""
    unreferenced_result: ClassVar[str]
    """What ``z`` is without a reference capture: ``"height"`` (above the model plane) or
    ``"depth"`` (camera Z). With one it is always the height above the reference plane."""
    frame: ClassVar[str]
    """The name of the model frame points are given in: ``"camera"`` (a camera frame, OpenCV's
    axes), ``"paper"`` (the paper's X_H, Y_H, z over its reference plane R)."""
    sigma_direction: ClassVar[str]
    """Along what a point's sigma is taken (``"height"``, ``"camera ray"``)."""
    calibration_parameters: ClassVar[tuple[str, ...]] = ()
    """Rig-file keys that the paper's master-block calibration adjusts (L, alpha, d); empty when
    the model is calibrated otherwise (``gcps calibrate-procam``)."""
    scalar_parameters: ClassVar[tuple[ParameterField, ...]] = ()
    """The model's rig-file values that are single numbers, in the order a form lists them;
    empty for a model whose file holds matrices (edited by importing a calibration file)."""
    cameras: ClassVar[int] = 1
    """How many cameras a capture of the rig holds (one stack each, camera 0 first); results lie on
    camera 0's pixel grid. A model of more than one camera prepares a :class:`PreparedGeometry`
    whose :meth:`~PreparedGeometry.combine` turns every camera's decoded maps into camera 0's."""

    @property
    def camera_shapes(self) -> tuple[tuple[int, int], ...]:
        """Every camera's frame ``(height_px, width_px)``, camera 0 first (default: :attr:`shape`)."""
        return (self.shape,)

    def image_axes(self) -> ImageAxes:
        """The axes of a map of the result (default: camera columns and rows, row 0 at the top)."""
        height, width = self.shape
        return ImageAxes(
            x=np.arange(width, dtype=np.float64),
            y=np.arange(height, dtype=np.float64),
            x_label="camera column (px)",
            y_label="camera row (px), running down",
            unit="px",
        )

    @abstractmethod
    def scene_distance_mm(self, field_width_mm: float) -> float:
        """The camera's height above the plane on which the virtual rig places its scenes, mm: the
        model's own plane, or, for a model without one, the plane facing the camera at the
        distance where ``field_width_mm`` fills the image's width (cheap: no table is built)."""

    @property
    def scene_centre_x_mm(self) -> float | None:
        """X of the field's centre on the model's own plane, where the virtual rig centres its
        scenes; None for a model without a plane (scenes face its camera, centred on its axis)."""
        return None

    @classmethod
    def example_parameters(cls) -> dict[str, Any]:
        """Values a form may offer as a start for a new rig of this model (none by default)."""
        return {}

    @property
    def light_codes(self) -> int | None:
        """The paper's light codes across the field (``nlp``) when the model triangulates them
        directly (prepared without a projector size it reads ``u`` as light codes), else None."""
        return None

    @property
    @abstractmethod
    def camera_centre_mm(self) -> np.ndarray:
        """The camera's centre of projection, ``(3,)`` float64 mm in the model frame."""

    def footprint_mm(self, points_mm: np.ndarray | None = None) -> float:
        """The size of one camera pixel on the scene, mm (meshes do not join neighbours farther
        apart in ``z`` than a few of them). Default: the median distance between horizontally
        neighbouring finite ``points_mm`` (``(H, W, 3)``), which must be given."""
        if points_mm is None:
            raise GeometryError(f"the {self.model} model's pixel footprint needs the measured points")
        step = np.linalg.norm(np.diff(np.asarray(points_mm, dtype=np.float64), axis=1), axis=-1)
        finite = step[np.isfinite(step)]
        return float(np.median(finite)) if finite.size else math.inf

    @abstractmethod
    def check_codec(
        self, projector_size: tuple[float, float], coded_axes: Collection[str], options: GeometryOptions | None = None
    ) -> None:
        """Raise :class:`GeometryError` saying why captures of a codec of this projector size and these
        coded axes cannot be measured with the model (and ``options``); cheap: no table is built.

        Implementations check what :meth:`prepare` and :attr:`PreparedGeometry.required_axes`
        would refuse: a projector of another size than the model's own, the triangulated axis not
        coded.
        """

    @abstractmethod
    def value_rows(self) -> list[tuple[str, str]]:
        """The model's values as ``(name, value with its unit)`` rows, for a page (numbers with six
        significant digits)."""

    def summary(self) -> str:
        """The values in one line, for lists and histories: the model's label and its rows."""
        return f"{self.label}: " + ", ".join(f"{name} {value}" for name, value in self.value_rows())

    def parameters(self) -> dict[str, Any]:
        """The rig file's values without the ``model`` key: what an application stores beside the
        model's name (``model_from_dict({"model": name, **parameters})`` reads it back)."""
        data = self.to_dict()
        data.pop("model", None)
        return data

    @classmethod
    @abstractmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GeometryModel:
        """The model of a rig file's JSON object, every value validated (:class:`GeometryError`
        naming the key and the value)."""

    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """Camera frame shape ``(height_px, width_px)`` the model describes."""

    @property
    def projector_size(self) -> tuple[float, float] | None:
        """The projector's own size ``(width, height)`` in projector units where the model fixes it
        (the :attr:`PreparedGeometry.projector_size` that :meth:`prepare` would give without one),
        else None. Cheap: no table is built. Default None (a model whose projector size comes with
        the codec)."""
        return None

    @abstractmethod
    def prepare(
        self,
        shape: tuple[int, int] | None = None,
        projector_size: tuple[float, float] | None = None,
        options: GeometryOptions | None = None,
    ) -> PreparedGeometry:
        """The model prepared for frames of ``shape`` (default :attr:`shape`), with projector
        coordinates in a projector of ``projector_size = (width, height)`` projector units,
        triangulating as ``options`` say (default :class:`GeometryOptions`).

        Cached: preparing the same model for the same sizes and options again returns the same object.

        Raises
        ------
        GeometryError
            If ``shape`` differs from the model's camera size, the projector size is not
            positive (or does not match the model's own projector size), or an option asks for
            what the model cannot do.
        """

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object; :func:`~metrology.core.geometry.model_from_dict` reads it back
        to an equal model."""

    def to_json(self) -> str:
        """The rig file's text (indented JSON, full float precision, trailing newline)."""
        return json.dumps(self.to_dict(), indent=2) + "\n"


def subpixel_offsets(supersample: int) -> np.ndarray:
    """Offsets of the ``s`` sub-pixel centres of a pixel along one axis, px: ``(i + 0.5) / s - 0.5``."""
    if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"supersample must be a positive integer, got {supersample!r}")
    return (np.arange(supersample) + 0.5) / supersample - 0.5


def subpixel_grid(count: int, supersample: int) -> np.ndarray:
    """Pixel coordinates of the sub-pixel centres of ``count`` pixels (pixel ``j`` centred at
    ``j``), ``(count * s,)`` float64, pixel-major."""
    return (np.arange(count, dtype=np.float64)[:, None] + subpixel_offsets(supersample)[None, :]).ravel()


def short_number(value: Any, digits: int = 6) -> str:
    """A number with at most ``digits`` significant digits (``1000.0000000002`` -> ``1000``), or nested
    lists of numbers (a matrix) written so."""
    if isinstance(value, list | tuple):
        return "[" + ", ".join(short_number(item, digits) for item in value) + "]"
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return f"{number:.{digits}g}"


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
    sigma_mm : (H, W) float32 array or None
        The points' standard uncertainty, mm (when a coordinate sigma was given).
    """

    points_mm: np.ndarray | None
    height_mm: np.ndarray | None
    sigma_mm: np.ndarray | None = None


def triangulate_frame(
    prepared: PreparedGeometry,
    u: np.ndarray | None,
    v: np.ndarray | None,
    *,
    reference: ReferenceSurface | None = None,
    points: bool = True,
    heights: bool = True,
    sigma: np.ndarray | None = None,
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
    sigma : (H, W) float32 array, optional
        Standard deviation of the :attr:`~PreparedGeometry.axis` coordinate: the points'
        uncertainty is computed too (``sigma_mm``).
    threads : int, optional

    Returns
    -------
    Triangulation
    """
    from metrology.core.tiling import run_tiled

    check_axes(prepared, u, v)
    check_frame(prepared, "u", u)
    check_frame(prepared, "v", v)
    check_frame(prepared, "sigma", sigma)
    height, width = prepared.shape
    xyz = np.empty((height, width, 3), np.float32) if points else None
    z = np.empty((height, width), np.float32) if heights else None
    sigma_mm = np.empty((height, width), np.float32) if sigma is not None else None

    def run(rows: slice) -> None:
        prepared.triangulate_rows(
            rows,
            None if u is None else u[rows],
            None if v is None else v[rows],
            reference=reference,
            points_out=None if xyz is None else xyz[rows],
            height_out=None if z is None else z[rows],
            sigma_in=None if sigma is None else sigma[rows],
            sigma_out=None if sigma_mm is None else sigma_mm[rows],
        )

    run_tiled(run, height, width, threads)
    return Triangulation(points_mm=xyz, height_mm=z, sigma_mm=sigma_mm)
