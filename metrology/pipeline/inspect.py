"""Inspect: a scan against its nominal model, to the aligned transform, each point's signed
deviation and uncertainty, and a conformance decision (the ``gcps inspect`` command,
docs/inspection.md).

Steps (:mod:`metrology.core.inspection`): a start (``auto``: global registration, seeded;
``identity``; point pairs), the weighted trimmed point-to-plane best fit on up to
``fit_points`` of the scan's points (chosen with the seed), then every point's signed distance
(trimming affects the fit only), its uncertainty along the normal and, with a tolerance, the
decision.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metrology.core.inspection import alignment, conformance
from metrology.core.inspection.distance import Deviations, SurfaceDistance
from metrology.core.inspection.feature_regions import FeatureSpec, measure_features, parse_features
from metrology.core.inspection.nominal import NominalModel
from metrology.core.inspection.scan import Scan
from metrology.core.option_checks import check_int, check_keys, check_number, check_positive
from metrology.pipeline.common import PhaseTimer
from metrology.version import software_version

__all__ = ["INITS", "REPORT_FORMAT", "InspectOptions", "InspectionResult", "inspect"]

REPORT_FORMAT = "gcps-inspection/1"
INITS = ("auto", "identity", "pairs")

Pair = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True)
class InspectOptions:
    """Options of :func:`inspect` (and of ``gcps inspect``).

    Attributes
    ----------
    init : str
        ``auto`` (global registration), ``identity`` (already roughly aligned) or ``pairs``.
    pairs : tuple of ((x, y, z) scan, (x, y, z) nominal)
        At least three point pairs, mm, for ``init="pairs"`` (empty otherwise).
    tolerance_mm : float or None
        Allowed ``|deviation|``, mm; None: no conformance decision.
    k : float
        Coverage factor of the decision (default 2).
    systematic_mm : float
        The rig's systematic standard uncertainty, mm, added to every point's (default 0).
    seed : int
        Seed of the global registration and of the choice of the fit's points.
    restarts : int
        Global registration restarts.
    fit_points : int
        At most this many scan points take part in the best fit.
    trim_k : float
        Robust trimming: residuals beyond ``trim_k`` MADs (x 1.4826) of the median leave the fit.
    max_iterations : int
        Of the best fit.
    features : tuple of FeatureSpec
        Features fitted on regions of the aligned scan and compared with the nominal
        (:mod:`metrology.core.inspection.feature_regions`); empty: none.

    JSON form (:meth:`to_dict`): the attributes by name, ``pairs`` as a list of
    ``{"scan": [x, y, z], "nominal": [x, y, z]}``, ``features`` as a list of
    ``{"name", "kind", "region", "band_mm"}``. :meth:`from_dict` reads any subset.
    """

    init: str = "auto"
    pairs: tuple[Pair, ...] = ()
    tolerance_mm: float | None = None
    k: float = 2.0
    systematic_mm: float = 0.0
    seed: int = 0
    restarts: int = 3
    fit_points: int = 100_000
    trim_k: float = alignment.TRIM_K
    max_iterations: int = alignment.MAX_ITERATIONS
    features: tuple[FeatureSpec, ...] = ()

    def __post_init__(self) -> None:
        if self.init not in INITS:
            raise ValueError(f"init must be one of {', '.join(INITS)}, got {self.init!r}")
        if self.init == "pairs" and len(self.pairs) < 3:
            raise ValueError(f"init pairs needs at least 3 point pairs, got {len(self.pairs)}")
        if self.init != "pairs" and self.pairs:
            raise ValueError(f"pairs are given only with init 'pairs', not {self.init!r}")
        for pair in self.pairs:
            values = np.asarray(pair, dtype=np.float64)
            if values.shape != (2, 3) or not np.isfinite(values).all():
                raise ValueError(f"a point pair must be two finite (x, y, z), got {pair!r}")
        check_positive("tolerance_mm", self.tolerance_mm, allow_none=True)
        check_number("k", self.k)
        check_number("systematic_mm", self.systematic_mm)
        check_int("seed", self.seed, 0, 2**31 - 1)
        check_int("restarts", self.restarts, 1, 100)
        check_int("fit_points", self.fit_points, 100, 100_000_000)
        check_positive("trim_k", self.trim_k)
        check_int("max_iterations", self.max_iterations, 1, 1000)
        object.__setattr__(self, "features", parse_features(self.features))

    def to_dict(self) -> dict[str, Any]:
        return {
            "init": self.init,
            "pairs": [{"scan": list(scan), "nominal": list(nominal)} for scan, nominal in self.pairs],
            "tolerance_mm": self.tolerance_mm,
            "k": self.k,
            "systematic_mm": self.systematic_mm,
            "seed": self.seed,
            "restarts": self.restarts,
            "fit_points": self.fit_points,
            "trim_k": self.trim_k,
            "max_iterations": self.max_iterations,
            "features": [feature.to_dict() for feature in self.features],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> InspectOptions:
        check_keys("inspect", data, set(cls().to_dict()))
        values = dict(data)
        if "pairs" in values:
            values["pairs"] = tuple(parse_pairs(values["pairs"]))
        return cls(**values)


def parse_pairs(data: Any) -> list[Pair]:
    """Point pairs from their JSON form, a list of ``{"scan": [x, y, z], "nominal": [x, y, z]}``;
    ValueError naming what is wrong."""
    if not isinstance(data, list):
        raise ValueError('point pairs must be a JSON list of {"scan": [x, y, z], "nominal": [x, y, z]}')
    pairs: list[Pair] = []
    for i, item in enumerate(data):
        if not isinstance(item, dict) or set(item) != {"scan", "nominal"}:
            raise ValueError(f'point pair {i}: must be {{"scan": [x, y, z], "nominal": [x, y, z]}}')
        try:
            scan = np.asarray(item["scan"], dtype=np.float64)
            nominal = np.asarray(item["nominal"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"point pair {i}: coordinates must be numbers") from None
        if scan.shape != (3,) or nominal.shape != (3,) or not (np.isfinite(scan).all() and np.isfinite(nominal).all()):
            raise ValueError(f"point pair {i}: scan and nominal must be three finite numbers each")
        pairs.append(((*scan.tolist(),), (*nominal.tolist(),)))
    return pairs


@dataclass(frozen=True, eq=False)
class InspectionResult:
    """Output of :func:`inspect`.

    Attributes
    ----------
    fit : FitResult
        The best fit (transform, RMS, points used, iterations, free DOF, standard deviations).
    deviation_mm : (N,) float64
        Signed deviation of every input point, input order, NaN where there is no point.
    uncertainty_mm : (N,) float64
        Each point's combined standard uncertainty along the normal (NaN: no point or no usable sigma).
    decision : (N,) int8 or None
        :mod:`~metrology.core.inspection.conformance` codes (with a tolerance).
    aligned_mm : (N, 3) float64
        The points in the nominal's frame (NaN rows where there is no point).
    shape : tuple of int
        The input's shape of per-point values (``(N,)`` or ``(H, W)``).
    start : dict
        How the start transform was found (method; seed, voxel and restarts' scores for ``auto``).
    features : list of dict
        One entry per asked feature (:func:`~metrology.core.inspection.feature_regions.measure_features`).
    """

    fit: alignment.FitResult
    deviation_mm: np.ndarray
    uncertainty_mm: np.ndarray
    decision: np.ndarray | None
    aligned_mm: np.ndarray
    shape: tuple[int, ...]
    start: dict[str, Any]
    options: InspectOptions
    software_version: str
    timings_s: dict[str, float] = field(default_factory=dict)
    features: list[dict[str, Any]] = field(default_factory=list)

    def deviation_map(self) -> np.ndarray:
        """float32 deviations in the input's shape, NaN where there is no point."""
        return self.deviation_mm.astype(np.float32).reshape(self.shape)

    def deviation_statistics(self) -> dict[str, Any]:
        values = self.deviation_mm[np.isfinite(self.deviation_mm)]
        if values.size == 0:
            return {key: None for key in ("mean_mm", "std_mm", "rms_mm", "min_mm", "max_mm", "p01_mm", "p99_mm")} | {
                "points": 0
            }
        p01, p99 = np.percentile(values, [1.0, 99.0])
        return {
            "points": int(values.size),
            "mean_mm": float(values.mean()),
            "std_mm": float(values.std()),
            "rms_mm": float(np.sqrt(np.mean(values**2))),
            "min_mm": float(values.min()),
            "max_mm": float(values.max()),
            "p01_mm": float(p01),
            "p99_mm": float(p99),
        }

    def report(self, provenance: Mapping[str, Any]) -> dict[str, Any]:
        """The ``gcps-inspection/1`` report (docs/inspection.md); ``provenance`` is completed with
        the software version, the options and the seed. ``features`` follows ``conformance`` only
        when features were asked for (an addition to ``gcps-inspection/1``)."""
        fit = self.fit
        report: dict[str, Any] = {
            "format": REPORT_FORMAT,
            "transform": fit.transform.tolist(),
            "alignment": {
                "method": self.start["method"],
                "rms_mm": fit.rms_mm,
                "points_used": fit.points_used,
                "iterations": fit.iterations,
                "converged": fit.converged,
                "symmetric_dof": fit.symmetric_dof,
                "std": {"rotation_deg": fit.rotation_std_deg, "translation_mm": fit.translation_std_mm},
            },
            "deviation": self.deviation_statistics(),
            "tolerance_mm": self.options.tolerance_mm,
            "k": self.options.k,
            "conformance": None if self.decision is None else conformance.counts(self.decision[self.valid]),
            "provenance": {
                **provenance,
                "software_version": self.software_version,
                "options": self.options.to_dict(),
                "seed": self.options.seed if self.options.init == "auto" else None,
                "systematic_mm": self.options.systematic_mm,
                "start": self.start,
                "timings_s": self.timings_s,
            },
        }
        if self.options.features:
            report = {
                **{key: value for key, value in report.items() if key != "provenance"},
                "features": self.features,
                "provenance": report["provenance"],
            }
        return report

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.deviation_mm)


