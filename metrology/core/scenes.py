"""Scenes for the virtual rig: height fields over the reference plane R (gcps-v1, docs/conventions.md).

A :class:`Scene` is a small frozen dataclass describing a surface ``Z = h(X, Y)`` in rig
coordinates (millimetres; X from Q, the foot of the projector pupil; Y = 0 through both
pupils; Z = 0 is R). Every scene includes the reference plane around its object, so
``h = 0`` away from the object. Its fields are the scene's analytic parameters (sphere
centre and radius, block size, ...), which acceptance tests compare fits against.

The virtual rig (:mod:`metrology.core.simulate`) only needs, from a scene:

- ``height_mm(X, Y)``: vectorised heights, mm;
- ``albedo(X, Y)``: reflectance in [0, 1];
- ``z_min_mm`` / ``z_max_mm``: bounds of the height field;
- ``footprint_mm``: a box ``(x0, x1, y0, y1)`` outside which ``h == 0`` (``None`` when the
  height field is not zero anywhere, e.g. a plane at Z != 0);
- ``max_slope``: an upper bound of ``|grad h|`` (``inf`` for surfaces with vertical walls), used
  to prove that a camera ray crosses the surface once and that no projector shadow can occur.

Positions default to the centre of the paper's field (X = d = 352 mm, Y = 0); give
``rig=`` to :func:`make_scene` to centre a scene on another rig's field.

Examples
--------
>>> scene = make_scene("block", top_mm=40.0)
>>> float(scene.height_mm(352.0, 0.0)), float(scene.height_mm(10.0, 0.0))
(40.0, 0.0)
>>> make_scene("sphere").center_z_mm  # resting on R
50.0
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.base import GeometryModel
from metrology.core.geometry.crossed_axes import PAPER_RIG

FloatArray = npt.NDArray[np.float64]

FIELD_CENTER_X_MM = PAPER_RIG.d_mm
"""Default X of scene centres: the centre of the paper's field (X = d), mm."""
FIELD_WIDTH_MM = PAPER_RIG.fw_mm
"""Width of the field the scenes are laid out in (the paper's FW), mm."""

_BUMP_SLOPE = 6.0 * math.sqrt(0.2) * 0.8**2
"""Maximum of ``|d/dr (1 - r^2)^3|`` (at r^2 = 0.2): about 1.717."""


