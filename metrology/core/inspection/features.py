"""Feature fits on a region of a scan: plane, sphere, cylinder and circle, by least squares and by
minimum zone, with their form errors (flatness, sphericity, cylindricity, roundness) and uncertainties.

Points are ``(N, 3)`` float64 millimetres (any frame); an optional ``sigma_mm`` ``(N,)`` gives each
point's standard uncertainty along the feature's normal, mm. Every feature is a parametrised
surface with one *geometric residual* per point (mm, positive outside):

- plane: ``r = n . (p - c)`` (``n`` the unit normal, ``c`` a point of the plane);
- sphere: ``r = |p - c| - R``;
- cylinder: ``r = |(p - q) - ((p - q) . w) w| - R`` (``q`` a point of the axis, ``w`` its unit direction);
- circle (in space): a plane fitted first, then in that plane, for the points projected on it,
  ``r = |p' - c| - R`` (ISO 12181: roundness is measured in a section).

**Least squares** minimises ``sum (r_i / sigma_i)^2`` (``sigma_i = 1`` without sigma): an algebraic
start (centroid and SVD for a plane, the linear sphere/circle fit ``|p|^2 = 2 c . p + k``, the
three principal directions tried as cylinder axes), then Levenberg-Marquardt on the geometric
residuals (scipy ``least_squares``, analytic Jacobians). The parameters are small moves of the
final shape (tilts of the normal or axis in rad, shifts in mm, the radius in mm), so their
covariance is ``C = (J^T W J)^-1`` at the solution with ``W = diag(1 / sigma_i^2)`` when sigma is
given, else ``C = s^2 (J^T J)^-1`` with ``s^2 = sum r_i^2 / (N - p)``; :attr:`FeatureFit.std` is the
square root of its diagonal.

**Minimum zone** (Chebyshev) minimises ``max |r_i|`` over the same parameters (the size, offset
or radius included): the narrowest pair of parallel planes, concentric spheres, coaxial
cylinders or concentric circles holding every point. Solved by sequential linear programming
from the least-squares shape: each step minimises ``t`` subject to
``-t <= r_i + J_i delta <= t`` within a trust region (scipy ``linprog``, HiGHS), solved by exchange
(the programme of the points of largest ``|r|``, then with the points it violates added, until
none is); the step is accepted when ``max |r|`` falls.
The reported width (flatness, sphericity, cylindricity, roundness) is ``max r - min r`` of the
final shape: a zone that holds every point, never narrower than the true minimum. Its standard
uncertainty is first order: ``sqrt(sigma_a^2 + sigma_b^2)`` at the two points that touch the
outer and inner surfaces (with sigma), or ``sqrt(2) s`` from the least-squares residuals (an
upper bound where the residuals are form rather than noise). Noise widens a zone: the width of
noisy points estimates form plus about 4 to 6 sigma.

:func:`compare_with_nominal` fits the same feature to the nominal mesh's vertices near the
measured one and gives the nominal's value beside the measured one.

Examples
--------
>>> import numpy as np
>>> t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
>>> ring = np.stack([10 + 5 * np.cos(t), 5 * np.sin(t), np.full(36, 2.0)], axis=1)
>>> fit = fit_circle(ring)
>>> round(fit.radius_mm, 9), round(fit.form_mm, 9)
(5.0, 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any, ClassVar, Protocol

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

KINDS = ("plane", "sphere", "cylinder", "circle")
"""The features :func:`fit_feature` fits."""
FORM_NAMES: Mapping[str, str] = {
    "plane": "flatness",
    "sphere": "sphericity",
    "cylinder": "cylindricity",
    "circle": "roundness",
}
"""The form error each feature's minimum zone measures."""

MAX_ZONE_ITERATIONS = 200
"""Largest number of linear programmes of one minimum-zone fit."""


