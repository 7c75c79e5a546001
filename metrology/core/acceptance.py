"""Acceptance quantities after VDI/VDE 2634 part 2 (beyond the paper).

All inputs are ``(N, 3)`` float arrays of measured points ``(X, Y, Z)`` in mm, e.g.
the valid pixels of a measurement's points (:meth:`metrology.core.measure.Measurement.points_mm`,
or :func:`points_from_height_map` of a height map).

- **Flatness measurement error F**: range (max - min) of the signed distances of
  the points from their least-squares plane. The plane is the total-least-squares
  fit: through the centroid, normal = right singular vector of the centred points
  with the smallest singular value (minimises the sum of squared orthogonal
  distances).
- **Probing error form P_F**: range of the radial residuals ``|p - c| - r`` about
  the least-squares sphere (centre and radius free).
- **Probing error size P_S**: fitted diameter minus the known (calibrated) diameter.
- **Sphere-spacing error SD**: distance between the fitted centres of two spheres
  minus the known spacing.

Per-point uncertainty (issue 12): every fit and figure takes an optional ``sigma`` (``(N,)``
standard uncertainty of each point, mm, e.g. the valid pixels of ``gcps measure --sigma``). The
fits then weight each point by ``w = 1 / sigma^2`` (weighted total least squares for the plane:
the weighted centroid and the smallest right singular vector of ``sqrt(w) (p - c)``; for the
sphere the weighted algebraic fit and the geometric residuals scaled by ``sqrt(w)``), and
``max_sigma`` drops the points whose sigma exceeds it (or is not finite) before fitting.

The standard lets up to 0.3 % of the points be discarded as outliers; every
quantity is reported with and without that rejection (``reject_frac``): the
``floor(reject_frac * N)`` points with the largest absolute residuals are removed
and the fit repeated once.

Sphere fit: first the algebraic (linear) least-squares fit, which solves
``|p|^2 = 2 c . p + (r^2 - |c|^2)`` for ``c`` and ``r^2 - |c|^2`` in one linear
solve (Kasa fit; biased for partial caps and noisy data), then a geometric
refinement minimising ``sum (|p_i - c| - r)^2`` with
``scipy.optimize.least_squares`` (Levenberg-Marquardt) from that start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:  # pragma: no cover
    from metrology.core.geometry.base import GeometryModel, ReferenceSurface


VDI_REJECT_FRAC = 0.003
"""Share of points VDI/VDE 2634-2 allows to discard as outliers."""


@dataclass(frozen=True)
class PlaneFit:
    """Least-squares plane: ``normal . (p - centroid) = distance`` (normal has +Z)."""

    centroid: np.ndarray
    normal: np.ndarray
    distances: np.ndarray


@dataclass(frozen=True)
class SphereFit:
    """Least-squares sphere: ``radii = |p - center| - radius``."""

    center: np.ndarray
    radius: float
    residuals: np.ndarray
    algebraic_center: np.ndarray
    algebraic_radius: float


def points_from_height_map(
    model: GeometryModel,
    z_mm: npt.ArrayLike,
    mask: npt.ArrayLike | None = None,
    reference: ReferenceSurface | None = None,
) -> np.ndarray:
    """The valid pixels of a height map as 3D points in the model's frame (docs/conventions.md).

    Parameters
    ----------
    model : GeometryModel
        Any geometric model (:meth:`~metrology.core.geometry.base.PreparedGeometry.points_from_heights`
        places each height on its camera ray).
    z_mm : (height_px, width_px) float array
        Height map, mm, NaN where invalid: heights above ``reference``, or what the model gives
        without one (the paper's heights above R; a pinhole rig's depths).
    mask : (height_px, width_px) bool array, optional
        Pixels to keep (e.g. a sphere's region).
    reference : ReferenceSurface, optional
        The reference the heights are measured from (a measurement's ``reference.surface``).

    Returns
    -------
    points : (N, 3) float64 array, mm: the paper's ``(X_H, Y_H, z)`` on a crossed-axes rig.
    """
    z = np.asarray(z_mm, dtype=np.float64)
    if z.shape != model.shape:
        raise ValueError(f"z_mm must have the rig's shape {model.shape}, got {z.shape}")
    xyz = model.prepare().points_from_heights(z, reference).astype(np.float64, copy=False)
    keep = np.isfinite(xyz).all(axis=-1)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != model.shape:
            raise ValueError(f"mask must have the rig's shape {model.shape}, got {m.shape}")
        keep &= m
    return xyz[keep]


def _check_points(points: npt.ArrayLike, name: str = "points", minimum: int = 4) -> np.ndarray:
    p, _ = _checked(points, None, None, name, minimum)
    return p


def _checked(
    points: npt.ArrayLike,
    sigma: npt.ArrayLike | None,
    max_sigma: float | None,
    name: str = "points",
    minimum: int = 4,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The finite points (and, with ``sigma``, those with a finite sigma <= ``max_sigma``) and their
    weights ``1 / sigma^2`` (None without ``sigma``)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must be an (N, 3) array of X, Y, Z in mm, got shape {p.shape}")
    keep = np.isfinite(p).all(axis=1)
    weights = None
    if max_sigma is not None:
        if sigma is None:
            raise ValueError("max_sigma needs a per-point sigma")
        if not (isinstance(max_sigma, (int, float, np.floating, np.integer)) and max_sigma > 0):
            raise ValueError(f"max_sigma must be a positive number of mm, got {max_sigma!r}")
    if sigma is not None:
        s = np.asarray(sigma, dtype=np.float64)
        if s.shape != (len(p),):
            raise ValueError(f"sigma must have one value per point, shape ({len(p)},), got {s.shape}")
        if (s[np.isfinite(s)] <= 0).any():
            raise ValueError("sigma must be positive where finite (a standard uncertainty in mm)")
        keep &= np.isfinite(s)
        if max_sigma is not None:
            keep &= s <= max_sigma
        weights = 1.0 / s[keep] ** 2
    p = p[keep]
    if len(p) < minimum:
        raise ValueError(f"{name} needs at least {minimum} finite points, got {len(p)}")
    return p, weights


def _check_frac(reject_frac: float) -> None:
    if not (0.0 <= reject_frac < 0.5):
        raise ValueError(f"reject_frac must lie in [0, 0.5), got {reject_frac!r}")


def fit_plane(points: npt.ArrayLike, sigma: npt.ArrayLike | None = None, max_sigma: float | None = None) -> PlaneFit:
    """Total-least-squares plane through ``(N, 3)`` points (N >= 3), signed distances in mm.

    With ``sigma`` (``(N,)`` mm) the fit is weighted by ``1 / sigma^2`` (weighted centroid, SVD of
    the weighted centred points); ``max_sigma`` (mm) drops the points above it. ``distances``
    are those of the points kept (finite, and within ``max_sigma``), in their order.
    """
    p, w = _checked(points, sigma, max_sigma, minimum=3)
    return _plane(p, w)


def _plane(p: np.ndarray, w: np.ndarray | None) -> PlaneFit:
    if w is None:
        centroid = p.mean(axis=0)
        centred = p - centroid
    else:
        centroid = (w[:, None] * p).sum(axis=0) / w.sum()
        centred = (p - centroid) * np.sqrt(w / w.mean())[:, None]
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    normal = vt[-1]
    if normal[2] < 0:
        normal = -normal
    return PlaneFit(centroid=centroid, normal=normal, distances=(p - centroid) @ normal)


def fit_sphere(points: npt.ArrayLike, sigma: npt.ArrayLike | None = None, max_sigma: float | None = None) -> SphereFit:
    """Least-squares sphere through ``(N, 3)`` points (N >= 4): algebraic start, geometric refinement.

    With ``sigma`` (``(N,)`` mm) both steps are weighted by ``1 / sigma^2``; ``max_sigma`` (mm)
    drops the points above it. ``residuals`` are those of the points kept, in their order.

    Raises
    ------
    ValueError
        If the points are degenerate (e.g. coplanar).
    """
    p, w = _checked(points, sigma, max_sigma, minimum=4)
    return _sphere(p, w)


def _sphere(p: np.ndarray, w: np.ndarray | None) -> SphereFit:
    root_w = np.ones(len(p)) if w is None else np.sqrt(w / w.mean())
    shift = p.mean(axis=0) if w is None else (w[:, None] * p).sum(axis=0) / w.sum()
    q = p - shift  # conditioning
    a = np.column_stack([2 * q, np.ones(len(q))])
    b = (q**2).sum(axis=1)
    sol, _, rank, _ = np.linalg.lstsq(a * root_w[:, None], b * root_w, rcond=None)
    if rank < 4:
        raise ValueError("points are degenerate (coplanar or collinear): no sphere fits them")
    c0 = sol[:3]
    r0 = math.sqrt(max(sol[3] + c0 @ c0, 0.0))

    def radial(x: np.ndarray) -> np.ndarray:
        return root_w * (np.linalg.norm(q - x[:3], axis=1) - x[3])

    def jac(x: np.ndarray) -> np.ndarray:
        diff = q - x[:3]
        dist = np.linalg.norm(diff, axis=1)
        return root_w[:, None] * np.column_stack([-diff / dist[:, None], -np.ones(len(q))])

    # SciPy's optimiser is imported here, not with the module: the web server's URLconf imports this
    # module (the acceptance API) and would pay about 0.5 s of CPU at every start for it
    from scipy import optimize

    res = optimize.least_squares(radial, np.r_[c0, r0], jac=jac, method="lm", xtol=1e-12, ftol=1e-12)
    center = res.x[:3] + shift
    radius = float(abs(res.x[3]))
    return SphereFit(
        center=center,
        radius=radius,
        residuals=np.linalg.norm(p - center, axis=1) - radius,
        algebraic_center=c0 + shift,
        algebraic_radius=r0,
    )


def _reject(
    points: np.ndarray, residuals: np.ndarray, reject_frac: float, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None, int]:
    n_out = math.floor(reject_frac * len(points))
    if n_out == 0:
        return points, weights, 0
    keep = np.argsort(np.abs(residuals))[: len(points) - n_out]
    return points[keep], None if weights is None else weights[keep], n_out


def _sigma_report(sigma: npt.ArrayLike | None, max_sigma: float | None, n_input: int, n_kept: int) -> dict[str, Any]:
    if sigma is None:
        return {}
    return {"weighted": True, "max_sigma_mm": max_sigma, "n_dropped_sigma": n_input - n_kept}


def _finite_count(points: npt.ArrayLike) -> int:
    p = np.asarray(points, dtype=np.float64)
    return int(np.isfinite(p).all(axis=1).sum()) if p.ndim == 2 and p.shape[1] == 3 else 0


def flatness_error(
    points: npt.ArrayLike,
    reject_frac: float = VDI_REJECT_FRAC,
    *,
    sigma: npt.ArrayLike | None = None,
    max_sigma: float | None = None,
) -> dict[str, Any]:
    """Flatness measurement error F of a plane (VDI/VDE 2634-2).

    Parameters
    ----------
    points : (N, 3) float array, mm
        Points measured on a flat standard.
    reject_frac : float
        Share of points with the largest absolute distances discarded for the
        second figure (standard: 0.003).
    sigma : (N,) float array, optional
        Standard uncertainty of each point, mm: the plane is fitted with weights ``1 / sigma^2``.
    max_sigma : float, optional
        Drop the points whose sigma exceeds this (mm) before fitting (needs ``sigma``).

    Returns
    -------
    dict
        ``flatness_mm`` (range of signed distances, all points), ``flatness_rejected_mm``
        (after rejection), ``rms_mm``, ``n_points``, ``n_rejected``, ``normal``,
        ``centroid_mm``; with ``sigma`` also ``weighted`` (True), ``max_sigma_mm`` and
        ``n_dropped_sigma`` (finite points dropped by ``max_sigma`` or a non-finite sigma).
    """
    _check_frac(reject_frac)
    p, w = _checked(points, sigma, max_sigma, minimum=3)
    fit = _plane(p, w)
    kept, kept_w, n_out = _reject(p, fit.distances, reject_frac, w)
    fit2 = _plane(kept, kept_w) if n_out else fit
    return {
        "flatness_mm": float(np.ptp(fit.distances)),
        "flatness_rejected_mm": float(np.ptp(fit2.distances)),
        "rms_mm": float(np.sqrt(np.mean(fit.distances**2))),
        "n_points": len(p),
        "n_rejected": n_out,
        "normal": fit.normal.tolist(),
        "centroid_mm": fit.centroid.tolist(),
        "fit": "total least-squares plane (SVD)" + (", weighted 1/sigma^2" if w is not None else ""),
        **_sigma_report(sigma, max_sigma, _finite_count(points), len(p)),
    }


def probing_error(
    points: npt.ArrayLike,
    diameter_mm: float,
    reject_frac: float = VDI_REJECT_FRAC,
    *,
    sigma: npt.ArrayLike | None = None,
    max_sigma: float | None = None,
) -> dict[str, Any]:
    """Probing errors form P_F and size P_S on a sphere of known diameter (VDI/VDE 2634-2).

    Parameters
    ----------
    points : (N, 3) float array, mm
        Points measured on the sphere (N >= 4, not coplanar).
    diameter_mm : float
        Calibrated diameter of the sphere, mm, > 0.
    reject_frac : float
        Share of points discarded for the ``*_rejected`` figures.
    sigma : (N,) float array, optional
        Standard uncertainty of each point, mm: the sphere is fitted with weights ``1 / sigma^2``.
    max_sigma : float, optional
        Drop the points whose sigma exceeds this (mm) before fitting (needs ``sigma``).

    Returns
    -------
    dict
        ``form_error_mm`` (range of radial residuals), ``size_error_mm`` (fitted minus
        known diameter), ``diameter_mm``, ``center_mm``, ``rms_mm``, the same three
        after rejection (``form_error_rejected_mm``, ``size_error_rejected_mm``,
        ``diameter_rejected_mm``), ``n_points``, ``n_rejected``; with ``sigma`` also
        ``weighted``, ``max_sigma_mm`` and ``n_dropped_sigma``.
    """
    if not (diameter_mm > 0):
        raise ValueError(f"diameter_mm must be positive, got {diameter_mm!r}")
    _check_frac(reject_frac)
    p, w = _checked(points, sigma, max_sigma)
    fit = _sphere(p, w)
    kept, kept_w, n_out = _reject(p, fit.residuals, reject_frac, w)
    fit2 = _sphere(kept, kept_w) if n_out else fit
    return {
        "form_error_mm": float(np.ptp(fit.residuals)),
        "size_error_mm": 2 * fit.radius - diameter_mm,
        "diameter_mm": 2 * fit.radius,
        "center_mm": fit.center.tolist(),
        "rms_mm": float(np.sqrt(np.mean(fit.residuals**2))),
        "form_error_rejected_mm": float(np.ptp(fit2.residuals)),
        "size_error_rejected_mm": 2 * fit2.radius - diameter_mm,
        "diameter_rejected_mm": 2 * fit2.radius,
        "n_points": len(p),
        "n_rejected": n_out,
        "fit": "algebraic linear least-squares sphere, refined geometrically (Levenberg-Marquardt)"
        + (", weighted 1/sigma^2" if w is not None else ""),
        **_sigma_report(sigma, max_sigma, _finite_count(points), len(p)),
    }


def sphere_spacing_error(
    points_a: npt.ArrayLike, points_b: npt.ArrayLike, spacing_mm: float, reject_frac: float = VDI_REJECT_FRAC
) -> dict[str, Any]:
    """Sphere-spacing error SD of a ball bar (VDI/VDE 2634-2).

    Parameters
    ----------
    points_a, points_b : (N, 3) float arrays, mm
        Points measured on each sphere.
    spacing_mm : float
        Calibrated distance between the sphere centres, mm, > 0.
    reject_frac : float
        Share of points discarded per sphere for the ``*_rejected`` figures.

    Returns
    -------
    dict
        ``spacing_mm`` (measured), ``spacing_error_mm`` (measured minus known), the
        same after rejection, ``center_a_mm``, ``center_b_mm``, ``diameter_a_mm``,
        ``diameter_b_mm``.
    """
    if not (spacing_mm > 0):
        raise ValueError(f"spacing_mm must be positive, got {spacing_mm!r}")
    _check_frac(reject_frac)
    a = _check_points(points_a, "points_a")
    b = _check_points(points_b, "points_b")
    fa, fb = fit_sphere(a), fit_sphere(b)
    ka, _, _ = _reject(a, fa.residuals, reject_frac)
    kb, _, _ = _reject(b, fb.residuals, reject_frac)
    fa2, fb2 = fit_sphere(ka), fit_sphere(kb)
    spacing = float(np.linalg.norm(fa.center - fb.center))
    spacing2 = float(np.linalg.norm(fa2.center - fb2.center))
    return {
        "spacing_mm": spacing,
        "spacing_error_mm": spacing - spacing_mm,
        "spacing_rejected_mm": spacing2,
        "spacing_error_rejected_mm": spacing2 - spacing_mm,
        "center_a_mm": fa.center.tolist(),
        "center_b_mm": fb.center.tolist(),
        "diameter_a_mm": 2 * fa.radius,
        "diameter_b_mm": 2 * fb.radius,
        "fit": "least-squares spheres (algebraic start, geometric refinement); distance of centres",
    }


def segment_objects(z_mm: npt.ArrayLike, count: int, min_height_mm: float = 1.0) -> list[np.ndarray]:
    """The ``count`` largest regions standing above the reference plane (e.g. the spheres).

    Parameters
    ----------
    z_mm : (H, W) float array
        Height map, mm, NaN where not measured.
    count : int
        How many regions to return, largest first, >= 1.
    min_height_mm : float
        Pixels higher than this above R belong to an object, mm.

    Returns
    -------
    masks : list of ``count`` (H, W) bool arrays, largest region first.

    Raises
    ------
    ValueError
        If fewer than ``count`` regions of at least 100 pixels stand above ``min_height_mm``.
    """
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    z = np.asarray(z_mm, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        above = (z > min_height_mm).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(above, connectivity=4)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = np.argsort(areas)[::-1]
    big = [int(i) + 1 for i in order if areas[i] >= 100]
    if len(big) < count:
        raise ValueError(
            f"found {len(big)} region(s) of 100 pixels or more higher than {min_height_mm} mm above the "
            f"reference plane; {count} needed"
        )
    return [labels == label for label in big[:count]]
