"""Features of an inspection: regions of the aligned scan, their fits and the nominal's values.

A feature to inspect (:class:`FeatureSpec`) names a kind (plane, sphere, cylinder, circle:
:data:`~metrology.core.inspection.features.KINDS`) and a :class:`Region` that selects points of
the scan *after alignment*, in the nominal's frame (mm). A region is the intersection of the
selectors it gives (at least one):

- ``box_mm``: ``[[x0, y0, z0], [x1, y1, z1]]``, the points with ``x0 <= x <= x1`` (and so on);
- ``near_faces``: face indices of the nominal (its faces as validated: degenerate faces dropped,
  :class:`~metrology.core.inspection.nominal.NominalModel`), the points whose closest point of the
  nominal lies on one of them;
- ``within_mm``: the points with ``|deviation| <= within_mm``.

Each region's points are fitted by least squares and minimum zone
(:func:`~metrology.core.inspection.features.fit_feature`), weighted by each point's standard
uncertainty along the nominal's normal when every selected point has one, and compared with the
same feature fitted to the nominal mesh's vertices within ``band_mm`` of it
(:func:`~metrology.core.inspection.features.compare_with_nominal`): ``difference = measured -
nominal``. :func:`measure_features` returns one JSON-ready entry per feature (the ``features``
of the ``gcps-inspection/1`` report, docs/inspection.md); a feature whose region holds too few
points, or that cannot be fitted, gets an ``error`` sentence instead of numbers (the inspection
itself stands).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.inspection.features import KINDS, compare_with_nominal, fit_feature

REGION_KEYS = ("box_mm", "near_faces", "within_mm")
"""The selectors of a :class:`Region`."""
DEFAULT_BAND_MM = 1.0
"""Default half-width of the band around a measured feature that selects the nominal's vertices, mm."""
MINIMUM_POINTS: Mapping[str, int] = {"plane": 3, "sphere": 4, "cylinder": 5, "circle": 4}
"""Fewest points each kind of feature is fitted to."""


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