# --------------------------------------------------------------------------- shapes
class _Shape(Protocol):
    """A feature's shape with a local parametrisation: ``theta = 0`` is the shape itself."""

    names: ClassVar[tuple[str, ...]]

    def residuals(self, theta: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``(r (N,), J (N, p))``: geometric residuals (mm) and their derivatives in ``theta``."""
        ...

    def moved(self, theta: FloatArray) -> _Shape:
        """The shape at parameters ``theta`` (whose own parameters are then 0)."""
        ...

    def scales(self, extent_mm: float) -> FloatArray:
        """``(p,)`` move of each parameter that shifts a point ``extent_mm`` away by about 1 mm."""
        ...


def _frame(normal: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unit ``n`` and two unit vectors ``e1, e2`` completing a right-handed orthonormal frame."""
    n = normal / np.linalg.norm(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return n, e1, np.cross(n, e1)


@dataclass(frozen=True)
class _Plane:
    """``n(a, b) = normalise(n + a e1 + b e2)``, ``r = n(a, b) . (p - c) - d``; theta ``(a, b, d)``."""

    names: ClassVar[tuple[str, ...]] = ("tilt_1_rad", "tilt_2_rad", "offset_mm")
    point: FloatArray
    normal: FloatArray
    e1: FloatArray
    e2: FloatArray

    @classmethod
    def through(cls, point: FloatArray, normal: FloatArray) -> _Plane:
        n, e1, e2 = _frame(normal)
        return cls(point, n, e1, e2)

    def _normal(self, theta: FloatArray) -> tuple[FloatArray, float]:
        m = self.normal + theta[0] * self.e1 + theta[1] * self.e2
        size = float(np.linalg.norm(m))
        return m / size, size

    def residuals(self, theta: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        w, size = self._normal(theta)
        q = points - self.point
        along = q @ w
        jac = np.empty((len(points), 3))
        jac[:, 0] = (q @ self.e1 - along * theta[0] / size) / size
        jac[:, 1] = (q @ self.e2 - along * theta[1] / size) / size
        jac[:, 2] = -1.0
        return along - theta[2], jac

    def moved(self, theta: FloatArray) -> _Plane:
        w, _ = self._normal(theta)
        return _Plane.through(self.point + theta[2] * w, w)

    def scales(self, extent_mm: float) -> FloatArray:
        return np.array([1.0 / extent_mm, 1.0 / extent_mm, 1.0])

    def centred(self, points: FloatArray, weights: FloatArray) -> _Plane:
        """The same plane, its point the projection of the weighted centroid of ``points``."""
        centroid = np.average(points, axis=0, weights=weights)
        return replace(self, point=centroid - ((centroid - self.point) @ self.normal) * self.normal)


@dataclass(frozen=True)
class _Ball:
    """A sphere (3-D points) or a circle (2-D points): ``r = |p - c - dc| - (R + dR)``; theta ``(dc, dR)``."""

    names: ClassVar[tuple[str, ...]] = ()
    centre: FloatArray
    radius: float

    def residuals(self, theta: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        k = len(self.centre)
        rel = points - (self.centre + theta[:k])
        dist = np.linalg.norm(rel, axis=1)
        jac = np.empty((len(points), k + 1))
        jac[:, :k] = -rel / np.where(dist > 0, dist, 1.0)[:, None]
        jac[:, k] = -1.0
        return dist - (self.radius + theta[k]), jac

    def moved(self, theta: FloatArray) -> _Ball:
        k = len(self.centre)
        return replace(self, centre=self.centre + theta[:k], radius=self.radius + float(theta[k]))

    def scales(self, extent_mm: float) -> FloatArray:
        return np.ones(len(self.centre) + 1)


@dataclass(frozen=True)
class _Sphere(_Ball):
    names: ClassVar[tuple[str, ...]] = ("centre_x_mm", "centre_y_mm", "centre_z_mm", "radius_mm")


@dataclass(frozen=True)
class _Circle2(_Ball):
    names: ClassVar[tuple[str, ...]] = ("centre_1_mm", "centre_2_mm", "radius_mm")


@dataclass(frozen=True)
class _Cylinder:
    """Axis through ``q + x e1 + y e2`` along ``w = normalise(u + a e1 + b e2)``, radius ``R + dR``:
    ``r = |d - (d . w) w| - R``, ``d = p - q``; theta ``(x, y, a, b, dR)``."""

    names: ClassVar[tuple[str, ...]] = ("axis_shift_1_mm", "axis_shift_2_mm", "tilt_1_rad", "tilt_2_rad", "radius_mm")
    point: FloatArray
    axis: FloatArray
    e1: FloatArray
    e2: FloatArray
    radius: float

    @classmethod
    def along(cls, point: FloatArray, axis: FloatArray, radius: float) -> _Cylinder:
        u, e1, e2 = _frame(axis)
        return cls(point, u, e1, e2, radius)

    def _axis(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        m = self.axis + theta[2] * self.e1 + theta[3] * self.e2
        size = float(np.linalg.norm(m))
        return self.point + theta[0] * self.e1 + theta[1] * self.e2, m / size, size

    def residuals(self, theta: FloatArray, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        q, w, size = self._axis(theta)
        d = points - q
        along = d @ w
        radial = d - along[:, None] * w
        rho = np.linalg.norm(radial, axis=1)
        unit = radial / np.where(rho > 0, rho, 1.0)[:, None]
        jac = np.empty((len(points), 5))
        jac[:, 0] = -(unit @ self.e1)
        jac[:, 1] = -(unit @ self.e2)
        for column, e in ((2, self.e1), (3, self.e2)):
            dw = (e - (w @ e) * w) / size
            jac[:, column] = -along * (d @ dw) / np.where(rho > 0, rho, 1.0)
        jac[:, 4] = -1.0
        return rho - (self.radius + theta[4]), jac

    def moved(self, theta: FloatArray) -> _Cylinder:
        q, w, _ = self._axis(theta)
        return _Cylinder.along(q, w, self.radius + float(theta[4]))

    def scales(self, extent_mm: float) -> FloatArray:
        return np.array([1.0, 1.0, 1.0 / extent_mm, 1.0 / extent_mm, 1.0])

    def centred(self, points: FloatArray, weights: FloatArray) -> _Cylinder:
        """The same cylinder, its axis point the projection of the weighted centroid of ``points``."""
        centroid = np.average(points, axis=0, weights=weights)
        return _Cylinder.along(self.point + ((centroid - self.point) @ self.axis) * self.axis, self.axis, self.radius)


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class MinimumZone:
    """The minimum-zone (Chebyshev) shape of a feature (module docstring).

    Attributes
    ----------
    width_mm : float
        ``max r - min r`` of the zone's shape: flatness, sphericity, cylindricity or roundness, mm.
    u_width_mm : float
        Its first-order standard uncertainty, mm (module docstring).
    geometry : dict
        The zone's mid surface, with the keys of the least-squares fit's geometry (mm, unit vectors).
    iterations : int
        Linear programmes solved.
    converged : bool
        False when :data:`MAX_ZONE_ITERATIONS` ended the search first.
    """

    width_mm: float
    u_width_mm: float
    geometry: Mapping[str, Any]
    iterations: int
    converged: bool

    def to_dict(self) -> dict[str, Any]:
        """The fields by name (JSON types)."""
        return asdict(self)


@dataclass(frozen=True, eq=False)
class FeatureFit:
    """A feature fitted to points: the least-squares shape, its uncertainty and the form error.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    geometry : dict
        The least-squares shape: plane ``point_mm``, ``normal``; sphere ``centre_mm``,
        ``radius_mm``; cylinder ``axis_point_mm`` (the projection of the points' centroid),
        ``axis_direction``, ``radius_mm``; circle ``centre_mm``, ``normal``, ``radius_mm``.
        Vectors are lists of three floats (mm, or unit vectors).
    n_points : int
    rms_mm : float
        Root mean square of the least-squares residuals, mm.
    peak_to_valley_mm : float
        ``max r - min r`` of the least-squares residuals, mm (the form error of a Gaussian fit).
    parameter_names : tuple of str
        The parameters of :attr:`covariance`: small moves of the fitted shape (``tilt_*_rad``:
        rotations of the normal or axis towards two perpendicular directions; ``*_mm``: shifts and
        the radius).
    covariance : (p, p) float64 array
        Their covariance (module docstring), mm and rad.
    sigma_given : bool
        True when per-point sigma weighted the fit and scales the covariance.
    chi2_reduced : float
        ``sum (r_i / sigma_i)^2 / (N - p)`` (1 expected with the right sigma and no form error).
    zone : MinimumZone or None
        The minimum-zone fit (None when not asked for).
    """

    kind: str
    geometry: Mapping[str, Any]
    n_points: int
    rms_mm: float
    peak_to_valley_mm: float
    parameter_names: tuple[str, ...]
    covariance: FloatArray
    sigma_given: bool
    chi2_reduced: float
    zone: MinimumZone | None = field(default=None)

    @property
    def std(self) -> dict[str, float]:
        """Standard uncertainty of each parameter (``sqrt`` of the covariance's diagonal), by name."""
        return {
            name: float(math.sqrt(max(v, 0.0)))
            for name, v in zip(self.parameter_names, np.diag(self.covariance), strict=True)
        }

    @property
    def form_name(self) -> str:
        """flatness, sphericity, cylindricity or roundness."""
        return FORM_NAMES[self.kind]

    @property
    def form_mm(self) -> float:
        """The form error: the minimum zone's width, or the least-squares peak to valley without a zone, mm."""
        return self.zone.width_mm if self.zone is not None else self.peak_to_valley_mm

    @property
    def radius_mm(self) -> float:
        """The fitted radius, mm (sphere, cylinder, circle)."""
        if "radius_mm" not in self.geometry:
            raise AttributeError(f"a {self.kind} has no radius")
        return float(self.geometry["radius_mm"])

    def to_dict(self) -> dict[str, Any]:
        """JSON form: the fields, ``std`` by name and ``form`` ``{name, value_mm, method}``."""
        return {
            "kind": self.kind,
            "geometry": dict(self.geometry),
            "n_points": self.n_points,
            "rms_mm": self.rms_mm,
            "peak_to_valley_mm": self.peak_to_valley_mm,
            "parameters": list(self.parameter_names),
            "covariance": self.covariance.tolist(),
            "std": self.std,
            "sigma_given": self.sigma_given,
            "chi2_reduced": self.chi2_reduced,
            "form": {
                "name": self.form_name,
                "value_mm": self.form_mm,
                "method": "minimum_zone" if self.zone is not None else "least_squares",
            },
            "zone": None if self.zone is None else self.zone.to_dict(),
        }


# --------------------------------------------------------------------------- input
def _inputs(points_mm: npt.ArrayLike, sigma_mm: npt.ArrayLike | None, minimum: int) -> tuple[FloatArray, FloatArray]:
    points = np.asarray(points_mm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points_mm must be an (N, 3) array, got shape {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points_mm must be finite (select the region's measured points first)")
    if len(points) < minimum:
        raise ValueError(f"at least {minimum} points are needed, got {len(points)}")
    if sigma_mm is None:
        return points, np.ones(len(points))
    sigma = np.asarray(sigma_mm, dtype=np.float64)
    if sigma.shape != (len(points),):
        raise ValueError(f"sigma_mm must have shape ({len(points)},), got {sigma.shape}")
    if not (np.isfinite(sigma).all() and (sigma > 0).all()):
        raise ValueError("sigma_mm must be finite and positive")
    return points, sigma


# --------------------------------------------------------------------------- solvers
def _least_squares(shape: _Shape, points: FloatArray, sigma: FloatArray) -> _Shape:
    """Levenberg-Marquardt on ``r_i / sigma_i`` from ``shape``; the optimum as a shape."""
    from scipy.optimize import least_squares

    p = len(shape.names)
    inverse = 1.0 / sigma
    current = shape
    for _ in range(3):  # re-centre the parametrisation and polish
        solution = least_squares(
            _weighted(current, points, inverse, 0),
            np.zeros(p),
            jac=_weighted(current, points, inverse, 1),
            method="lm",
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
        )
        current = current.moved(solution.x)
        if np.all(np.abs(solution.x) * current.scales(1.0) < 1e-14):
            break
    return current


def _weighted(shape: _Shape, points: FloatArray, inverse: FloatArray, which: int) -> Callable[[FloatArray], FloatArray]:
    """The residuals (``which = 0``) or Jacobian (1) of ``shape``, each row divided by its sigma."""
    scale = inverse if which == 0 else inverse[:, None]
    return lambda theta: shape.residuals(theta, points)[which] * scale


def _covariance(
    shape: _Shape, points: FloatArray, sigma: FloatArray, sigma_given: bool
) -> tuple[FloatArray, FloatArray, float]:
    """``(residuals, covariance, chi2_reduced)`` at ``shape`` (module docstring)."""
    r, jac = shape.residuals(np.zeros(len(shape.names)), points)
    weighted = jac / sigma[:, None]
    dof = max(len(points) - len(shape.names), 1)
    chi2 = float(np.sum((r / sigma) ** 2) / dof)
    normal = weighted.T @ weighted
    inverse = np.asarray(np.linalg.pinv(normal), dtype=np.float64)
    return r, inverse if sigma_given else inverse * chi2, chi2


def _minimum_zone(shape: _Shape, points: FloatArray) -> tuple[_Shape, FloatArray, int, bool]:
    """Minimise ``max |r_i|`` by sequential linear programming (module docstring).

    Returns the zone's shape, its residuals, the number of steps and whether it converged.
    """
    p = len(shape.names)
    extent = float(np.max(np.linalg.norm(points - points.mean(axis=0), axis=1))) or 1.0
    scales = shape.scales(extent)
    r, jac = shape.residuals(np.zeros(p), points)
    worst = float(np.max(np.abs(r)))
    radius = max(float(np.ptp(r)), 1e-9 * extent)  # trust region, mm of point motion
    floor = 1e-13 * extent
    for iteration in range(1, MAX_ZONE_ITERATIONS + 1):
        bound = radius * scales
        reach = np.abs(jac) @ bound  # the most a point's residual can change in the region
        keep = np.abs(r) + reach >= np.max(np.abs(r) - reach)
        lp = _chebyshev_step(r[keep], jac[keep], bound)
        if lp is None:
            radius *= 0.5
            if radius < floor:
                return shape, r, iteration, False
            continue
        step, predicted = lp
        gain = worst - predicted
        if gain <= 1e-12 * max(worst, floor) + floor:
            return shape, r, iteration, True
        trial = shape.moved(step)
        r_trial, jac_trial = trial.residuals(np.zeros(p), points)
        worst_trial = float(np.max(np.abs(r_trial)))
        ratio = (worst - worst_trial) / gain
        if ratio > 0.1:
            shape, r, jac, worst = trial, r_trial, jac_trial, worst_trial
            if ratio > 0.75 and np.max(np.abs(step) / bound) > 0.99:
                radius *= 2.0
        else:
            radius *= 0.25
            if radius < floor:
                return shape, r, iteration, True
    return shape, r, MAX_ZONE_ITERATIONS, False


EXCHANGE_POINTS = 64
"""Points per parameter of each linear programme of the exchange (:func:`_chebyshev_step`)."""
EXCHANGE_TOLERANCE = 1e-10
"""A point outside the subset violates a step's zone when it exceeds ``t`` by this fraction of the
largest residual (HiGHS keeps its own constraints to about 1e-9 relative)."""


def _chebyshev_step(r: FloatArray, jac: FloatArray, bound: FloatArray) -> tuple[FloatArray, float] | None:
    """``(delta, t)`` minimising ``t`` subject to ``|r_i + J_i delta| <= t`` for every ``i`` and
    ``|delta_j| <= bound_j`` (None when the solver fails).

    Solved by exchange: the linear programme of the points of largest ``|r|`` first, then again
    with the points it violates added, until none is violated (the optimum of a subset that every
    point satisfies is the optimum of all).
    """
    from scipy.optimize import linprog

    p = jac.shape[1]
    cost = np.zeros(p + 1)
    cost[p] = 1.0
    bounds = [(-b, b) for b in bound] + [(0.0, None)]
    batch = EXCHANGE_POINTS * p
    subset = np.argsort(-np.abs(r))[:batch]
    while True:
        rk, jk = r[subset], jac[subset]
        ones = np.ones((len(subset), 1))
        a_ub = np.block([[jk, -ones], [-jk, -ones]])
        lp = linprog(cost, A_ub=a_ub, b_ub=np.concatenate([-rk, rk]), bounds=bounds, method="highs")
        if lp.status != 0:
            return None
        step, t = lp.x[:p], float(lp.x[p])
        excess = np.abs(r + jac @ step) - t
        excess[subset] = 0.0  # the solver's own tolerance decides those
        violated = np.flatnonzero(excess > EXCHANGE_TOLERANCE * max(t, float(np.abs(r).max()), 1e-300))
        if not violated.size:
            return step, t
        worst = violated[np.argsort(-excess[violated])[:batch]]
        subset = np.union1d(subset, worst)


def _zone_uncertainty(r: FloatArray, sigma: FloatArray, sigma_given: bool, rms: float) -> float:
    if not sigma_given:
        return math.sqrt(2.0) * rms
    return float(math.hypot(sigma[int(np.argmax(r))], sigma[int(np.argmin(r))]))


# --------------------------------------------------------------------------- starts
def _algebraic_ball(points: FloatArray, weights: FloatArray) -> tuple[FloatArray, float]:
    """The linear fit ``|p|^2 = 2 c . p + k`` (``k = R^2 - |c|^2``) of ``(N, k)`` points, centred
    first for conditioning: ``(centre, radius)``."""
    origin = np.average(points, axis=0, weights=weights)
    q = points - origin
    design = np.column_stack([2.0 * q, np.ones(len(q))]) * weights[:, None]
    target = np.sum(q * q, axis=1) * weights
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    centre = solution[:-1]
    return origin + centre, float(math.sqrt(max(solution[-1] + centre @ centre, 0.0)))


def _plane_start(points: FloatArray, weights: FloatArray) -> _Plane:
    centroid = np.average(points, axis=0, weights=weights)
    _, _, vt = np.linalg.svd((points - centroid) * weights[:, None], full_matrices=False)
    return _Plane.through(centroid, vt[2])


def _principal_axes(points: FloatArray, weights: FloatArray) -> FloatArray:
    centroid = np.average(points, axis=0, weights=weights)
    _, _, vt = np.linalg.svd((points - centroid) * weights[:, None], full_matrices=False)
    return vt


START_POINTS = 2000
"""A cylinder's candidate starts are compared on an even subsample of at most about this many points."""


def _cylinder_starts(points: FloatArray, weights: FloatArray, axis_hint: FloatArray | None) -> list[_Cylinder]:
    """A start per candidate axis: the hint, or the three principal directions; each with the
    algebraic circle of the points projected across it."""
    candidates = [axis_hint] if axis_hint is not None else list(_principal_axes(points, weights))
    centroid = np.average(points, axis=0, weights=weights)
    starts = []
    for axis in candidates:
        u, e1, e2 = _frame(np.asarray(axis, dtype=np.float64))
        flat = np.column_stack([(points - centroid) @ e1, (points - centroid) @ e2])
        centre, radius = _algebraic_ball(flat, weights)
        starts.append(_Cylinder(centroid + centre[0] * e1 + centre[1] * e2, u, e1, e2, radius))
    return starts


# --------------------------------------------------------------------------- geometry of shapes
def _vector(v: FloatArray) -> list[float]:
    return [float(x) for x in v]


def _geometry(kind: str, shape: Any, plane: _Plane | None = None) -> dict[str, Any]:
    if kind == "plane":
        return {"point_mm": _vector(shape.point), "normal": _vector(shape.normal)}
    if kind == "sphere":
        return {"centre_mm": _vector(shape.centre), "radius_mm": float(shape.radius)}
    if kind == "cylinder":
        return {
            "axis_point_mm": _vector(shape.point),
            "axis_direction": _vector(shape.axis),
            "radius_mm": float(shape.radius),
        }
    assert plane is not None
    centre = plane.point + shape.centre[0] * plane.e1 + shape.centre[1] * plane.e2
    return {"centre_mm": _vector(centre), "normal": _vector(plane.normal), "radius_mm": float(shape.radius)}


def _result(
    kind: str,
    shape: Any,
    points: FloatArray,
    sigma: FloatArray,
    sigma_given: bool,
    minimum_zone: bool,
    plane: _Plane | None = None,
    extra_covariance: FloatArray | None = None,
) -> FeatureFit:
    """The fit's result from its least-squares shape (``points`` in the shape's own coordinates)."""
    r, covariance, chi2 = _covariance(shape, points, sigma, sigma_given)
    names = shape.names
    if extra_covariance is not None:  # the circle: the plane's parameters first
        names = _Plane.names + names
        covariance = np.block(
            [
                [extra_covariance, np.zeros((3, covariance.shape[0]))],
                [np.zeros((covariance.shape[0], 3)), covariance],
            ]
        )
    rms = float(np.sqrt(np.mean(r * r)))
    zone = None
    if minimum_zone:
        zone_shape, zr, iterations, converged = _minimum_zone(shape, points)
        zone = MinimumZone(
            width_mm=float(np.ptp(zr)),
            u_width_mm=_zone_uncertainty(zr, sigma, sigma_given, rms),
            geometry=_geometry(kind, zone_shape, plane),
            iterations=iterations,
            converged=converged,
        )
    return FeatureFit(
        kind=kind,
        geometry=_geometry(kind, shape, plane),
        n_points=len(points),
        rms_mm=rms,
        peak_to_valley_mm=float(np.ptp(r)),
        parameter_names=tuple(names),
        covariance=covariance,
        sigma_given=sigma_given,
        chi2_reduced=chi2,
        zone=zone,
    )


# --------------------------------------------------------------------------- fits
def fit_plane(
    points_mm: npt.ArrayLike, sigma_mm: npt.ArrayLike | None = None, *, minimum_zone: bool = True
) -> FeatureFit:
    """Least-squares plane (and minimum-zone flatness) of ``(N, 3)`` points, mm (module docstring).

    Parameters ``tilt_1_rad``, ``tilt_2_rad`` (the normal's rotation) and ``offset_mm`` (along the
    normal, at the points' weighted centroid).

    Raises
    ------
    ValueError
        Fewer than 3 points, non-finite points, or a sigma of the wrong shape or not positive.
    """
    points, sigma = _inputs(points_mm, sigma_mm, 3)
    weights = 1.0 / sigma
    plane = _plane_start(points, weights)
    fitted = _least_squares(plane, points, sigma)
    assert isinstance(fitted, _Plane)
    return _result("plane", fitted.centred(points, weights**2), points, sigma, sigma_mm is not None, minimum_zone)


def fit_sphere(
    points_mm: npt.ArrayLike, sigma_mm: npt.ArrayLike | None = None, *, minimum_zone: bool = True
) -> FeatureFit:
    """Least-squares sphere (and minimum-zone sphericity) of ``(N, 3)`` points, mm (module docstring).

    Parameters ``centre_x_mm``, ``centre_y_mm``, ``centre_z_mm``, ``radius_mm``.
    """
    points, sigma = _inputs(points_mm, sigma_mm, 4)
    centre, radius = _algebraic_ball(points, 1.0 / sigma)
    fitted = _least_squares(_Sphere(centre, radius), points, sigma)
    return _result("sphere", fitted, points, sigma, sigma_mm is not None, minimum_zone)


def fit_cylinder(
    points_mm: npt.ArrayLike,
    sigma_mm: npt.ArrayLike | None = None,
    *,
    minimum_zone: bool = True,
    axis_hint: npt.ArrayLike | None = None,
) -> FeatureFit:
    """Least-squares cylinder (and minimum-zone cylindricity) of ``(N, 3)`` points, mm.

    Starts from each principal direction of the points (or from ``axis_hint``, a 3-vector) and keeps
    the least-squares fit of least cost. Parameters ``axis_shift_1_mm``, ``axis_shift_2_mm`` (the
    axis moved across itself at ``axis_point_mm``), ``tilt_1_rad``, ``tilt_2_rad``, ``radius_mm``.
    """
    points, sigma = _inputs(points_mm, sigma_mm, 5)
    weights = 1.0 / sigma
    hint = None if axis_hint is None else np.asarray(axis_hint, dtype=np.float64).reshape(3)
    best: _Cylinder | None = None
    best_cost = math.inf
    # each start fitted on an even subsample of at most START_POINTS points; the best one on all
    sample = np.arange(0, len(points), max(1, len(points) // START_POINTS))
    for start in _cylinder_starts(points, weights, hint):
        fitted = _least_squares(start, points[sample], sigma[sample])
        assert isinstance(fitted, _Cylinder)
        cost = float(np.sum((fitted.residuals(np.zeros(5), points[sample])[0] * weights[sample]) ** 2))
        if math.isfinite(cost) and cost < best_cost:
            best, best_cost = fitted, cost
    if best is not None and len(sample) < len(points):
        polished = _least_squares(best, points, sigma)
        assert isinstance(polished, _Cylinder)
        best = polished
    if best is None:
        raise ValueError("no cylinder fits these points")
    return _result("cylinder", best.centred(points, weights**2), points, sigma, sigma_mm is not None, minimum_zone)


def fit_circle(
    points_mm: npt.ArrayLike, sigma_mm: npt.ArrayLike | None = None, *, minimum_zone: bool = True
) -> FeatureFit:
    """A circle in space: the least-squares plane of ``(N, 3)`` points, then the least-squares circle
    of the points projected on it (and the minimum-zone roundness there), mm.

    Parameters: the plane's ``tilt_1_rad``, ``tilt_2_rad``, ``offset_mm``, then ``centre_1_mm``,
    ``centre_2_mm`` (in the plane) and ``radius_mm``; the two blocks' covariances are taken as
    independent.
    """
    points, sigma = _inputs(points_mm, sigma_mm, 4)
    weights = 1.0 / sigma
    fitted = _least_squares(_plane_start(points, weights), points, sigma)
    assert isinstance(fitted, _Plane)
    plane = fitted.centred(points, weights**2)
    _, plane_covariance, _ = _covariance(plane, points, sigma, sigma_mm is not None)
    rel = points - plane.point
    flat = np.column_stack([rel @ plane.e1, rel @ plane.e2])
    centre, radius = _algebraic_ball(flat, weights)
    circle = _least_squares(_Circle2(centre, radius), flat, sigma)
    return _result(
        "circle",
        circle,
        flat,
        sigma,
        sigma_mm is not None,
        minimum_zone,
        plane=plane,
        extra_covariance=plane_covariance,
    )


FITTERS: Mapping[str, Callable[..., FeatureFit]] = {
    "plane": fit_plane,
    "sphere": fit_sphere,
    "cylinder": fit_cylinder,
    "circle": fit_circle,
}
"""The fit of each feature kind."""


def fit_feature(
    kind: str, points_mm: npt.ArrayLike, sigma_mm: npt.ArrayLike | None = None, *, minimum_zone: bool = True
) -> FeatureFit:
    """Fit feature ``kind`` (one of :data:`KINDS`) to points (see the ``fit_*`` functions)."""
    if kind not in FITTERS:
        raise ValueError(f"unknown feature {kind!r}; expected one of {', '.join(KINDS)}")
    return FITTERS[kind](points_mm, sigma_mm, minimum_zone=minimum_zone)


# --------------------------------------------------------------------------- nominal
def feature_residuals(fit: FeatureFit, points_mm: npt.ArrayLike) -> FloatArray:
    """Geometric residuals (mm, positive outside) of ``(N, 3)`` points from the fit's least-squares
    shape; for a circle, the distance in space to the circle (``sqrt(h^2 + (rho - R)^2)``, ``h``
    the height above its plane, ``rho`` the distance from its centre in the plane), unsigned."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    g = fit.geometry
    if fit.kind == "plane":
        return np.asarray((points - np.array(g["point_mm"])) @ np.array(g["normal"]), dtype=np.float64)
    if fit.kind == "sphere":
        return np.linalg.norm(points - np.array(g["centre_mm"]), axis=1) - g["radius_mm"]
    if fit.kind == "cylinder":
        d = points - np.array(g["axis_point_mm"])
        w = np.array(g["axis_direction"])
        return np.linalg.norm(d - (d @ w)[:, None] * w, axis=1) - g["radius_mm"]
    d = points - np.array(g["centre_mm"])
    n = np.array(g["normal"])
    h = d @ n
    rho = np.linalg.norm(d - h[:, None] * n, axis=1)
    return np.asarray(np.hypot(h, rho - g["radius_mm"]), dtype=np.float64)


@dataclass(frozen=True)
class ComparedQuantity:
    """One value of a feature measured and on the nominal: ``difference = measured - nominal``.

    ``u_measured`` is the measured value's standard uncertainty (NaN where the fit does not give it).
    """

    name: str
    measured: float
    nominal: float
    difference: float
    u_measured: float

    def to_dict(self) -> dict[str, Any]:
        """The fields by name (JSON types)."""
        return asdict(self)


@dataclass(frozen=True, eq=False)
class NominalComparison:
    """A measured feature beside the same feature fitted to the nominal mesh (:func:`compare_with_nominal`).

    Attributes
    ----------
    kind : str
    nominal : FeatureFit
        The feature fitted to the nominal's vertices near the measured one (least squares).
    vertices_used : int
    quantities : tuple of ComparedQuantity
        plane: ``offset_mm`` (the measured plane's point from the nominal plane, along its normal)
        and ``tilt_deg``; sphere: ``radius_mm``, ``centre_offset_mm``; cylinder: ``radius_mm``,
        ``axis_offset_mm``, ``tilt_deg``; circle: ``radius_mm``, ``centre_offset_mm``, ``tilt_deg``;
        plus the form error (nominal: that of the nominal's vertices, 0 for an exact model).
    """

    kind: str
    nominal: FeatureFit
    vertices_used: int
    quantities: tuple[ComparedQuantity, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "nominal": self.nominal.to_dict(),
            "vertices_used": self.vertices_used,
            "quantities": [q.to_dict() for q in self.quantities],
        }

    def quantity(self, name: str) -> ComparedQuantity:
        """The compared quantity called ``name``."""
        for q in self.quantities:
            if q.name == name:
                return q
        raise KeyError(name)


def _angle_deg(a: FloatArray, b: FloatArray, oriented: bool) -> float:
    cosine = float(a @ b) / float(np.linalg.norm(a) * np.linalg.norm(b))
    if not oriented:
        cosine = abs(cosine)
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


def _quantity(name: str, measured: float, nominal: float, u: float = math.nan) -> ComparedQuantity:
    return ComparedQuantity(name, float(measured), float(nominal), float(measured - nominal), float(u))


def compare_with_nominal(
    fit: FeatureFit,
    vertices_mm: npt.ArrayLike,
    faces: npt.ArrayLike,
    *,
    band_mm: float = 1.0,
) -> NominalComparison:
    """Fit the same feature to the nominal mesh's vertices within ``band_mm`` of the measured one
    and compare (``measured - nominal``).

    The nominal mesh is in the same frame as the measured points (after alignment). Its vertices
    (those used by a face) within ``band_mm`` of the measured feature's least-squares shape
    (:func:`feature_residuals`) are fitted by least squares: a tessellated sphere or cylinder has
    its vertices exactly on the surface, so the fit recovers the nominal's radius.

    Parameters
    ----------
    fit : FeatureFit
        The measured feature.
    vertices_mm : (V, 3) array_like of float
    faces : (F, 3) array_like of int
    band_mm : float
        Half-width of the band around the measured feature that selects the nominal's vertices, mm.

    Raises
    ------
    ValueError
        If too few vertices lie in the band.
    """
    vertices = np.asarray(vertices_mm, dtype=np.float64)
    used = np.unique(np.asarray(faces, dtype=np.int64).ravel())
    if used.size and (used.min() < 0 or used.max() >= len(vertices)):
        raise ValueError("faces index vertices that do not exist")
    candidates = vertices[used]
    near = candidates[np.abs(feature_residuals(fit, candidates)) <= band_mm]
    minimum = {"plane": 3, "sphere": 4, "cylinder": 5, "circle": 4}[fit.kind]
    if len(near) < minimum:
        raise ValueError(f"only {len(near)} nominal vertices lie within {band_mm:g} mm of the measured {fit.kind}")
    if fit.kind == "cylinder":
        nominal = fit_cylinder(near, minimum_zone=False, axis_hint=fit.geometry["axis_direction"])
    else:
        nominal = fit_feature(fit.kind, near, minimum_zone=False)
    return NominalComparison(fit.kind, nominal, len(near), _compared(fit, nominal))


def _compared(fit: FeatureFit, nominal: FeatureFit) -> tuple[ComparedQuantity, ...]:
    g, h, std = fit.geometry, nominal.geometry, fit.std
    quantities = []
    if fit.kind == "plane":
        n = np.array(h["normal"])
        offset = float((np.array(g["point_mm"]) - np.array(h["point_mm"])) @ n)
        quantities.append(_quantity("offset_mm", offset, 0.0, std["offset_mm"]))
        quantities.append(_quantity("tilt_deg", _angle_deg(np.array(g["normal"]), n, oriented=False), 0.0))
    else:
        quantities.append(_quantity("radius_mm", g["radius_mm"], h["radius_mm"], std["radius_mm"]))
    if fit.kind in ("sphere", "circle"):
        offset = float(np.linalg.norm(np.array(g["centre_mm"]) - np.array(h["centre_mm"])))
        quantities.append(_quantity("centre_offset_mm", offset, 0.0))
    if fit.kind == "cylinder":
        d = np.array(g["axis_point_mm"]) - np.array(h["axis_point_mm"])
        w = np.array(h["axis_direction"])
        quantities.append(_quantity("axis_offset_mm", float(np.linalg.norm(d - (d @ w) * w)), 0.0))
        quantities.append(_quantity("tilt_deg", _angle_deg(np.array(g["axis_direction"]), w, oriented=False), 0.0))
    if fit.kind == "circle":
        quantities.append(
            _quantity("tilt_deg", _angle_deg(np.array(g["normal"]), np.array(h["normal"]), oriented=False), 0.0)
        )
    u_form = fit.zone.u_width_mm if fit.zone is not None else math.nan
    quantities.append(_quantity(f"{fit.form_name}_mm", fit.form_mm, nominal.peak_to_valley_mm, u_form))
    return tuple(quantities)
