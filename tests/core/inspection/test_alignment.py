"""Alignment: automatic global registration from random starting poses (noise-free points on a
non-symmetric part, against the true pose), the free degree of freedom of a cylinder, point
pairs, 3-2-1 datums, and the best fit's standard deviations against a Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.inspection import alignment
from metrology.core.inspection.distance import SurfaceDistance
from tests.core.inspection.parts import asymmetric_part, cylinder_part, pose_error, random_pose

ROTATION_DEG = 0.001
DISPLACEMENT_MM = 0.005


@pytest.fixture(scope="module")
def part() -> tuple[SurfaceDistance, np.ndarray]:
    surface = SurfaceDistance(asymmetric_part())
    points, _ = alignment.sample_surface(surface, 100_000, np.random.default_rng(11))
    return surface, points


def auto_pose(surface: SurfaceDistance, points: np.ndarray, truth: np.ndarray, seed: int = 0) -> np.ndarray:
    scan = alignment.apply(np.linalg.inv(truth), points)  # truth maps the scan onto the nominal
    start = alignment.global_registration(surface, scan, seed=seed)
    return alignment.best_fit(surface, scan, start.transform).transform


def test_auto_alignment_from_a_random_pose(part: tuple[SurfaceDistance, np.ndarray]) -> None:
    surface, points = part
    truth = random_pose(np.random.default_rng(100))
    rotation, displacement = pose_error(auto_pose(surface, points, truth), truth, points)
    assert rotation < ROTATION_DEG and displacement < DISPLACEMENT_MM


@pytest.mark.slow
def test_auto_alignment_from_20_random_poses_is_exact_and_reproducible(
    part: tuple[SurfaceDistance, np.ndarray],
) -> None:
    """Every one of 20 random poses (any rotation, shifts up to 50 mm) is found within 5 um and
    0.001 degrees (largest displacement of the 100k points); the same seed gives the same answer."""
    surface, points = part
    rng = np.random.default_rng(2026)
    errors = []
    for _ in range(20):
        truth = random_pose(rng)
        errors.append(pose_error(auto_pose(surface, points, truth), truth, points))
    worst = np.max(errors, axis=0)
    assert worst[0] < ROTATION_DEG and worst[1] < DISPLACEMENT_MM, errors
    truth = random_pose(rng)
    np.testing.assert_array_equal(auto_pose(surface, points, truth, 5), auto_pose(surface, points, truth, 5))


def test_cylinder_reports_its_free_rotation() -> None:
    surface = SurfaceDistance(cylinder_part())
    rng = np.random.default_rng(4)
    points, _ = alignment.sample_surface(surface, 20_000, rng)
    truth = random_pose(rng, angle_rad=0.02, shift_mm=0.5)
    fit = alignment.best_fit(surface, alignment.apply(np.linalg.inv(truth), points), np.eye(4))
    assert fit.converged
    assert len(fit.symmetric_dof) == 1, fit.symmetric_dof
    free = fit.symmetric_dof[0]
    assert free["kind"] == "rotation"
    np.testing.assert_allclose(free["axis"], [0, 0, 1], atol=1e-3)  # 256 facets: nearly symmetric
    np.testing.assert_allclose(free["point_mm"][:2], [0, 0], atol=0.01)  # the cylinder's axis
    assert fit.rotation_std_deg[2] is None and fit.rotation_std_deg[0] is not None
    # the fixed five degrees of freedom are right: every point back on the surface
    assert fit.rms_mm < 1e-6


def test_asymmetric_part_has_no_free_dof(part: tuple[SurfaceDistance, np.ndarray]) -> None:
    surface, points = part
    fit = alignment.best_fit(surface, points[:5000], np.eye(4))
    assert fit.symmetric_dof == [] and fit.iterations <= 1
    assert None not in fit.rotation_std_deg + fit.translation_std_mm


def test_point_pairs_kabsch_is_exact() -> None:
    rng = np.random.default_rng(5)
    truth = random_pose(rng)
    nominal = rng.uniform(-30, 30, (4, 3))
    found = alignment.kabsch(alignment.apply(np.linalg.inv(truth), nominal), nominal)
    np.testing.assert_allclose(found, truth, atol=1e-12)
    with pytest.raises(ValueError, match="at least 3"):
        alignment.kabsch(nominal[:2], nominal[:2])
    with pytest.raises(ValueError, match="collinear"):
        line = np.outer(np.arange(4.0), [1.0, 2.0, 3.0])
        alignment.kabsch(line, line)


def test_datum_321_alignment_of_a_block(part: tuple[SurfaceDistance, np.ndarray]) -> None:
    """Primary: the block's bottom (z = 0), secondary: its front (y = 0), tertiary: its left end
    (x = 0). From a start 1 degree and 1 mm off, the datums put the noise-free points back exactly."""
    surface, points = part
    normals = surface.face_normals
    centres = surface.vertices[surface.faces].mean(axis=1)
    bottom = (normals[:, 2] < -0.999) & (np.abs(centres[:, 2]) < 1e-9)
    front = (normals[:, 1] < -0.999) & (np.abs(centres[:, 1]) < 1e-9)
    left = (normals[:, 0] < -0.999) & (np.abs(centres[:, 0]) < 1e-9)
    rng = np.random.default_rng(8)
    truth = random_pose(rng, angle_rad=np.radians(1.0), shift_mm=1.0)
    scan = alignment.apply(np.linalg.inv(truth), points)
    found = alignment.datum_alignment(surface, scan, np.eye(4), bottom, front, left, max_distance_mm=3.0)
    rotation, displacement = pose_error(found, truth, points)
    assert rotation < 1e-9 and displacement < 1e-12


def test_standard_deviations_match_a_monte_carlo(part: tuple[SurfaceDistance, np.ndarray]) -> None:
    """Points with Gaussian noise along the normal (sigma 10 um): the reported standard deviations
    of the rotation and translation agree with the spread of 40 fits within 35 %."""
    surface, points = part
    rng = np.random.default_rng(9)
    base = points[:3000]
    normals = surface.deviations(base).direction
    sigma = 0.01
    fits = []
    for _ in range(40):
        noisy = base + rng.normal(0, sigma, (base.shape[0], 1)) * normals
        fits.append(alignment.best_fit(surface, noisy, np.eye(4), sigma_mm=np.full(base.shape[0], sigma), trim_k=10.0))
    rotations = np.array([np.degrees([f.transform[2, 1], f.transform[0, 2], f.transform[1, 0]]) for f in fits])
    translations = np.array([f.transform[:3, 3] for f in fits])
    predicted_rotation = np.mean([f.rotation_std_deg for f in fits], axis=0)
    predicted_translation = np.mean([f.translation_std_mm for f in fits], axis=0)
    np.testing.assert_allclose(rotations.std(axis=0, ddof=1), predicted_rotation, rtol=0.35)
    np.testing.assert_allclose(translations.std(axis=0, ddof=1), predicted_translation, rtol=0.35)
    assert np.mean([f.rms_mm for f in fits]) == pytest.approx(sigma, rel=0.05)