def inspect(nominal: NominalModel, scan: Scan, options: InspectOptions | None = None) -> InspectionResult:
    """Align ``scan`` to ``nominal``, compute every point's deviation and uncertainty, and decide
    conformance with ``options.tolerance_mm`` (module docstring). ValueError when the scan has no
    point or too few for a fit."""
    options = options or InspectOptions()
    timer = PhaseTimer()
    with timer.phase("inspect"):
        with timer.phase("prepare"):
            surface = SurfaceDistance(nominal)
        valid = scan.valid
        index = np.flatnonzero(valid)
        if index.size == 0:
            raise ValueError("the scan has no points")
        points = scan.points_mm[index]
        sigma = None if scan.sigma_mm is None else scan.sigma_mm[index]
        usable = np.ones(index.size, bool) if sigma is None else np.isfinite(sigma) & (sigma > 0)
        if np.count_nonzero(usable) < 6:
            raise ValueError(f"the scan has {np.count_nonzero(usable)} usable points; at least 6 are needed")
        rng = np.random.default_rng(options.seed)
        candidates = np.flatnonzero(usable)
        if candidates.size > options.fit_points:
            candidates = np.sort(rng.choice(candidates, options.fit_points, replace=False))
        with timer.phase("start"):
            viewpoint = scan.ray_origin_mm if len(scan.shape) == 2 else None  # a point map: one view
            initial, start = _start(surface, points[candidates], options, viewpoint)
        with timer.phase("best_fit"):
            fit = alignment.best_fit(
                surface,
                points[candidates],
                initial,
                sigma_mm=None if sigma is None else sigma[candidates],
                trim_k=options.trim_k,
                max_iterations=options.max_iterations,
                trim_floor_mm=2 * start["voxel_mm"] if options.init == "auto" else 0.0,
            )
        with timer.phase("deviations"):
            aligned = alignment.apply(fit.transform, points)
            pieces = _deviation_pieces(surface, aligned, candidates, fit.deviations)
        with timer.phase("uncertainty"):
            m = index.size
            distance, face, u_point, u = np.empty(m), np.empty(m, np.int64), np.empty(m), np.empty(m)
            to_nominal = alignment.rigid_transform(fit.transform[:3, :3], np.zeros(3))  # the rotation alone
            for rows, aligned_rows, dev in pieces:
                distance[rows], face[rows] = dev.distance_mm, dev.face
                rays = None
                if sigma is not None and scan.sigma_along_ray:  # ray directions, nominal frame
                    rays = alignment.apply(to_nominal, points[rows] - scan.ray_origin_mm)
                u_rows = conformance.point_uncertainty(None if sigma is None else sigma[rows], dev.direction, rays=rays)
                u_fit = fit.normal_uncertainty_mm(aligned_rows, dev.direction)
                u_point[rows] = u_rows
                u[rows] = conformance.combined_uncertainty(u_rows, u_fit, options.systematic_mm)
            u_point[~usable] = np.nan
            u[~usable] = np.nan
        features: list[dict[str, Any]] = []
        if options.features:
            with timer.phase("features"):
                features = measure_features(
                    options.features,
                    aligned,
                    distance,
                    face,
                    nominal.vertices,
                    nominal.faces,
                    sigma_mm=None if sigma is None else u_point,
                )
        n = scan.points_mm.shape[0]
        deviation = np.full(n, np.nan)
        deviation[index] = distance
        uncertainty = np.full(n, np.nan)
        uncertainty[index] = u
        aligned_all = np.full((n, 3), np.nan)
        aligned_all[index] = aligned
        decision = None
        if options.tolerance_mm is not None:
            decision = conformance.decide(deviation, uncertainty, options.tolerance_mm, options.k)
    return InspectionResult(
        fit=fit,
        deviation_mm=deviation,
        uncertainty_mm=uncertainty,
        decision=decision,
        aligned_mm=aligned_all,
        shape=scan.shape,
        start=start,
        options=options,
        software_version=software_version(),
        timings_s=dict(timer.timings_s),
        features=features,
    )


