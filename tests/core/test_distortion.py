"""OpenCV's distortion model: forward against cv2.projectPoints, inverse to 1e-6 px."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from metrology.core.distortion import Distortion, check_dist, project_normalized, undistort_pixels

K = np.array([[1400.0, 0.0, 1010.0], [0.0, 1390.0, 770.0], [0.0, 0.0, 1.0]])


def _coeffs(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(0.0, 0.02, n)
    if n == 14:
        d[12:] = [0.01, -0.02]  # tilt angles, rad
    return d


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_forward_matches_opencv(n: int) -> None:
    rng = np.random.default_rng(n)
    pts = np.c_[rng.uniform(-0.6, 0.6, (2000, 2)), np.ones(2000)]
    d = _coeffs(n, n + 10)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, d)
    u, v = project_normalized(K, Distortion.from_coeffs(d), pts[:, 0], pts[:, 1])
    assert np.abs(u - ref[:, 0, 0]).max() < 1e-9
    assert np.abs(v - ref[:, 0, 1]).max() < 1e-9


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_jacobian_matches_finite_differences(n: int) -> None:
    dist = Distortion.from_coeffs(_coeffs(n, 3 * n))
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-0.5, 0.5, (2, 500))
    _, _, (jxx, jxy, jyx, jyy) = dist.distort_with_jacobian(x, y)
    h = 1e-6
    xp, yp = dist.distort(x + h, y)
    xm, ym = dist.distort(x - h, y)
    assert np.allclose(jxx, (xp - xm) / (2 * h), atol=1e-7)
    assert np.allclose(jyx, (yp - ym) / (2 * h), atol=1e-7)
    xp, yp = dist.distort(x, y + h)
    xm, ym = dist.distort(x, y - h)
    assert np.allclose(jxy, (xp - xm) / (2 * h), atol=1e-7)
    assert np.allclose(jyy, (yp - ym) / (2 * h), atol=1e-7)


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_inverse_converges_to_tolerance(n: int) -> None:
    dist = Distortion.from_coeffs(_coeffs(n, 7 * n))
    rng = np.random.default_rng(2)
    x, y = rng.uniform(-0.6, 0.6, (2, 3000))
    u, v = project_normalized(K, dist, x, y)
    res = undistort_pixels(K, dist, u, v)
    assert res.n_failed == 0
    u2, v2 = project_normalized(K, dist, res.x, res.y)
    assert np.hypot(u2 - u, v2 - v).max() <= 1e-6
    assert np.abs(res.x - x).max() < 1e-6 / 1400 * 2


@pytest.mark.parametrize("n", [5, 8, 14])
def test_a_given_start_meets_the_same_tolerance(n: int) -> None:
    """``start``: from a close guess (the truth off by 1e-4) the solution without it; from a bad one
    (off by 0.3) the points that do not converge restart from ``K^-1 (u, v)``: either way every
    point reprojects within 1e-6 px, NaN input stays NaN. From a close guess one Newton step."""
    dist = Distortion.from_coeffs(_coeffs(n, 7 * n))
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-0.6, 0.6, (2, 3000))
    u, v = project_normalized(K, dist, x, y)
    u[:3] = np.nan
    free = undistort_pixels(K, dist, u, v)
    for off in (1e-4, 0.3):
        res = undistort_pixels(K, dist, u, v, start=(x + off, y - off))
        assert res.n_failed == 0 and np.isnan(res.x[:3]).all() and res.converged[3:].all()
        u2, v2 = project_normalized(K, dist, res.x[3:], res.y[3:])
        assert np.hypot(u2 - u[3:], v2 - v[3:]).max() <= 1e-6
        if off < 1e-3:  # a bad start may find another preimage where the model folds over
            assert np.abs(res.x[3:] - free.x[3:]).max() * 1400 < 2e-6
    if n != 14:  # the undamped kernel (untilted models): one step from the close guess
        close = undistort_pixels(K, dist, u[3:], v[3:], start=(x[3:] + 1e-5, y[3:] - 1e-5))
        assert close.iterations == 1 < undistort_pixels(K, dist, u[3:], v[3:]).iterations


def test_strong_distortion_beats_opencv_default_iterations() -> None:
    """Strong barrel distortion: OpenCV's five iterations leave pixels of error, ours 1e-6 px."""
    d = np.array([-0.35, 0.12, 0.001, -0.001, -0.02])
    dist = Distortion.from_coeffs(d)
    x, y = np.meshgrid(np.linspace(-0.7, 0.7, 41), np.linspace(-0.5, 0.5, 31))
    u, v = project_normalized(K, dist, x, y)
    res = undistort_pixels(K, dist, u, v)
    assert res.n_failed == 0
    assert np.abs(res.x - x).max() * 1400 < 1e-5
    cv = cv2.undistortPoints(np.c_[u.ravel(), v.ravel()][:, None, :], K, d)[:, 0, :]
    assert np.abs(cv[:, 0] - x.ravel()).max() * 1400 > 0.1  # OpenCV's default is pixels off


def test_points_without_solution_are_reported() -> None:
    """Rational model r_d = r / (1 + r^2) never exceeds 0.5: r_d = 0.8 has no solution."""
    dist = Distortion.from_coeffs([0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    u = np.array([1010.0 + 0.3 * 1400, 1010.0 + 0.8 * 1400, np.nan])
    v = np.array([770.0, 770.0, 770.0])
    res = undistort_pixels(K, dist, u, v, max_iter=30)
    assert res.converged.tolist() == [True, False, False]
    assert res.failed.tolist() == [False, True, False]
    assert res.n_failed == 1
    assert np.isfinite(res.x[0]) and np.isnan(res.x[1]) and np.isnan(res.x[2])


@pytest.mark.parametrize("bad", [[0.1], [0.1, 0.2, 0.3], [0.0] * 6, [0.0] * 13, [0.1, np.nan, 0, 0]])
def test_bad_coefficient_counts_are_named(bad: list[float]) -> None:
    with pytest.raises(ValueError, match="projector dist"):
        check_dist(bad, "projector dist")


def test_absent_or_empty_is_identity() -> None:
    assert Distortion.from_coeffs(None).is_identity
    assert Distortion.from_coeffs([]).is_identity