# --------------------------------------------------------------------------- validation
def _real(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"scene parameter {name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"scene parameter {name} must be finite, got {value!r}")
    return value


def _positive(name: str, value: Any) -> float:
    value = _real(name, value)
    if value <= 0:
        raise ValueError(f"scene parameter {name} must be positive, got {value!r}")
    return value


def _non_negative(name: str, value: Any) -> float:
    value = _real(name, value)
    if value < 0:
        raise ValueError(f"scene parameter {name} must be >= 0, got {value!r}")
    return value


def _set(obj: Any, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


def _resolved(name: str, value: float | None) -> float:
    """A parameter that may be given as None (a default derived from the others), once ``__post_init__`` set it."""
    assert value is not None, f"scene parameter {name} is set by __post_init__"
    return value


def _xy(X: npt.ArrayLike, Y: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    return np.asarray(X, dtype=np.float64), np.asarray(Y, dtype=np.float64)


def _bump(dx: FloatArray, dy: FloatArray, ax: float, ay: float) -> FloatArray:
    """Compact C2 bump ``(1 - r^2)^3`` for ``r^2 = (dx/ax)^2 + (dy/ay)^2 < 1``, else 0."""
    t = 1.0 - (dx / ax) ** 2 - (dy / ay) ** 2
    np.maximum(t, 0.0, out=t)
    return t * t * t


# --------------------------------------------------------------------------- base
@dataclass(frozen=True, kw_only=True)
class Scene:
    """Base of all scenes: a height field over R with a uniform reflectance.

    Parameters
    ----------
    reflectance : float
        Diffuse albedo of the whole scene (object and plane), in [0, 1]. Default 1.

    Notes
    -----
    Subclasses set :attr:`name`, override :meth:`height_mm` and the bounds. Surfaces are
    ideal diffusers whose radiance does not depend on orientation.
    """

    name: ClassVar[str] = ""
    smooth: ClassVar[bool] = False
    """True when the height field is continuous with bounded slope (see ``max_slope``)."""
    height_field: ClassVar[bool] = True
    """True for a height field over R; False for a :class:`MeshScene` (ray cast as a triangle mesh)."""

    reflectance: float = 1.0

    def __post_init__(self) -> None:
        value = _real("reflectance", self.reflectance)
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"scene parameter reflectance must lie in [0, 1], got {value!r}")
        _set(self, "reflectance", value)

    # ------------------------------------------------------------ the height field
    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        """Height of the surface above R at (X, Y).

        Parameters
        ----------
        X, Y : array_like of float, broadcastable
            Rig coordinates on R, mm.

        Returns
        -------
        z_mm : float64 ndarray, broadcast shape
            Height above R, mm (0 on the reference plane).
        """
        X, Y = _xy(X, Y)
        return np.zeros(np.broadcast_shapes(X.shape, Y.shape))

    def albedo(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        """Reflectance at (X, Y): float64 ndarray of the broadcast shape, in [0, 1]."""
        X, Y = _xy(X, Y)
        return np.full(np.broadcast_shapes(X.shape, Y.shape), self.reflectance)

    @property
    def z_max_mm(self) -> float:
        """Upper bound of the height field, mm (the ray march starts here)."""
        return 0.0

    @property
    def z_min_mm(self) -> float:
        """Lower bound of the height field, mm."""
        return 0.0

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        """Box ``(x0, x1, y0, y1)`` in mm outside which the height is 0; None if unbounded."""
        return None

    @property
    def footprints_mm(self) -> tuple[tuple[float, float, float, float], ...]:
        """Boxes ``(x0, x1, y0, y1)`` (mm) whose union holds every point with non-zero height.

        Defaults to ``(footprint_mm,)``; scenes of several objects list one box each, so the
        ray caster skips the plane between them. Empty when ``footprint_mm`` is None.
        """
        box = self.footprint_mm
        return () if box is None else (box,)

    @property
    def max_slope(self) -> float:
        """Upper bound of ``|grad h|`` (dimensionless); ``inf`` for surfaces with walls."""
        return 0.0

    def params(self) -> dict[str, Any]:
        """The scene's name and analytic parameters, as a JSON-able dict."""
        data: dict[str, Any] = {"scene": self.name}
        for f in fields(self):
            data[f.name] = getattr(self, f.name)
        return data


class _SmoothScene(Scene):
    """Mixin for smooth scenes: ``max_slope`` estimated on a fine grid over the footprint."""

    smooth: ClassVar[bool] = True
    _SLOPE_GRID_MM: ClassVar[float] = 0.5
    _SLOPE_MARGIN: ClassVar[float] = 1.1

    @cached_property
    def _grid_bounds(self) -> tuple[float, float]:
        box = self.footprint_mm
        assert box is not None
        x0, x1, y0, y1 = box
        h = self._SLOPE_GRID_MM
        xs = np.arange(x0 - h, x1 + 2 * h, h)
        ys = np.arange(y0 - h, y1 + 2 * h, h)
        z = self.height_mm(xs[None, :], ys[:, None])
        gy, gx = np.gradient(z, h)
        slope = float(np.max(np.hypot(gx, gy))) * self._SLOPE_MARGIN
        return float(np.max(z)) + slope * h, slope

    @property
    def max_slope(self) -> float:
        """Estimated bound of ``|grad h|``: the maximum on a 0.5 mm grid, times 1.1."""
        return self._grid_bounds[1]

    @property
    def z_max_mm(self) -> float:
        """Maximum of the height on a 0.5 mm grid plus ``max_slope`` times the grid step."""
        return self._grid_bounds[0]


# --------------------------------------------------------------------------- planes
@dataclass(frozen=True, kw_only=True)
class ReferenceScene(Scene):
    """The reference plane R alone (Z = 0 everywhere)."""

    name: ClassVar[str] = "reference"

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        return (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class PlaneScene(Scene):
    """A plane parallel to R at height ``z_mm`` filling the whole field.

    Parameters
    ----------
    z_mm : float
        Height of the plane above R, mm (may be negative, but below L). Default 20.
    """

    name: ClassVar[str] = "plane"
    z_mm: float = 20.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _set(self, "z_mm", _real("z_mm", self.z_mm))

    def _z(self) -> float:
        return self.z_mm

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        return np.full(np.broadcast_shapes(X.shape, Y.shape), self._z())

    @property
    def z_max_mm(self) -> float:
        return self._z()

    @property
    def z_min_mm(self) -> float:
        return self._z()

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        return None if self._z() != 0.0 else (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class StageScene(PlaneScene):
    """The characterization plane on a translation stage at height ``z_in_mm`` (paper section 5).

    Parameters
    ----------
    z_in_mm : float
        Stage position Z_in, mm. Default 0.
    """

    name: ClassVar[str] = "stage"
    z_mm: float = field(default=0.0, init=False, repr=False)
    z_in_mm: float = 0.0

    def __post_init__(self) -> None:
        z_in = _real("z_in_mm", self.z_in_mm)
        _set(self, "z_in_mm", z_in)
        _set(self, "z_mm", z_in)
        super().__post_init__()

    def params(self) -> dict[str, Any]:
        data = super().params()
        data.pop("z_mm", None)
        return data


# --------------------------------------------------------------------------- master block
@dataclass(frozen=True, kw_only=True)
class BlockScene(Scene):
    """A parallelepiped master block standing on R (the calibration master of section 4).

    Parameters
    ----------
    center_x_mm, center_y_mm : float
        Centre of the block's footprint, mm. Default: field centre (352, 0).
    size_x_mm, size_y_mm : float
        Footprint along X and Y, mm, > 0. Default 200 x 150.
    top_mm : float
        Height of the flat top face above R, mm, > 0. Default 40.

    Notes
    -----
    The projector is at X = 0, so the block's shadow falls on R beside its +X face.
    """

    name: ClassVar[str] = "block"
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    size_x_mm: float = 200.0
    size_y_mm: float = 150.0
    top_mm: float = 40.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("center_x_mm", "center_y_mm"):
            _set(self, name, _real(name, getattr(self, name)))
        for name in ("size_x_mm", "size_y_mm", "top_mm"):
            _set(self, name, _positive(name, getattr(self, name)))

    @property
    def x_range_mm(self) -> tuple[float, float]:
        """X of the block's -X and +X faces, mm."""
        return (self.center_x_mm - self.size_x_mm / 2, self.center_x_mm + self.size_x_mm / 2)

    @property
    def y_range_mm(self) -> tuple[float, float]:
        """Y of the block's -Y and +Y faces, mm."""
        return (self.center_y_mm - self.size_y_mm / 2, self.center_y_mm + self.size_y_mm / 2)

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        (x0, x1), (y0, y1) = self.x_range_mm, self.y_range_mm
        inside = (x0 <= X) & (x1 >= X) & (y0 <= Y) & (y1 >= Y)
        return np.where(inside, self.top_mm, 0.0)

    @property
    def z_max_mm(self) -> float:
        return self.top_mm

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        return (*self.x_range_mm, *self.y_range_mm)

    @property
    def max_slope(self) -> float:
        return math.inf


# --------------------------------------------------------------------------- spheres
def _cap_height(X: FloatArray, Y: FloatArray, cx: float, cy: float, cz: float, r: float) -> FloatArray:
    rho2 = (X - cx) ** 2 + (Y - cy) ** 2
    inside = rho2 < r * r
    cap = cz + np.sqrt(np.where(inside, r * r - rho2, 0.0))
    return np.where(inside, np.maximum(cap, 0.0), 0.0)


@dataclass(frozen=True, kw_only=True)
class SphereScene(Scene):
    """A sphere seen from above: its upper hemisphere, standing on R.

    Parameters
    ----------
    radius_mm : float
        Sphere radius, mm, > 0. Default 50.
    center_x_mm, center_y_mm : float
        Centre in the XY plane, mm. Default: field centre (352, 0).
    center_z_mm : float or None
        Height of the centre, mm. ``None`` (default) rests the sphere on R
        (``center_z_mm = radius_mm``).

    Notes
    -----
    The height field is ``cz + sqrt(r^2 - rho^2)`` for ``rho < r`` (clipped at 0 when the
    centre is below ``r``); below the equator it is a vertical cylinder, which hides the
    lower hemisphere exactly as the sphere itself does for all but grazing camera rays.
    Fit a sphere only to points well above the equator.
    """

    name: ClassVar[str] = "sphere"
    radius_mm: float = 50.0
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    center_z_mm: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        r = _positive("radius_mm", self.radius_mm)
        _set(self, "radius_mm", r)
        for name in ("center_x_mm", "center_y_mm"):
            _set(self, name, _real(name, getattr(self, name)))
        cz = r if self.center_z_mm is None else _real("center_z_mm", self.center_z_mm)
        if cz + r <= 0:
            raise ValueError(f"scene parameter center_z_mm puts the sphere below R: {cz!r}")
        _set(self, "center_z_mm", cz)

    @property
    def center_mm(self) -> tuple[float, float, float]:
        """Sphere centre (X, Y, Z), mm."""
        return (self.center_x_mm, self.center_y_mm, _resolved("center_z_mm", self.center_z_mm))

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        return _cap_height(X, Y, *self.center_mm, self.radius_mm)

    @property
    def z_max_mm(self) -> float:
        return _resolved("center_z_mm", self.center_z_mm) + self.radius_mm

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        cx, cy, r = self.center_x_mm, self.center_y_mm, self.radius_mm
        return (cx - r, cx + r, cy - r, cy + r)

    @property
    def max_slope(self) -> float:
        return math.inf


@dataclass(frozen=True, kw_only=True)
class TwoSpheresScene(Scene):
    """Two equal spheres at a known centre spacing (VDI/VDE 2634 part 2 sphere-spacing error).

    Parameters
    ----------
    radius_mm : float
        Radius of both spheres, mm, > 0. Default 40.
    spacing_mm : float
        Distance between the centres, mm, > 2 radius. Default 250.
    center_x_mm, center_y_mm : float
        Midpoint between the centres, mm. Default: field centre (352, 0).
    center_z_mm : float or None
        Height of both centres, mm; ``None`` (default) rests both spheres on R.
    angle_rad : float
        Direction of the line of centres in the XY plane, from +X towards +Y, rad. Default 0.
    """

    name: ClassVar[str] = "two_spheres"
    radius_mm: float = 40.0
    spacing_mm: float = 250.0
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    center_z_mm: float | None = None
    angle_rad: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        r = _positive("radius_mm", self.radius_mm)
        _set(self, "radius_mm", r)
        spacing = _positive("spacing_mm", self.spacing_mm)
        if spacing <= 2 * r:
            raise ValueError(f"scene parameter spacing_mm must exceed 2 * radius_mm = {2 * r}, got {spacing!r}")
        _set(self, "spacing_mm", spacing)
        for name in ("center_x_mm", "center_y_mm", "angle_rad"):
            _set(self, name, _real(name, getattr(self, name)))
        cz = r if self.center_z_mm is None else _real("center_z_mm", self.center_z_mm)
        if cz + r <= 0:
            raise ValueError(f"scene parameter center_z_mm puts the spheres below R: {cz!r}")
        _set(self, "center_z_mm", cz)

    @property
    def centers_mm(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Centres (X, Y, Z) of the two spheres, mm; the first is on the -direction side."""
        h = self.spacing_mm / 2
        ux, uy = math.cos(self.angle_rad), math.sin(self.angle_rad)
        cz = _resolved("center_z_mm", self.center_z_mm)
        return (
            (self.center_x_mm - h * ux, self.center_y_mm - h * uy, cz),
            (self.center_x_mm + h * ux, self.center_y_mm + h * uy, cz),
        )

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        a, b = self.centers_mm
        return np.maximum(_cap_height(X, Y, *a, self.radius_mm), _cap_height(X, Y, *b, self.radius_mm))

    @property
    def z_max_mm(self) -> float:
        return _resolved("center_z_mm", self.center_z_mm) + self.radius_mm

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        (ax, ay, _), (bx, by, _) = self.centers_mm
        r = self.radius_mm
        return (min(ax, bx) - r, max(ax, bx) + r, min(ay, by) - r, max(ay, by) + r)

    @property
    def footprints_mm(self) -> tuple[tuple[float, float, float, float], ...]:
        r = self.radius_mm
        return tuple((x - r, x + r, y - r, y + r) for x, y, _ in self.centers_mm)

    @property
    def max_slope(self) -> float:
        return math.inf


# --------------------------------------------------------------------------- staircase
@dataclass(frozen=True, kw_only=True)
class StaircaseScene(Scene):
    """Flat steps along X with vertical risers: marked depth discontinuities.

    Step i (i = 0 .. n_steps - 1, counted along +X) covers
    ``edges_x_mm[i] <= X < edges_x_mm[i + 1]`` and ``|Y - center_y_mm| <= size_y_mm / 2`` at
    height ``levels_mm[i]``.

    Parameters
    ----------
    n_steps : int
        Number of treads, >= 1. Default 4.
    step_height_mm : float
        Rise of each step, mm, > 0. Default 10.
    step_width_mm : float
        Run of each tread along X, mm, > 0. Default 60.
    size_y_mm : float
        Extent along Y, mm, > 0. Default 200.
    center_x_mm, center_y_mm : float
        Centre of the footprint, mm. Default: field centre (352, 0).
    ascending : bool
        True (default): heights grow along +X, risers face the projector (lit) and the last
        drop casts a shadow; False: heights fall along +X and every riser casts a shadow.
    """

    name: ClassVar[str] = "staircase"
    n_steps: int = 4
    step_height_mm: float = 10.0
    step_width_mm: float = 60.0
    size_y_mm: float = 200.0
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    ascending: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.n_steps
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"scene parameter n_steps must be a positive integer, got {n!r}")
        _set(self, "n_steps", int(n))
        for name in ("step_height_mm", "step_width_mm", "size_y_mm"):
            _set(self, name, _positive(name, getattr(self, name)))
        for name in ("center_x_mm", "center_y_mm"):
            _set(self, name, _real(name, getattr(self, name)))
        if not isinstance(self.ascending, (bool, np.bool_)):
            raise ValueError(f"scene parameter ascending must be a bool, got {self.ascending!r}")
        _set(self, "ascending", bool(self.ascending))

    @property
    def edges_x_mm(self) -> tuple[float, ...]:
        """X of the n_steps + 1 discontinuities (risers and the two outer walls), mm."""
        x0 = self.center_x_mm - self.n_steps * self.step_width_mm / 2
        return tuple(x0 + i * self.step_width_mm for i in range(self.n_steps + 1))

    @property
    def levels_mm(self) -> tuple[float, ...]:
        """Height of each tread along +X, mm."""
        rises = [(i + 1) * self.step_height_mm for i in range(self.n_steps)]
        return tuple(rises if self.ascending else rises[::-1])

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        edges = self.edges_x_mm
        index = np.floor((X - edges[0]) / self.step_width_mm)
        inside = (index >= 0) & (index < self.n_steps) & (np.abs(Y - self.center_y_mm) <= self.size_y_mm / 2)
        i = np.clip(index, 0, self.n_steps - 1)
        levels = (i + 1) * self.step_height_mm if self.ascending else (self.n_steps - i) * self.step_height_mm
        return np.where(inside, levels, 0.0)

    @property
    def z_max_mm(self) -> float:
        return self.n_steps * self.step_height_mm

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        e = self.edges_x_mm
        h = self.size_y_mm / 2
        return (e[0], e[-1], self.center_y_mm - h, self.center_y_mm + h)

    @property
    def max_slope(self) -> float:
        return math.inf


# --------------------------------------------------------------------------- face
_FACE_BUMPS: tuple[tuple[float, float, float, float, float], ...] = (
    # (dx, dy, ax, ay, amplitude) in mm for scale 1 and relief 115 mm; -Y is the forehead.
    (0.0, 0.0, 140.0, 170.0, 80.0),  # head
    (0.0, -78.0, 80.0, 50.0, 14.0),  # forehead
    (-38.0, -28.0, 28.0, 17.0, -9.0),  # eye sockets
    (38.0, -28.0, 28.0, 17.0, -9.0),
    (0.0, 10.0, 45.0, 55.0, 26.0),  # nose
    (-52.0, 30.0, 40.0, 34.0, 10.0),  # cheeks
    (52.0, 30.0, 40.0, 34.0, 10.0),
    (0.0, 64.0, 32.0, 12.0, 5.0),  # lips
    (0.0, 108.0, 40.0, 26.0, 10.0),  # chin
)
_FACE_NOMINAL_RELIEF_MM = 106.0
"""Head plus nose amplitude of :data:`_FACE_BUMPS`: the ``relief_mm`` of gain 1."""


@dataclass(frozen=True, kw_only=True)
class FaceScene(_SmoothScene):
    """A smooth face-like relief: a sum of compact C2 bumps (head, forehead, eyes, nose, ...).

    Each bump is ``A (1 - r^2)^3`` inside its ellipse ``r < 1`` and 0 outside, so the relief is
    smooth, exactly 0 outside its footprint and has bounded slope (no projector shadows and
    one crossing per camera ray on the paper's rig).

    Parameters
    ----------
    center_x_mm, center_y_mm : float
        Centre of the head, mm. Default: field centre (352, 0).
    scale : float
        Lateral size factor, > 0; 1 gives a 280 mm x 340 mm footprint. Default 1.
    relief_mm : float
        Amplitude factor: the head-plus-nose peak height, mm, > 0. Default 106
        (the highest point is about 105 mm above R).
    """

    name: ClassVar[str] = "face"
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    scale: float = 1.0
    relief_mm: float = 106.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("center_x_mm", "center_y_mm"):
            _set(self, name, _real(name, getattr(self, name)))
        for name in ("scale", "relief_mm"):
            _set(self, name, _positive(name, getattr(self, name)))

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        gain = self.relief_mm / _FACE_NOMINAL_RELIEF_MM
        shape = np.broadcast_shapes(X.shape, Y.shape)
        dx0 = np.broadcast_to(X - self.center_x_mm, shape).ravel()
        dy0 = np.broadcast_to(Y - self.center_y_mm, shape).ravel()
        z = np.zeros(dx0.size)
        s = self.scale
        for number, (bx, by, ax, ay, amp) in enumerate(_FACE_BUMPS):
            dx, dy = dx0 - bx * s, dy0 - by * s
            if number == 0:  # the head covers the footprint
                z += (gain * amp) * _bump(dx, dy, ax * s, ay * s)
                continue
            # Small bumps: evaluate only inside their box.
            near = np.flatnonzero((np.abs(dx) < ax * s) & (np.abs(dy) < ay * s))
            z[near] += (gain * amp) * _bump(dx[near], dy[near], ax * s, ay * s)
        return np.maximum(z, 0.0, out=z).reshape(shape)

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        _, _, ax, ay, _ = _FACE_BUMPS[0]
        s = self.scale
        return (
            self.center_x_mm - ax * s,
            self.center_x_mm + ax * s,
            self.center_y_mm - ay * s,
            self.center_y_mm + ay * s,
        )


# --------------------------------------------------------------------------- flowerpot
@dataclass(frozen=True, kw_only=True)
class FlowerpotScene(_SmoothScene):
    """A smooth bulge decorated with sub-millimetre ridges (the paper's decorated surface).

    ``h = bulge_mm * b(r) + ridge_height_mm * (1 - cos(2 pi (Y - cy) / ridge_period_mm)) / 2 * b(r)^(1/3)``
    with ``b = (1 - r^2)^3`` over the ellipse of semi-axes ``size_x_mm / 2``, ``size_y_mm / 2``.
    The ridges run along X (bands at constant Y, like the rings of a pot lying along Y);
    GCPS resolves them, gray code alone (one code is about 4 mm on R) does not.

    Parameters
    ----------
    center_x_mm, center_y_mm : float
        Centre, mm. Default: field centre (352, 0).
    size_x_mm, size_y_mm : float
        Footprint of the bulge, mm, > 0. Default 300 x 240.
    bulge_mm : float
        Height of the undecorated bulge, mm, >= 0. Default 60.
    ridge_height_mm : float
        Peak-to-valley height of the decoration, mm, >= 0. Default 0.4.
    ridge_period_mm : float
        Spacing of the ridges along Y, mm, > 0. Default 8.
    """

    name: ClassVar[str] = "flowerpot"
    center_x_mm: float = FIELD_CENTER_X_MM
    center_y_mm: float = 0.0
    size_x_mm: float = 300.0
    size_y_mm: float = 240.0
    bulge_mm: float = 60.0
    ridge_height_mm: float = 0.4
    ridge_period_mm: float = 8.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("center_x_mm", "center_y_mm"):
            _set(self, name, _real(name, getattr(self, name)))
        for name in ("size_x_mm", "size_y_mm", "ridge_period_mm"):
            _set(self, name, _positive(name, getattr(self, name)))
        for name in ("bulge_mm", "ridge_height_mm"):
            _set(self, name, _non_negative(name, getattr(self, name)))
        if self.bulge_mm + self.ridge_height_mm <= 0:
            raise ValueError("scene parameters bulge_mm and ridge_height_mm are both 0")

    def _window(self, X: FloatArray, Y: FloatArray) -> FloatArray:
        return _bump(X - self.center_x_mm, Y - self.center_y_mm, self.size_x_mm / 2, self.size_y_mm / 2)

    def base_height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        """The undecorated bulge, mm (float64, broadcast shape)."""
        X, Y = _xy(X, Y)
        return self.bulge_mm * self._window(X, Y)

    def decoration_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        """The ridges alone, mm, in [0, ridge_height_mm] (float64, broadcast shape)."""
        X, Y = _xy(X, Y)
        ridges = 0.5 - 0.5 * np.cos(2 * np.pi * (Y - self.center_y_mm) / self.ridge_period_mm)
        return self.ridge_height_mm * ridges * np.cbrt(self._window(X, Y))

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        X, Y = _xy(X, Y)
        w = self._window(X, Y)
        ridges = 0.5 - 0.5 * np.cos(2 * np.pi * (Y - self.center_y_mm) / self.ridge_period_mm)
        return self.bulge_mm * w + self.ridge_height_mm * ridges * np.cbrt(w)

    @property
    def footprint_mm(self) -> tuple[float, float, float, float] | None:
        hx, hy = self.size_x_mm / 2, self.size_y_mm / 2
        return (self.center_x_mm - hx, self.center_x_mm + hx, self.center_y_mm - hy, self.center_y_mm + hy)


# --------------------------------------------------------------------------- meshes
def _rotation(value: Any) -> FloatArray:
    rotation = np.asarray(value, dtype=np.float64)
    if rotation.shape != (3, 3) or not np.isfinite(rotation).all():
        raise ValueError(f"scene parameter rotation must be a finite 3 x 3 matrix, got shape {rotation.shape}")
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-9) or np.linalg.det(rotation) < 0:
        raise ValueError("scene parameter rotation must be a proper rotation (orthonormal, determinant +1)")
    return rotation


@dataclass(frozen=True, kw_only=True, eq=False)
class MeshScene(Scene):
    """A triangle mesh (a nominal part) placed at a pose in the model frame, ray cast as it is.

    Not a height field: the virtual rig casts the camera rays and the projector's shadow rays
    against the triangles (:func:`metrology.core.simulate.cast.cast_truth`, Open3D's
    ``RaycastingScene``, each hit then recomputed in float64 on its triangle), on every model.
    A point of the mesh ``x`` sits at ``rotation @ x + translation_mm`` in the model frame (the
    paper's frame on R, a pinhole rig's camera frame). Nothing else is in the scene: add the
    support (a plane, a table) to the mesh when it should be seen. Not in :data:`SCENES` (it
    takes arrays): build it directly, or with :meth:`on_plane`.

    Parameters
    ----------
    vertices_mm : (V, 3) array_like of float
        The mesh's vertices in its own frame, mm.
    faces : (F, 3) array_like of int
        Vertex indices of each triangle (outward normals counter-clockwise, as STL).
    rotation : (3, 3) array_like of float
        Rotation of the mesh frame into the model frame. Default identity.
    translation_mm : (3,) array_like of float
        Model-frame position of the mesh frame's origin, mm. Default 0.
    """

    name: ClassVar[str] = "mesh"
    height_field: ClassVar[bool] = False
    vertices_mm: np.ndarray
    faces: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        super().__post_init__()
        vertices = np.array(self.vertices_mm, dtype=np.float64)
        faces = np.array(self.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not len(vertices) or not np.isfinite(vertices).all():
            raise ValueError(f"scene parameter vertices_mm must be a finite (V, 3) array, got shape {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3 or not len(faces) or faces.dtype.kind not in "iu":
            raise ValueError(f"scene parameter faces must be an (F, 3) integer array, got {faces.shape} {faces.dtype}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise ValueError(f"scene parameter faces indexes vertices outside 0..{len(vertices) - 1}")
        translation = np.array(self.translation_mm, dtype=np.float64)
        if translation.shape != (3,) or not np.isfinite(translation).all():
            raise ValueError(f"scene parameter translation_mm must be 3 finite numbers, got {self.translation_mm!r}")
        for name, value in (
            ("vertices_mm", vertices),
            ("faces", faces.astype(np.int64)),
            ("rotation", _rotation(self.rotation)),
            ("translation_mm", translation),
        ):
            value.flags.writeable = False
            _set(self, name, value)

    @classmethod
    def on_plane(
        cls,
        vertices_mm: npt.ArrayLike,
        faces: npt.ArrayLike,
        placement: Any,
        *,
        rotation: npt.ArrayLike | None = None,
        translation_mm: npt.ArrayLike | None = None,
        reflectance: float = 1.0,
    ) -> MeshScene:
        """A mesh given in the scene coordinates ``(X, Y, height)`` of a
        :class:`~metrology.core.simulate.cast.ScenePlacement` (after the optional pose ``rotation``,
        ``translation_mm`` there): a mesh built like the height-field scenes, on their reference plane.

        The scene is stored with its vertices in the model frame (identity pose). A placement whose
        frame is mirrored (:meth:`~metrology.core.simulate.cast.ScenePlacement.facing_camera`: ``X, Y``
        and the height towards the camera are left-handed in a camera frame) reverses the faces'
        order of corners, so that the normals stay outward.
        """
        frame = np.column_stack([placement.e_x, placement.e_y, placement.e_n])
        inner = np.eye(3) if rotation is None else _rotation(rotation)
        shift = np.zeros(3) if translation_mm is None else np.asarray(translation_mm, dtype=np.float64)
        local = np.asarray(vertices_mm, dtype=np.float64) @ inner.T + shift
        corners = np.asarray(faces)
        return cls(
            vertices_mm=local @ frame.T + np.asarray(placement.origin_mm, dtype=np.float64),
            faces=corners[:, ::-1] if np.linalg.det(frame) < 0 else corners,
            reflectance=reflectance,
        )

    @property
    def model_vertices_mm(self) -> FloatArray:
        """``(V, 3)`` float64: the vertices in the model frame, mm."""
        return np.asarray(self.vertices_mm @ self.rotation.T + self.translation_mm, dtype=np.float64)

    def height_mm(self, X: npt.ArrayLike, Y: npt.ArrayLike) -> FloatArray:
        raise TypeError("a mesh scene is not a height field: it is ray cast (metrology.core.simulate.cast_truth)")

    def params(self) -> dict[str, Any]:
        """The name, counts, a SHA-256 of the vertices and faces, the pose and the reflectance."""
        import hashlib

        digest = hashlib.sha256(self.vertices_mm.tobytes() + self.faces.tobytes()).hexdigest()
        return {
            "scene": self.name,
            "reflectance": self.reflectance,
            "vertices": len(self.vertices_mm),
            "faces": len(self.faces),
            "sha256": digest,
            "rotation": self.rotation.tolist(),
            "translation_mm": self.translation_mm.tolist(),
        }


# --------------------------------------------------------------------------- registry
SCENES: Mapping[str, type[Scene]] = {
    cls.name: cls
    for cls in (
        ReferenceScene,
        PlaneScene,
        BlockScene,
        SphereScene,
        TwoSpheresScene,
        StaircaseScene,
        FaceScene,
        FlowerpotScene,
        StageScene,
    )
}
"""Scene classes by name, as typed on the command line (``gcps simulate --scene NAME``)."""


def scene_parameters(name: str) -> dict[str, Any]:
    """The parameters scene ``name`` accepts, with their defaults.

    Raises
    ------
    ValueError
        If ``name`` is not in :data:`SCENES`.
    """
    cls = _scene_class(name)
    return {f.name: f.default for f in fields(cls) if f.init}


def _scene_class(name: str) -> type[Scene]:
    try:
        return SCENES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown scene {name!r}; expected one of {', '.join(SCENES)}") from None


def make_scene(name: str, rig: GeometryModel | None = None, **params: Any) -> Scene:
    """Build scene ``name`` from keyword parameters.

    Parameters
    ----------
    name : str
        One of :data:`SCENES`: reference, plane, block, sphere, two_spheres, staircase, face,
        flowerpot, stage.
    rig : GeometryModel, optional
        When given, scenes with a ``center_x_mm`` default it to the rig's field centre on its
        plane (:attr:`~metrology.core.geometry.base.GeometryModel.scene_centre_x_mm`: the
        crossed-axes rig's ``d_mm``) instead of the paper's 352 mm.
    **params
        The scene's parameters (see :func:`scene_parameters`).

    Returns
    -------
    Scene

    Raises
    ------
    ValueError
        Unknown scene, unknown parameter (named), or a parameter value out of range (named).
    """
    cls = _scene_class(name)
    accepted = scene_parameters(name)
    unknown = sorted(set(params) - set(accepted))
    if unknown:
        raise ValueError(
            f"scene {name!r} has no parameter {', '.join(map(repr, unknown))}; "
            f"it accepts {', '.join(accepted) or 'none'}"
        )
    centre = None if rig is None else rig.scene_centre_x_mm
    if centre is not None and "center_x_mm" in accepted and "center_x_mm" not in params:
        params["center_x_mm"] = centre
    return cls(**params)


SceneFactory = Callable[[float], Scene]
