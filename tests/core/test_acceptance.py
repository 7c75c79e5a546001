"""VDI/VDE 2634-2 acceptance quantities on analytic points and on exact noisy code maps."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrology.core.acceptance import (
    fit_plane,
    fit_sphere,
    flatness_error,
    points_from_height_map,
    probing_error,
    sphere_spacing_error,
)
from metrology.core.geometry.crossed_axes import PAPER_RIG, height_from_codes
from metrology.core.synthetic import add_code_noise, exact_codes, reference_codes, sphere_heights


def _sphere_cap(rng, center, radius, n=5000, max_polar=1.2, sigma=0.0):
    polar = np.arccos(rng.uniform(np.cos(max_polar), 1.0, n))
    azim = rng.uniform(0, 2 * np.pi, n)
    r = radius + sigma * rng.standard_normal(n)
    u = np.column_stack([np.sin(polar) * np.cos(azim), np.sin(polar) * np.sin(azim), np.cos(polar)])
    return np.asarray(center) + r[:, None] * u


def test_plane_fit_recovers_tilted_plane() -> None:
    rng = np.random.default_rng(0)
    xy = rng.uniform(-100, 100, (4000, 2))
    z = 40.0 + 0.01 * xy[:, 0] - 0.02 * xy[:, 1] + 0.01 * rng.standard_normal(4000)
    pts = np.column_stack([xy, z])
    fit = fit_plane(pts)
    expected = np.array([-0.01, 0.02, 1.0]) / np.linalg.norm([-0.01, 0.02, 1.0])
    assert fit.normal == pytest.approx(expected, abs=1e-4)
    out = flatness_error(pts)
    # range of 4000 Gaussian samples of sigma 10 um: about 7 sigma
    assert 0.05 < out["flatness_mm"] < 0.09
    assert out["rms_mm"] == pytest.approx(0.01 / np.linalg.norm([-0.01, 0.02, 1.0]), rel=0.05)
    assert out["n_rejected"] == 12 and out["flatness_rejected_mm"] < out["flatness_mm"]
    json.dumps(out, allow_nan=False)


def test_outlier_rejection_removes_gross_errors() -> None:
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-50, 50, (2000, 2)), 0.005 * rng.standard_normal(2000)])
    pts[:5, 2] += 2.0  # 0.25 % gross outliers
    out = flatness_error(pts)
    assert out["flatness_mm"] > 1.9
    assert out["flatness_rejected_mm"] < 0.05


@pytest.mark.parametrize("sigma", [0.0, 0.02])
def test_sphere_fit_on_a_cap(sigma: float) -> None:
    rng = np.random.default_rng(2)
    pts = _sphere_cap(rng, (10.0, -5.0, 30.0), 25.0, sigma=sigma)
    fit = fit_sphere(pts)
    tol = 1e-9 if sigma == 0 else 3e-3
    assert fit.radius == pytest.approx(25.0, abs=tol)
    assert fit.center == pytest.approx([10.0, -5.0, 30.0], abs=2 * tol)
    out = probing_error(pts, 50.0)
    assert abs(out["size_error_mm"]) < 2 * tol + 1e-9
    if sigma:
        assert 5 * sigma < out["form_error_mm"] < 9 * sigma
        assert out["form_error_rejected_mm"] < out["form_error_mm"]
        assert out["rms_mm"] == pytest.approx(sigma, rel=0.05)


def test_geometric_refinement_beats_algebraic_fit_on_noisy_cap() -> None:
    rng = np.random.default_rng(3)
    pts = _sphere_cap(rng, (0.0, 0.0, 0.0), 10.0, n=3000, max_polar=0.5, sigma=0.2)
    fit = fit_sphere(pts)
    assert abs(fit.radius - 10.0) < abs(fit.algebraic_radius - 10.0)


def test_sphere_spacing() -> None:
    rng = np.random.default_rng(4)
    a = _sphere_cap(rng, (0.0, 0.0, 0.0), 20.0, sigma=0.01)
    b = _sphere_cap(rng, (200.0, 30.0, 10.0), 20.0, sigma=0.01)
    out = sphere_spacing_error(a, b, float(np.linalg.norm([200.0, 30.0, 10.0])))
    assert abs(out["spacing_error_mm"]) < 2e-3
    assert abs(out["spacing_error_rejected_mm"]) < 2e-3


def test_rendered_sphere_radius_50_at_realistic_noise() -> None:
    rig = PAPER_RIG.with_parameters(width_px=320, height_px=240)
    rng = np.random.default_rng(5)
    z_true = sphere_heights(rig, (352.0, 0.0, 50.0), 50.0)
    z = height_from_codes(
        rig, add_code_noise(rig, reference_codes(rig), rng), add_code_noise(rig, exact_codes(rig, z_true), rng)
    )
    pts = points_from_height_map(rig, z, mask=z_true > 5.0)
    out = probing_error(pts, 100.0)
    assert abs(out["size_error_mm"]) < 0.05  # the bar: under 50 um
    assert out["form_error_rejected_mm"] <= out["form_error_mm"]
    assert 0.1 < out["form_error_mm"] < 1.5  # range of ~0.1 mm-sigma height noise on thousands of points


def test_two_rendered_spheres_spacing() -> None:
    rig = PAPER_RIG.with_parameters(width_px=320, height_px=240)
    rng = np.random.default_rng(6)
    ca, cb = (250.0, 0.0, 40.0), (450.0, 0.0, 40.0)
    za, zb = sphere_heights(rig, ca, 40.0), sphere_heights(rig, cb, 40.0)
    z_true = np.where(za > 0, za, zb)
    z = height_from_codes(
        rig, add_code_noise(rig, reference_codes(rig), rng), add_code_noise(rig, exact_codes(rig, z_true), rng)
    )
    pa = points_from_height_map(rig, z, mask=za > 5.0)
    pb = points_from_height_map(rig, z, mask=zb > 5.0)
    out = sphere_spacing_error(pa, pb, 200.0)
    assert abs(out["spacing_error_mm"]) < 0.05


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        flatness_error(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="at least 4"):
        probing_error(np.zeros((3, 3)), 10.0)
    with pytest.raises(ValueError, match="degenerate"):
        fit_sphere(np.column_stack([np.random.default_rng(0).uniform(size=(50, 2)), np.zeros(50)]))
    with pytest.raises(ValueError, match="diameter_mm"):
        probing_error(np.ones((10, 3)), -1.0)
    with pytest.raises(ValueError, match="reject_frac"):
        flatness_error(np.ones((10, 3)), reject_frac=0.7)
    with pytest.raises(ValueError, match="spacing_mm"):
        sphere_spacing_error(np.ones((10, 3)), np.ones((10, 3)), 0.0)
