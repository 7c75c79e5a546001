"""Aligning a scan to its nominal model: a start (global registration, identity, point pairs or
a 3-2-1 datum alignment), then a weighted, trimmed point-to-plane best fit on the nominal surface.

A transform is a ``(4, 4)`` float64 matrix ``T`` with ``x_nominal = T[:3, :3] x_scan + T[:3, 3]``
(mm) and last row ``[0, 0, 0, 1]``.

Best fit (:func:`best_fit`)
---------------------------
Iterate: map the scan points ``p_i`` to ``x_i = T p_i``; find each one's signed distance ``r_i``
and unit gradient ``n_i`` on the nominal (:mod:`.distance`: exact closest points, so the
"plane" of point-to-plane is the surface's own tangent plane); keep the points with
``|r_i - median(r)| <= max(trim_k * 1.4826 * MAD(r), f_k)`` (robust trimming: only the fit drops
them; ``f_k = trim_floor_mm * TRIM_FLOOR_DECAY^k`` at iteration ``k`` is a floor that keeps, at
first, every point within the start's own error: without it a rough start whose error only some
faces see, e.g. a slide that only the few points on a side face measure, has those points trimmed
as outliers and the slide declared free);
solve the weighted least squares ``min sum_i w_i (r_i + g_i . delta)^2`` with
``w_i = 1 / sigma_i^2``, ``g_i = [(x_i - c) x n_i, n_i]`` and ``delta = (omega, t)`` a small
rotation vector (rad) about the kept points' weighted centroid ``c`` and a translation (mm); apply
``x -> R(omega) (x - c) + c + t``. It has converged when ``|omega| < 1e-10`` rad and
``|t| < 1e-8`` mm (noise-free points), or when the step is below 20 % of its own standard deviation,
``sqrt(delta^T H delta / s^2) < 0.2`` (noisy points, whose trimmed set keeps changing a little: the
steps shrink by a factor of 14 or more per iteration near the solution (measured on the benchmark's
part: 4.6, 0.1, 0.0006 standard deviations), so the step after such a one would be below about
0.015 standard deviations; the criterion saves that last closest-point pass over the points);
else it stops after ``max_iterations``. Above ``2 * COARSE_POINTS`` points the iterations first
run on every k-th point (about ``COARSE_POINTS``) until the step is below 1000 times those
tolerances or 10 % of its standard deviation, then on all. The fit has not converged while the
floor still keeps a point that the MAD rule alone would trim.

Uncertainty: the covariance of ``delta`` is ``C = s^2 H^+`` with ``H = sum_i w_i g_i g_i^T``
(the weighted normal matrix) and ``s^2 = sum_i w_i r_i^2 / (n - 6)`` (the residual variance
factor, so that the standard deviations reflect the residuals actually seen). The reported
standard deviations are those of ``T``'s parameters: the rotation about the nominal's x, y, z
axes (degrees) and ``T[:3, 3]`` (mm, at the nominal's origin: ``delta t_0 = t - (t_0 - c) x omega``).
A point's alignment uncertainty along the normal is ``sqrt(g C g^T)``.

Free degrees of freedom: with rotations scaled by the kept points' RMS distance ``L`` from ``c``
(so that all six parameters are displacements in mm), an eigenvalue of ``H`` below
``free_dof_ratio`` times the largest marks a direction the surface does not constrain (a
rotationally symmetric part turns freely about its axis, an extrusion slides along it). Such
directions are listed in ``symmetric_dof`` (``{"kind": "rotation", "axis", "point_mm"}`` or
``{"kind": "translation", "direction"}``, nominal frame); the least squares takes the
minimum-norm step there (the part is not moved along it), and the standard deviations they
affect are None.

Global registration (:func:`global_registration`)
-------------------------------------------------
The nominal is sampled (area-weighted, ``numpy`` generator seeded with ``seed``) with its face
normals; the scan is voxel-downsampled (voxel ``= diagonal / voxel_divisions``), its normals
estimated and turned away from its centroid (or towards ``viewpoint_mm``, the camera of a one-view
scan). FPFH features (radius 5 voxels) are matched by
Open3D's RANSAC (``open3d.utility.random.seed(seed + k)`` for restart ``k``); each restart's
answer is refined by :func:`best_fit` on a few thousand points (trimming floor two voxels), and the one with most points
within one voxel of the surface (then the lowest RMS) wins; the restarts stop early once one
explains ``accept_fraction`` (98 %) of the points that way. Same inputs and seed, same answer.
The nominal's sampled cloud and its features depend only on the surface, the seed and the voxel:
the last :data:`KEPT_TARGETS` of each surface are kept (with the generator's state after the
sampling), so that registering several scans to one nominal samples and describes it once.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metrology.core.inspection.distance import Deviations, SurfaceDistance

TRIM_K = 3.0
FREE_DOF_RATIO = 1e-3
MAX_ITERATIONS = 60
ROTATION_TOL_RAD = 1e-10
TRANSLATION_TOL_MM = 1e-8
RANSAC_ITERATIONS = 20000
MIN_TRIM_MM = 1e-6
"""Residuals within this of the median are never trimmed (noise-free data has a MAD of ~0)."""
STEP_STD_FRACTION = 0.2
"""The fit has also converged when a step is below this many of its standard deviations (noisy data)."""
COARSE_POINTS = 20000
"""Above twice this many points, the fit first iterates on every k-th point (about this many)."""
TRIM_FLOOR_DECAY = 0.3
"""The trimming floor (``trim_floor_mm``) shrinks by this factor at each iteration."""
COARSE_STD_FRACTION = 0.2
"""The coarse stage also stops at steps below this many of their standard deviations."""
BLOCK_POINTS = 1 << 15
"""Rows per block of the per-point products (:func:`apply`, :meth:`FitResult.normal_uncertainty_mm`)."""
COARSE_TOLERANCE = 1e3
"""The coarse stage stops at steps below 1000 times the final tolerances (1e-7 rad, 1e-5 mm)."""
KEPT_TARGETS = 4
"""Registration targets (the nominal's cloud and FPFH features) kept per surface, by seed and voxel."""
_TARGETS: weakref.WeakKeyDictionary[SurfaceDistance, OrderedDict[tuple[int, float], tuple[Any, Any, Mapping[str, Any]]]]
_TARGETS = weakref.WeakKeyDictionary()
_TARGETS_LOCK = threading.Lock()


@dataclass(frozen=True)
class FitResult:
    """The best fit of a scan to the nominal (module docstring).

    Attributes
    ----------
    transform : (4, 4) float64
        ``x_nominal = T[:3, :3] x_scan + T[:3, 3]``, mm.
    rms_mm : float
        Weighted RMS of the kept points' signed distances at the final transform, mm.
    points_used : int
        Points kept by the trimming at the final transform.
    iterations : int
    converged : bool
    symmetric_dof : list of dict
        Directions the surface leaves free (module docstring); empty when all six are fixed.
    covariance : (6, 6) float64
        Of ``(omega, t)`` about :attr:`centre_mm` (rad, mm).
    centre_mm : (3,) float64
        The centre ``c`` of the rotation parameters, nominal frame.
    rotation_std_deg, translation_std_mm : list of 3 (float or None)
    deviations : Deviations or None
        The signed distances of the fit's points (in their order) at :attr:`transform`, from the
        last iteration (the deviations pass of :func:`metrology.pipeline.inspect.inspect` reuses them).
    """

    transform: np.ndarray
    rms_mm: float
    points_used: int
    iterations: int
    converged: bool
    symmetric_dof: list[dict[str, Any]]
    covariance: np.ndarray
    centre_mm: np.ndarray
    rotation_std_deg: list[float | None] = field(default_factory=list)
    translation_std_mm: list[float | None] = field(default_factory=list)
    deviations: Deviations | None = None

    def normal_uncertainty_mm(self, aligned_mm: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """``(N,)``: the alignment's standard uncertainty along ``direction`` (unit ``(N, 3)``, the
        surface normal) at the aligned points ``(N, 3)`` mm: ``sqrt(g C g^T)``."""
        out = np.empty(direction.shape[0])
        for start in range(0, out.size, BLOCK_POINTS):  # blocks that stay in cache; no BLAS (see apply)
            block = slice(start, start + BLOCK_POINTS)
            n = direction[block]
            g = np.concatenate([np.cross(aligned_mm[block] - self.centre_mm, n), n], axis=1)
            out[block] = np.einsum("ni,ni->n", np.einsum("ni,ij->nj", g, self.covariance), g)
        return np.sqrt(np.maximum(out, 0.0))


def apply(transform: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64: ``T[:3, :3] p + T[:3, 3]`` for each row ``p``.

    Computed in blocks of :data:`BLOCK_POINTS` rows without BLAS: a ``(N, 3) x (3, 3)`` product
    handed to OpenBLAS's threads takes 25 ms to 0.3 s for 1.3 M points on a loaded two-core
    machine (its threads wait for each other), the blocked ``einsum`` 45 to 70 ms."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    rotation, translation = transform[:3, :3], transform[:3, 3]
    out = np.empty_like(points)
    for start in range(0, points.shape[0], BLOCK_POINTS):
        block = out[start : start + BLOCK_POINTS]
        np.einsum("nj,ij->ni", points[start : start + BLOCK_POINTS], rotation, out=block)
        block += translation
    return out


def rotation_matrix(rotation_vector: np.ndarray) -> np.ndarray:
    """``(3, 3)``: the rotation by ``|w|`` rad about ``w / |w|`` (Rodrigues)."""
    w = np.asarray(rotation_vector, dtype=np.float64)
    angle = float(np.linalg.norm(w))
    if angle == 0.0:
        return np.eye(3)
    k = _skew(w / angle)
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def rigid_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``(4, 4)`` from a ``(3, 3)`` rotation and a ``(3,)`` translation."""
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = translation
    return transform


def kabsch(scan_mm: np.ndarray, nominal_mm: np.ndarray) -> np.ndarray:
    """The rigid transform (no scale) taking ``(N, 3)`` scan points onto their ``(N, 3)`` nominal
    partners in least squares (Kabsch/Umeyama: ``R = V diag(1, 1, det(V U^T)) U^T`` from the SVD
    ``U S V^T`` of the centred cross-covariance); ValueError below 3 pairs or when collinear."""
    p = np.asarray(scan_mm, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(nominal_mm, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] < 3 or p.shape != q.shape:
        raise ValueError(f"point pairs: at least 3 are needed, got {min(p.shape[0], q.shape[0])}")
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    u, s, vt = np.linalg.svd((p - pc).T @ (q - qc))
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise ValueError("point pairs: the scan points are collinear (the rotation is not determined)")
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rigid_transform(rotation, qc - rotation @ pc)


def best_fit(
    surface: SurfaceDistance,
    scan_mm: np.ndarray,
    initial: np.ndarray,
    *,
    sigma_mm: np.ndarray | None = None,
    trim_k: float = TRIM_K,
    max_iterations: int = MAX_ITERATIONS,
    free_dof_ratio: float = FREE_DOF_RATIO,
    trim_floor_mm: float = 0.0,
) -> FitResult:
    """Weighted, trimmed point-to-plane fit of ``(N, 3)`` scan points (mm, finite) to ``surface``
    from ``initial`` (module docstring); ``sigma_mm`` ``(N,)`` gives the weights ``1/sigma^2``;
    ``trim_floor_mm``: the start's error bound, below which no residual is trimmed at first."""
    points = np.asarray(scan_mm, dtype=np.float64).reshape(-1, 3)
    if points.shape[0] < 6:
        raise ValueError(f"best fit: at least 6 points are needed, got {points.shape[0]}")
    weights = np.ones(points.shape[0]) if sigma_mm is None else 1.0 / np.square(np.asarray(sigma_mm, np.float64))
    transform = np.array(initial, dtype=np.float64)
    coarse_iterations = 0
    floor = float(trim_floor_mm)
    if points.shape[0] > 2 * COARSE_POINTS:  # first on every k-th point, to near convergence
        stride = slice(None, None, points.shape[0] // COARSE_POINTS)
        transform, coarse_iterations, _, _, _, floor, _ = _iterate(
            surface,
            points[stride],
            weights[stride],
            transform,
            trim_k,
            max_iterations,
            COARSE_TOLERANCE,
            COARSE_STD_FRACTION,
            floor,
        )
    transform, iterations, converged, system, keep, _, deviations = _iterate(
        surface, points, weights, transform, trim_k, max_iterations, 1.0, STEP_STD_FRACTION, floor
    )
    iterations += coarse_iterations
    free = system.free_directions(free_dof_ratio)
    covariance = system.covariance(free)
    rotation_std, translation_std = _parameter_std(covariance, system.centre, transform[:3, 3], free)
    return FitResult(
        transform=transform,
        rms_mm=system.rms,
        points_used=int(keep.sum()),
        iterations=iterations,
        converged=bool(converged),
        symmetric_dof=[_describe(v, system) for v in free],
        covariance=covariance,
        centre_mm=system.centre,
        rotation_std_deg=rotation_std,
        translation_std_mm=translation_std,
        deviations=deviations,
    )


def _iterate(
    surface: SurfaceDistance,
    points: np.ndarray,
    weights: np.ndarray,
    transform: np.ndarray,
    trim_k: float,
    max_iterations: int,
    tolerance_scale: float,
    std_fraction: float,
    floor: float,
) -> tuple[np.ndarray, int, bool, _NormalSystem, np.ndarray, float, Deviations]:
    """Best-fit iterations from ``transform`` until the step is below the tolerances (times
    ``tolerance_scale``) or below ``std_fraction`` of its own standard deviation, and the trimming
    ``floor`` (mm, times :data:`TRIM_FLOOR_DECAY` per iteration) no longer keeps a point; the
    transform, iterations, converged, the last normal system, the kept points (at the returned
    transform), the floor left and the points' deviations at the returned transform."""
    converged = False
    iterations = 0
    while True:
        aligned = apply(transform, points)
        dev = surface.deviations(aligned)
        keep, floored = _kept(dev.distance_mm, trim_k, floor)
        system = _normal_system(aligned[keep], dev.direction[keep], dev.distance_mm[keep], weights[keep])
        if converged or iterations >= max_iterations:
            return transform, iterations, converged, system, keep, floor, dev
        step = system.step()
        transform = _compose(step, system.centre) @ transform
        iterations += 1
        small = (
            np.linalg.norm(step[:3]) < ROTATION_TOL_RAD * tolerance_scale
            and np.linalg.norm(step[3:]) < TRANSLATION_TOL_MM * tolerance_scale
        )
        converged = bool(small or system.step_in_std(step) < std_fraction) and not floored  # an unfloored step
        floor *= TRIM_FLOOR_DECAY


def _kept(residual: np.ndarray, trim_k: float, floor: float = 0.0) -> tuple[np.ndarray, bool]:
    """The points the fit keeps (module docstring) and whether the floor kept more than the MAD rule."""
    median = float(np.median(residual))
    spread = np.abs(residual - median)
    limit = max(trim_k * 1.4826 * float(np.median(spread)), MIN_TRIM_MM)
    keep = spread <= max(limit, floor)
    return keep, bool(floor > limit and np.any(keep & (spread > limit)))


@dataclass(frozen=True)
class _NormalSystem:
    """The weighted normal equations of one iteration, rotations about ``centre``."""

    jacobian: np.ndarray  # (M, 6) g_i
    residual: np.ndarray  # (M,)
    weights: np.ndarray  # (M,)
    centre: np.ndarray  # (3,)
    length: float  # RMS distance from the centre, mm
    normal_matrix: np.ndarray  # (6, 6) H = sum_i w_i g_i g_i^T
    gradient: np.ndarray  # (6,) sum_i w_i r_i g_i

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.sum(self.weights * self.residual**2) / np.sum(self.weights)))

    def _scaled(self) -> tuple[np.ndarray, np.ndarray]:
        scale = np.array([1.0 / self.length] * 3 + [1.0] * 3)  # parameters omega * L (mm) and t
        return scale[:, None] * self.normal_matrix * scale[None, :], scale

    def step(self) -> np.ndarray:
        """The minimum-norm least-squares ``(omega, t)`` (in scaled units, so that a free
        direction is not moved along)."""
        scaled, scale = self._scaled()
        rhs = -scale * self.gradient
        values, vectors = np.linalg.eigh(scaled)
        keep = values > values.max() * 1e-12
        solution = vectors[:, keep] @ ((vectors[:, keep].T @ rhs) / values[keep])
        return np.asarray(scale * solution)

    def step_in_std(self, step: np.ndarray) -> float:
        """The step's size in standard deviations of the parameters, ``sqrt(step^T H step / s^2)``
        (``s^2`` the weighted residual variance); inf without residuals."""
        dof = max(self.residual.size - 6, 1)
        variance = float(np.sum(self.weights * self.residual**2) / dof)
        if variance <= 0.0:
            return float("inf")
        return float(np.sqrt(max(step @ self.normal_matrix @ step, 0.0) / variance))

    def free_directions(self, ratio: float) -> list[np.ndarray]:
        """Unit eigenvectors (scaled parameters) of the eigenvalues below ``ratio`` times the largest."""
        scaled, _ = self._scaled()
        values, vectors = np.linalg.eigh(scaled)
        return [vectors[:, k] for k in range(6) if values[k] < ratio * values.max()]

    def covariance(self, free: list[np.ndarray]) -> np.ndarray:
        """``s^2 H^+`` of ``(omega, t)``, the free directions left out (module docstring)."""
        scaled, scale = self._scaled()
        values, vectors = np.linalg.eigh(scaled)
        keep = values >= FREE_DOF_RATIO * values.max() if free else values > 0
        inverse = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
        dof = max(self.residual.size - 6, 1)
        variance = float(np.sum(self.weights * self.residual**2) / dof)
        return np.asarray(variance * scale[:, None] * inverse * scale[None, :])


def _normal_system(
    aligned: np.ndarray, direction: np.ndarray, residual: np.ndarray, weights: np.ndarray
) -> _NormalSystem:
    if aligned.shape[0] < 6:
        raise ValueError("best fit: fewer than 6 points survive the trimming")
    centre = np.average(aligned, axis=0, weights=weights)
    arm = aligned - centre
    length = float(np.sqrt(np.average(np.einsum("ij,ij->i", arm, arm), weights=weights))) or 1.0
    jacobian = np.concatenate([np.cross(arm, direction), direction], axis=1)
    weighted = jacobian * weights[:, None]
    normal_matrix = np.einsum("ni,nj->ij", weighted, jacobian)  # no BLAS threads (see apply)
    gradient = np.einsum("ni,n->i", weighted, residual)
    return _NormalSystem(jacobian, residual, weights, centre, length, normal_matrix, gradient)


def _compose(step: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``x -> R(omega) (x - c) + c + t`` as a ``(4, 4)`` matrix."""
    rotation = rotation_matrix(step[:3])
    return rigid_transform(rotation, centre - rotation @ centre + step[3:])


def _parameter_std(
    covariance: np.ndarray, centre: np.ndarray, translation: np.ndarray, free: list[np.ndarray]
) -> tuple[list[float | None], list[float | None]]:
    """Standard deviations of the rotation (deg, about x, y, z) and of ``T[:3, 3]`` (mm); None
    where a free direction moves that parameter."""
    mapping = np.zeros((6, 6))  # (omega, t at centre) -> (omega, t at the origin)
    mapping[:3, :3] = np.eye(3)
    mapping[3:, :3] = -_skew(translation - centre)
    mapping[3:, 3:] = np.eye(3)
    variance = np.diag(mapping @ covariance @ mapping.T)
    std = np.sqrt(np.maximum(variance, 0.0))
    affected = np.zeros(6, bool)
    for v in free:
        moved = mapping @ v
        affected |= np.abs(moved) > 1e-3 * np.abs(moved).max()
    values: list[float | None] = [None if affected[k] else float(std[k]) for k in range(6)]
    rotation = [None if v is None else float(np.degrees(v)) for v in values[:3]]
    return rotation, values[3:]


def _describe(vector: np.ndarray, system: _NormalSystem) -> dict[str, Any]:
    """A free direction of the scaled parameters as a rotation axis (through a point) or a translation."""
    omega = vector[:3] / system.length
    t = vector[3:]
    if np.linalg.norm(vector[:3]) >= np.linalg.norm(t):
        axis = omega / np.linalg.norm(omega)
        # x -> omega x (x - c) + t equals omega x (x - q) for q - c = omega x t / |omega|^2
        point = system.centre + np.cross(omega, t) / float(omega @ omega)
        if axis[np.argmax(np.abs(axis))] < 0:
            axis = -axis
        return {"kind": "rotation", "axis": axis.tolist(), "point_mm": point.tolist()}
    direction = t / np.linalg.norm(t)
    if direction[np.argmax(np.abs(direction))] < 0:
        direction = -direction
    return {"kind": "translation", "direction": direction.tolist()}


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


# --------------------------------------------------------------------------- global registration
@dataclass(frozen=True)
class GlobalRegistration:
    """What :func:`global_registration` found: the start transform, the seed, the restarts' scores."""

    transform: np.ndarray
    seed: int
    restarts: int
    voxel_mm: float
    inlier_fractions: list[float]


def sample_surface(surface: SurfaceDistance, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points (mm) area-weighted on the surface and their face normals, ``(count, 3)`` each."""
    vertices, faces = surface.vertices, surface.faces
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    face = rng.choice(faces.shape[0], size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    points = a[face] + u[:, None] * (b - a)[face] + v[:, None] * (c - a)[face]
    return points, surface.face_normals[face]


def global_registration(
    surface: SurfaceDistance,
    scan_mm: np.ndarray,
    *,
    seed: int = 0,
    restarts: int = 3,
    voxel_divisions: float = 40.0,
    refine_points: int = 4000,
    accept_fraction: float = 0.98,
    viewpoint_mm: np.ndarray | None = None,
) -> GlobalRegistration:
    """A start transform of ``(N, 3)`` scan points onto ``surface`` without user input (module docstring).

    ``viewpoint_mm`` ``(3,)``: the camera centre of a single-view scan (a point map), scan frame; the
    scan's estimated normals are then turned towards it (every point seen was facing the camera)
    instead of away from the scan's centroid (right for a whole part, wrong for one view of it)."""
    import open3d

    reg = open3d.pipelines.registration
    rng = np.random.default_rng(seed)
    scan = np.asarray(scan_mm, dtype=np.float64).reshape(-1, 3)
    low, high = surface.vertices.min(axis=0), surface.vertices.max(axis=0)
    voxel = float(np.linalg.norm(high - low)) / voxel_divisions
    feature = open3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    target, target_fpfh = _target(surface, seed, voxel, rng, feature)
    subset = scan if scan.shape[0] <= 200000 else scan[rng.choice(scan.shape[0], 200000, replace=False)]
    source = _cloud(subset, voxel, None, viewpoint_mm)
    source_fpfh = reg.compute_fpfh_feature(source, feature)  # type: ignore[call-arg]
    refine = scan[rng.choice(scan.shape[0], min(refine_points, scan.shape[0]), replace=False)]
    best: tuple[float, float, np.ndarray] | None = None
    fractions: list[float] = []
    for k in range(restarts):
        open3d.utility.random.seed(seed + k)
        found = reg.registration_ransac_based_on_feature_matching(
            source,
            target,
            source_fpfh,
            target_fpfh,
            False,  # no mutual filter: it leaves too few matches on a small part
            1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(RANSAC_ITERATIONS, 0.999),
        )
        fit = best_fit(surface, refine, np.asarray(found.transformation), max_iterations=30, trim_floor_mm=2 * voxel)
        residual = surface.deviations(apply(fit.transform, refine)).distance_mm
        fraction = float(np.mean(np.abs(residual) <= voxel))
        fractions.append(fraction)
        score = (fraction, -fit.rms_mm)
        if best is None or score > best[:2]:
            best = (fraction, -fit.rms_mm, fit.transform)
        if fraction >= accept_fraction:
            break
    assert best is not None
    return GlobalRegistration(best[2], seed, restarts, voxel, fractions)


def _target(
    surface: SurfaceDistance, seed: int, voxel: float, rng: np.random.Generator, feature: Any
) -> tuple[Any, Any]:
    """The nominal's registration target: 40000 points sampled with ``rng`` (fresh from ``seed``),
    voxel-downsampled with their face normals, and their FPFH features; kept per surface
    (:data:`KEPT_TARGETS`), ``rng`` then set to the state the sampling leaves (the same draws follow)."""
    import open3d

    key = (int(seed), float(voxel))
    with _TARGETS_LOCK:
        kept = _TARGETS.setdefault(surface, OrderedDict())
        found = kept.get(key)
        if found is not None:
            kept.move_to_end(key)
    if found is not None:
        rng.bit_generator.state = found[2]
        return found[0], found[1]
    points, normals = sample_surface(surface, 40000, rng)
    target = _cloud(points, voxel, normals)
    fpfh = open3d.pipelines.registration.compute_fpfh_feature(target, feature)  # type: ignore[call-arg]
    with _TARGETS_LOCK:
        kept[key] = (target, fpfh, rng.bit_generator.state)
        while len(kept) > KEPT_TARGETS:
            kept.popitem(last=False)
    return target, fpfh


def _cloud(points: np.ndarray, voxel: float, normals: np.ndarray | None, viewpoint: np.ndarray | None = None) -> Any:
    """A voxel-downsampled Open3D cloud with normals (given, or estimated and turned towards
    ``viewpoint``, or outward from the centroid without one)."""
    import open3d

    cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(points))
    if normals is not None:
        cloud.normals = open3d.utility.Vector3dVector(normals)
        return cloud.voxel_down_sample(voxel)
    cloud = cloud.voxel_down_sample(voxel)
    cloud.estimate_normals(open3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    kept = np.asarray(cloud.points)
    estimated = np.asarray(cloud.normals)
    away = kept - kept.mean(axis=0) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64) - kept
    outward = np.where(np.einsum("ij,ij->i", estimated, away) < 0, -1.0, 1.0)
    cloud.normals = open3d.utility.Vector3dVector(estimated * outward[:, None])
    return cloud


# --------------------------------------------------------------------------- 3-2-1 datums
def datum_alignment(
    surface: SurfaceDistance,
    scan_mm: np.ndarray,
    initial: np.ndarray,
    primary: np.ndarray,
    secondary: np.ndarray,
    tertiary: np.ndarray,
    *,
    max_distance_mm: float = 1.0,
    iterations: int = 10,
) -> np.ndarray:
    """A 3-2-1 datum alignment: the scan's primary plane onto the nominal's (3 DOF), its secondary
    line onto the nominal's within that plane (2 DOF), its tertiary point onto the nominal's
    along that line (1 DOF).

    ``primary``, ``secondary``, ``tertiary`` are boolean ``(F,)`` masks (or index arrays) of the
    nominal's faces forming each datum region. The scan points of a region are those whose closest
    face after the current transform is in it, within ``max_distance_mm``. The nominal's datums are
    fitted to its region's vertices: plane (least squares, normal on the region's outward side),
    line (the region's points projected onto the primary plane, principal direction), point (the
    tertiary region's centroid, its position along the line). The scan's datums are fitted the
    same way to its region points. As the regions' points depend on the transform, the whole is
    repeated from the result (at most ``iterations`` times, until it changes by less than 1e-12).
    Returns the ``(4, 4)`` transform (it replaces ``initial``).
    """
    transform = np.asarray(initial, dtype=np.float64)
    for _ in range(iterations):
        step = _datum_step(surface, apply(transform, scan_mm), (primary, secondary, tertiary), max_distance_mm)
        transform = step @ transform
        if np.abs(step - np.eye(4)).max() < 1e-12:
            break
    return transform


def _datum_step(
    surface: SurfaceDistance, scan: np.ndarray, masks: tuple[np.ndarray, ...], max_distance_mm: float
) -> np.ndarray:
    """One 3-2-1 alignment of points already roughly in the nominal frame (:func:`datum_alignment`)."""
    dev = surface.deviations(scan)
    near = np.abs(dev.distance_mm) <= max_distance_mm
    regions = []
    for mask in masks:
        faces = np.zeros(surface.faces.shape[0], bool)
        faces[np.asarray(mask)] = True
        scan_points = scan[faces[dev.face] & near]
        if scan_points.shape[0] < 3:
            raise ValueError("datum alignment: fewer than 3 scan points on a datum region")
        regions.append((np.unique(surface.faces[faces].reshape(-1)), scan_points, faces))
    normal_nominal = surface.face_normals[regions[0][2]].sum(axis=0)
    n_nom, o_nom = _plane(surface.vertices[regions[0][0]], normal_nominal)
    n_scan, o_scan = _plane(regions[0][1], n_nom)
    rotation = _rotation_between(n_scan, n_nom)
    step = rigid_transform(rotation, o_nom - rotation @ o_scan)  # planes coincide
    scan2 = apply(step, regions[1][1])
    d_nom, l_nom = _line(surface.vertices[regions[1][0]], n_nom, o_nom)
    d_scan, l_scan = _line(scan2, n_nom, o_nom)
    if d_scan @ d_nom < 0:
        d_scan = -d_scan
    spin = _rotation_between(d_scan, d_nom)  # about n_nom, as both lie in the plane
    shift = l_nom - spin @ (l_scan - o_nom) - o_nom
    shift -= (shift @ d_nom) * d_nom  # lines coincide; the slide along them comes from the tertiary
    second = rigid_transform(spin, o_nom - spin @ o_nom + shift)
    tertiary_scan = apply(second @ step, regions[2][1]).mean(axis=0)
    tertiary_nominal = surface.vertices[regions[2][0]].mean(axis=0)
    slide = ((tertiary_nominal - tertiary_scan) @ d_nom) * d_nom
    return np.asarray(rigid_transform(np.eye(3), slide) @ second @ step)


def _plane(points: np.ndarray, towards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][2]
    return (normal if normal @ towards >= 0 else -normal), centre


def _line(points: np.ndarray, normal: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    flat = points - np.outer((points - origin) @ normal, normal)
    centre = flat.mean(axis=0)
    direction = np.linalg.svd(flat - centre, full_matrices=False)[2][0]
    return direction, centre


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit ``a`` onto unit ``b``."""
    axis = np.cross(a, b)
    sine, cosine = float(np.linalg.norm(axis)), float(a @ b)
    if sine < 1e-15:
        if cosine > 0:
            return np.eye(3)
        other = np.eye(3)[np.argmin(np.abs(a))]
        axis = np.cross(a, other)
        return rotation_matrix(np.pi * axis / np.linalg.norm(axis))
    return rotation_matrix(axis / sine * np.arctan2(sine, cosine))