@dataclass(frozen=True)
class Region:
    """Points of the aligned scan selected by box, nominal faces and distance (module docstring).

    Attributes
    ----------
    box_mm : ((x0, y0, z0), (x1, y1, z1)) or None
        Lower and upper corners of an axis-aligned box in the nominal's frame, mm (``x0 <= x1`` ...).
    near_faces : tuple of int
        Nominal face indices (empty: not used).
    within_mm : float or None
        Largest ``|deviation|``, mm.
    """

    box_mm: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    near_faces: tuple[int, ...] = ()
    within_mm: float | None = None

    def __post_init__(self) -> None:
        if self.box_mm is None and not self.near_faces and self.within_mm is None:
            raise ValueError(f"a region needs at least one of {', '.join(REGION_KEYS)}")
        if self.box_mm is not None:
            box = np.asarray(self.box_mm, dtype=np.float64) if _box_like(self.box_mm) else None
            if box is None or box.shape != (2, 3) or not np.isfinite(box).all() or (box[0] > box[1]).any():
                raise ValueError(
                    "box_mm must be [[x0, y0, z0], [x1, y1, z1]] with x0 <= x1, y0 <= y1, z0 <= z1, "
                    f"got {self.box_mm!r}"
                )
            object.__setattr__(self, "box_mm", (tuple(box[0].tolist()), tuple(box[1].tolist())))
        faces = self.near_faces
        if not isinstance(faces, (list, tuple)) or not all(
            isinstance(f, (int, np.integer)) and not isinstance(f, bool) and f >= 0 for f in faces
        ):
            raise ValueError(f"near_faces must be a list of face indices (integers >= 0), got {faces!r}")
        object.__setattr__(self, "near_faces", tuple(int(f) for f in faces))
        if self.within_mm is not None and not (_finite(self.within_mm) and self.within_mm > 0):
            raise ValueError(f"within_mm must be a positive number, got {self.within_mm!r}")

    def mask(self, points_mm: np.ndarray, distance_mm: np.ndarray, face: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: the points the region selects.

        Parameters
        ----------
        points_mm : (N, 3) float64
            Aligned points, nominal frame, mm.
        distance_mm : (N,) float64
            Their signed deviations, mm.
        face : (N,) int64
            The nominal face holding each point's closest point.
        """
        keep = np.isfinite(points_mm).all(axis=1) & np.isfinite(distance_mm)
        if self.box_mm is not None:
            low, high = (np.asarray(corner) for corner in self.box_mm)
            keep &= ((points_mm >= low) & (points_mm <= high)).all(axis=1)
        if self.near_faces:
            keep &= np.isin(face, np.asarray(self.near_faces, dtype=np.int64))
        if self.within_mm is not None:
            keep &= np.abs(distance_mm) <= self.within_mm
        return np.asarray(keep, dtype=bool)

    def to_dict(self) -> dict[str, Any]:
        """The selectors given (JSON types)."""
        out: dict[str, Any] = {}
        if self.box_mm is not None:
            out["box_mm"] = [list(corner) for corner in self.box_mm]
        if self.near_faces:
            out["near_faces"] = list(self.near_faces)
        if self.within_mm is not None:
            out["within_mm"] = self.within_mm
        return out

    @classmethod
    def from_dict(cls, data: Any) -> Region:
        if not isinstance(data, Mapping):
            raise ValueError(f"region must be an object with {', '.join(REGION_KEYS)}, got {data!r}")
        unknown = set(data) - set(REGION_KEYS)
        if unknown:
            raise ValueError(f"region: unknown keys {', '.join(sorted(unknown))}; expected {', '.join(REGION_KEYS)}")
        return cls(
            box_mm=data.get("box_mm"),
            near_faces=data.get("near_faces") or (),
            within_mm=data.get("within_mm"),
        )


def _box_like(value: Any) -> bool:
    return isinstance(value, (list, tuple)) and all(
        isinstance(row, (list, tuple)) and all(_finite(v) for v in row) for row in value
    )


@dataclass(frozen=True)
class FeatureSpec:
    """A feature to inspect: ``name``, ``kind`` (one of :data:`KINDS`), ``region`` and the
    ``band_mm`` that picks the nominal's vertices for its nominal value (module docstring).

    JSON form: ``{"name": str, "kind": str, "region": {...}, "band_mm": float}`` (``band_mm``
    optional, default :data:`DEFAULT_BAND_MM`).
    """

    name: str
    kind: str
    region: Region
    band_mm: float = DEFAULT_BAND_MM

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip() or len(self.name) > 100:
            raise ValueError(f"a feature's name must be a non-empty string of at most 100 characters: {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"feature {self.name!r}: kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if not (_finite(self.band_mm) and self.band_mm > 0):
            raise ValueError(f"feature {self.name!r}: band_mm must be a positive number, got {self.band_mm!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "region": self.region.to_dict(), "band_mm": self.band_mm}

    @classmethod
    def from_dict(cls, data: Any) -> FeatureSpec:
        if not isinstance(data, Mapping) or not {"name", "kind", "region"} <= set(data):
            raise ValueError(f'a feature must be {{"name": ..., "kind": ..., "region": {{...}}}}, got {data!r}')
        unknown = set(data) - {"name", "kind", "region", "band_mm"}
        if unknown:
            raise ValueError(f"feature {data.get('name')!r}: unknown keys {', '.join(sorted(unknown))}")
        try:
            region = Region.from_dict(data["region"])
        except ValueError as exc:
            raise ValueError(f"feature {data.get('name')!r}: {exc}") from None
        return cls(name=data["name"], kind=data["kind"], region=region, band_mm=data.get("band_mm", DEFAULT_BAND_MM))


def parse_features(data: Any) -> tuple[FeatureSpec, ...]:
    """Features from their JSON form, a list of :class:`FeatureSpec` objects; ValueError naming what
    is wrong (also for two features of the same name)."""
    if not isinstance(data, (list, tuple)):
        raise ValueError('features must be a JSON list of {"name", "kind", "region"} objects')
    specs = tuple(item if isinstance(item, FeatureSpec) else FeatureSpec.from_dict(item) for item in data)
    names = [spec.name for spec in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"feature names must differ, got {names}")
    return specs


def measure_features(
    specs: Sequence[FeatureSpec],
    points_mm: npt.ArrayLike,
    distance_mm: npt.ArrayLike,
    face: npt.ArrayLike,
    vertices_mm: npt.ArrayLike,
    faces: npt.ArrayLike,
    sigma_mm: npt.ArrayLike | None = None,
) -> list[dict[str, Any]]:
    """Each feature's region, fit and comparison with the nominal (module docstring).

    Parameters
    ----------
    specs : sequence of FeatureSpec
    points_mm : (N, 3) float64
        The aligned scan, nominal frame, mm.
    distance_mm : (N,) float64
        Each point's signed deviation, mm.
    face : (N,) int
        The nominal face nearest each point.
    vertices_mm, faces : the nominal mesh, ``(V, 3)`` mm and ``(F, 3)`` indices.
    sigma_mm : (N,) float64, optional
        Each point's standard uncertainty along the normal, mm (NaN: unknown).

    Returns
    -------
    list of dict
        Per feature: ``name``, ``kind``, ``region``, ``points``, ``geometry`` (least squares),
        ``std`` (by parameter), ``rms_mm``, ``form`` ``{name, value_mm, u_mm, method}``,
        ``form_mm``, ``sigma_given``, ``nominal`` ``{geometry, vertices_used, form_mm}``,
        ``quantities`` (``[{name, measured, nominal, difference, u_measured}]``), ``difference``
        (``{quantity: measured - nominal}``) and ``error`` (None, or why there are no numbers).
        A number the fit does not give (``u_measured`` of a tilt) is None.
    """
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    distance = np.asarray(distance_mm, dtype=np.float64).reshape(-1)
    nearest = np.asarray(face, dtype=np.int64).reshape(-1)
    sigma = None if sigma_mm is None else np.asarray(sigma_mm, dtype=np.float64).reshape(-1)
    return [_measure(spec, points, distance, nearest, vertices_mm, faces, sigma) for spec in specs]


def _measure(
    spec: FeatureSpec,
    points: np.ndarray,
    distance: np.ndarray,
    face: np.ndarray,
    vertices_mm: npt.ArrayLike,
    faces: npt.ArrayLike,
    sigma: np.ndarray | None,
) -> dict[str, Any]:
    selected = spec.region.mask(points, distance, face)
    count = int(np.count_nonzero(selected))
    entry: dict[str, Any] = {
        "name": spec.name,
        "kind": spec.kind,
        "region": spec.region.to_dict(),
        "points": count,
        "geometry": None,
        "std": None,
        "rms_mm": None,
        "form": None,
        "form_mm": None,
        "sigma_given": False,
        "nominal": None,
        "quantities": [],
        "difference": {},
        "error": None,
    }
    if count < MINIMUM_POINTS[spec.kind]:
        entry["error"] = f"the region holds {count} points; a {spec.kind} needs at least {MINIMUM_POINTS[spec.kind]}"
        return entry
    chosen = points[selected]
    weights = None if sigma is None else sigma[selected]
    if weights is not None and not (np.isfinite(weights) & (weights > 0)).all():
        weights = None  # some point without a usable sigma: unweighted, the residuals scale the covariance
    try:
        fit = fit_feature(spec.kind, chosen, weights)
        compared = compare_with_nominal(fit, vertices_mm, faces, band_mm=spec.band_mm)
    except (ValueError, np.linalg.LinAlgError) as exc:
        entry["error"] = f"no {spec.kind} fits the region: {exc}"
        return entry
    fit_dict = fit.to_dict()
    form = fit_dict["form"]
    entry.update(
        geometry=fit_dict["geometry"],
        std=fit_dict["std"],
        rms_mm=fit.rms_mm,
        form={**form, "u_mm": None if fit.zone is None else fit.zone.u_width_mm},
        form_mm=fit.form_mm,
        sigma_given=fit.sigma_given,
        nominal={
            "geometry": dict(compared.nominal.geometry),
            "vertices_used": compared.vertices_used,
            "form_mm": compared.nominal.peak_to_valley_mm,
        },
        quantities=[q.to_dict() for q in compared.quantities],
        difference={q.name: q.difference for q in compared.quantities},
    )
    return _finite_or_none(entry)


def _finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float (an uncertainty the fit does not give) as None: JSON as it is."""
    if isinstance(value, dict):
        return {key: _finite_or_none(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_finite_or_none(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


__all__ = [
    "DEFAULT_BAND_MM",
    "FeatureSpec",
    "Region",
    "measure_features",
    "parse_features",
]
