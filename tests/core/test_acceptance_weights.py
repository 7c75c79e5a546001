"""Per-point sigma in the acceptance fits (issue 12 item 3): weights 1/sigma^2 and a sigma threshold,
against analytic planes and spheres with heteroscedastic noise."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.acceptance import fit_plane, fit_sphere, flatness_error, probing_error

TRUE_NORMAL = np.array([-0.01, 0.02, 1.0]) / np.linalg.norm([-0.01, 0.02, 1.0])


def _plane(rng: np.random.Generator, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Points of ``z = 40 + 0.01 x - 0.02 y`` with noise whose sigma varies 100x across the points."""
    xy = rng.uniform(-100, 100, (n, 2))
    sigma = np.where(rng.uniform(size=n) < 0.5, 0.005, 0.5)
    z = 40.0 + 0.01 * xy[:, 0] - 0.02 * xy[:, 1] + sigma * rng.standard_normal(n)
    return np.column_stack([xy, z]), sigma


def _plane_error(fit) -> tuple[float, float]:
    """Angle of the normal to the truth (rad) and offset of the plane at the origin (mm)."""
    angle = float(np.arccos(min(1.0, abs(fit.normal @ TRUE_NORMAL))))
    z0 = (
        fit.centroid[2]
        - (fit.normal[0] * (0 - fit.centroid[0]) + fit.normal[1] * (0 - fit.centroid[1])) / fit.normal[2]
    )
    return angle, abs(float(z0) - 40.0)


def test_weighted_plane_fit_is_closer_to_the_truth_over_seeds() -> None:
    plain_angle, weighted_angle, plain_z, weighted_z = [], [], [], []
    for seed in range(20):
        pts, sigma = _plane(np.random.default_rng(seed))
        a, z = _plane_error(fit_plane(pts))
        plain_angle.append(a)
        plain_z.append(z)
        a, z = _plane_error(fit_plane(pts, sigma=sigma))
        weighted_angle.append(a)
        weighted_z.append(z)
    # the weighted fit is dominated by the 5 um points: errors ~ 100x smaller (expected ratio
    # sqrt(weighted variance / plain variance) ~ 0.014); require 5x on the mean over seeds
    assert np.mean(weighted_angle) < 0.2 * np.mean(plain_angle)
    assert np.mean(weighted_z) < 0.2 * np.mean(plain_z)
    # and absolutely: the normal of 1000 points of 5 um over 200 mm is within 1e-5 rad
    assert np.mean(weighted_angle) < 1e-5


def test_a_point_with_huge_sigma_is_ignored() -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform(-50, 50, (500, 2))
    pts = np.column_stack([xy, 10.0 + 0.001 * rng.standard_normal(500)])
    sigma = np.full(500, 0.001)
    pts[0, 2] += 50.0  # a gross outlier ...
    sigma[0] = 1e6  # ... that its sigma says is worthless
    clean = fit_plane(pts[1:])
    weighted = fit_plane(pts, sigma=sigma)
    assert weighted.normal == pytest.approx(clean.normal, abs=1e-9)
    assert weighted.centroid[2] == pytest.approx(clean.centroid[2], abs=1e-9)
    assert abs(fit_plane(pts).centroid[2] - 10.0) > 0.05  # unweighted, it pulls the plane
    # the threshold drops it: the flatness is that of the clean points
    out = flatness_error(pts, reject_frac=0.0, sigma=sigma, max_sigma=0.01)
    assert out["n_points"] == 499 and out["n_dropped_sigma"] == 1 and out["weighted"] is True
    assert out["flatness_mm"] == pytest.approx(flatness_error(pts[1:], reject_frac=0.0)["flatness_mm"], rel=1e-6)


def test_weighted_sphere_fit_and_threshold() -> None:
    rng = np.random.default_rng(2)
    n, radius, center = 4000, 25.0, np.array([5.0, -3.0, 100.0])
    polar = np.arccos(rng.uniform(np.cos(1.2), 1.0, n))
    azim = rng.uniform(0, 2 * np.pi, n)
    u = np.column_stack([np.sin(polar) * np.cos(azim), np.sin(polar) * np.sin(azim), np.cos(polar)])
    sigma = np.where(rng.uniform(size=n) < 0.5, 0.002, 0.3)
    pts = center + (radius + sigma * rng.standard_normal(n))[:, None] * u
    plain = fit_sphere(pts)
    weighted = fit_sphere(pts, sigma=sigma)
    assert abs(weighted.radius - radius) < 2e-4
    assert np.linalg.norm(weighted.center - center) < 5e-4
    assert np.linalg.norm(weighted.center - center) < 0.5 * np.linalg.norm(plain.center - center)
    out = probing_error(pts, 2 * radius, sigma=sigma, max_sigma=0.01)
    assert out["n_dropped_sigma"] == int((sigma > 0.01).sum())
    assert abs(out["size_error_mm"]) < 4e-4
    assert out["form_error_mm"] < 12 * 0.002  # range of ~2000 Gaussian samples of 2 um
    assert probing_error(pts, 2 * radius)["form_error_mm"] > 1.0  # without it, the 0.3 mm points


def test_non_finite_sigma_drops_the_point_and_bad_sigma_is_refused() -> None:
    pts, sigma = _plane(np.random.default_rng(3), 100)
    sigma[:10] = np.nan
    assert len(fit_plane(pts, sigma=sigma).distances) == 90
    with pytest.raises(ValueError, match="sigma must have one value per point"):
        fit_plane(pts, sigma=sigma[:50])
    with pytest.raises(ValueError, match="sigma must be positive"):
        fit_plane(pts, sigma=np.zeros(100))
    with pytest.raises(ValueError, match="max_sigma needs a per-point sigma"):
        flatness_error(pts, max_sigma=0.1)
    with pytest.raises(ValueError, match="max_sigma must be a positive number"):
        flatness_error(pts, sigma=np.full(100, 0.1), max_sigma=-1.0)
    with pytest.raises(ValueError, match="at least 3 finite points"):
        fit_plane(pts, sigma=np.full(100, 1.0), max_sigma=0.5)