def _deviation_pieces(
    surface: SurfaceDistance, aligned: np.ndarray, fitted: np.ndarray, known: Deviations | None
) -> list[tuple[np.ndarray | slice, np.ndarray, Deviations]]:
    """The deviations of the ``(N, 3)`` aligned points in pieces ``(rows, aligned[rows], their
    deviations)`` covering the rows once: those of the fit's points (at ``fitted``) taken from the
    fit's last iteration (the same transform, the same numbers), the others computed. Pieces, not
    one assembled :class:`Deviations`: the callers need a few of its fields per point, and copying
    the ``(N, 3)`` ones of 1.3 M points into one array took 0.16 s."""
    if known is None:
        return [(slice(None), aligned, surface.deviations(aligned))]
    rest = np.ones(aligned.shape[0], bool)
    rest[fitted] = False
    others = np.flatnonzero(rest)
    pieces: list[tuple[np.ndarray | slice, np.ndarray, Deviations]] = [(fitted, aligned[fitted], known)]
    if others.size:
        aligned_others = aligned[others]
        pieces.append((others, aligned_others, surface.deviations(aligned_others)))
    return pieces


def _start(
    surface: SurfaceDistance, points: np.ndarray, options: InspectOptions, viewpoint: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, Any]]:
    """The start transform and how it was found (``viewpoint``: the camera centre of a one-view scan)."""
    if options.init == "identity":
        return np.eye(4), {"method": "identity"}
    if options.init == "pairs":
        scan = np.array([pair[0] for pair in options.pairs])
        nominal = np.array([pair[1] for pair in options.pairs])
        return alignment.kabsch(scan, nominal), {"method": "pairs", "pairs": len(options.pairs)}
    found = alignment.global_registration(
        surface, points, seed=options.seed, restarts=options.restarts, viewpoint_mm=viewpoint
    )
    return found.transform, {
        "method": "auto",
        "seed": found.seed,
        "restarts": found.restarts,
        "voxel_mm": found.voxel_mm,
        "inlier_fractions": found.inlier_fractions,
    }
