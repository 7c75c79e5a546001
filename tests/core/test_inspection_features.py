"""Feature fits (metrology.core.inspection.features) against analytic truth.

- Points exactly on a plane, sphere, cylinder, circle: the fits return the primitive to 1e-9
  (relative to its size) and a zero form error.
- A sinusoidal ripple of amplitude a (k whole waves along the plane, around the circle, the
  cylinder or the sphere's latitude circles): the minimum zone is 2a (the extremes of the ripple
  touch the zone's two surfaces; the points sample the crests exactly for the plane, circle and
  cylinder, to within 1e-3 of a for the sphere's random points), while the least-squares peak to
  valley is larger or equal.
- Noisy points: the predicted standard deviation of each parameter within 20 % of the scatter of
  the fitted values over 300 draws (the scatter of a 300-sample standard deviation is about 4 %).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.core.inspection.features import (
    KINDS,
    compare_with_nominal,
    feature_residuals,
    fit_circle,
    fit_cylinder,
    fit_feature,
    fit_plane,
    fit_sphere,
)

RNG_SEED = 20261202
ROTATION = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))[0]
SHIFT = np.array([120.0, -35.0, 610.0])


def _place(local: np.ndarray) -> np.ndarray:
    """Points of the local frame moved by a fixed, generic rotation and shift."""
    return local @ ROTATION.T + SHIFT


def _plane_points(amplitude: float = 0.0, periods: int = 4) -> np.ndarray:
    x, y = np.meshgrid(np.linspace(0.0, 40.0, 81), np.linspace(0.0, 30.0, 31))
    z = amplitude * np.sin(2 * np.pi * periods * x / 40.0)
    return _place(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1))


def _sphere_points(radius: float, amplitude: float = 0.0, n: int = 600, seed: int = 1) -> np.ndarray:
    u = np.random.default_rng(seed).normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u = u[u[:, 2] > 0.1]  # a cap, as a scan sees it
    phi = np.arctan2(u[:, 1], u[:, 0])
    return _place((radius + amplitude * np.cos(4 * phi))[:, None] * u)


def _cylinder_points(radius: float, amplitude: float = 0.0) -> np.ndarray:
    angle, height = np.meshgrid(np.linspace(0.0, np.pi, 61), np.linspace(-15.0, 15.0, 21))
    rho = radius + amplitude * np.cos(6 * angle)  # crests at 0, pi/3, ..., pi; troughs between
    return _place(np.stack([(rho * np.cos(angle)).ravel(), (rho * np.sin(angle)).ravel(), height.ravel()], axis=1))


def _circle_points(radius: float, amplitude: float = 0.0, n: int = 120) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    rho = radius + amplitude * np.cos(5 * angle)
    return _place(np.stack([rho * np.cos(angle), rho * np.sin(angle), np.zeros(n)], axis=1))


def _close(a, b, scale: float) -> None:
    np.testing.assert_allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0, atol=1e-9 * scale)


def test_exact_plane():
    fit = fit_plane(_plane_points())
    normal = ROTATION[:, 2]
    assert abs(abs(float(np.array(fit.geometry["normal"]) @ normal)) - 1) < 1e-12
    assert abs(float((np.array(fit.geometry["point_mm"]) - SHIFT) @ normal)) < 1e-9 * 40
    assert fit.form_mm < 1e-9 * 40 and fit.rms_mm < 1e-9 * 40


def test_exact_sphere():
    fit = fit_sphere(_sphere_points(12.5))
    _close(fit.geometry["centre_mm"], SHIFT, 12.5)
    _close(fit.radius_mm, 12.5, 12.5)
    assert fit.form_mm < 1e-9 * 12.5


def test_exact_cylinder():
    fit = fit_cylinder(_cylinder_points(8.0))
    axis = np.array(fit.geometry["axis_direction"])
    assert abs(abs(float(axis @ ROTATION[:, 2])) - 1) < 1e-12
    d = np.array(fit.geometry["axis_point_mm"]) - SHIFT  # the axis passes through SHIFT
    assert np.linalg.norm(d - (d @ axis) * axis) < 1e-9 * 8
    _close(fit.radius_mm, 8.0, 8.0)
    assert fit.form_mm < 1e-9 * 8


def test_exact_circle():
    fit = fit_circle(_circle_points(6.0))
    _close(fit.geometry["centre_mm"], SHIFT, 6.0)
    _close(fit.radius_mm, 6.0, 6.0)
    assert abs(abs(float(np.array(fit.geometry["normal"]) @ ROTATION[:, 2])) - 1) < 1e-12
    assert fit.form_mm < 1e-9 * 6


@pytest.mark.parametrize(
    ("kind", "points", "tolerance"),
    [
        ("plane", lambda a: _plane_points(a), 1e-9),
        ("circle", lambda a: _circle_points(6.0, a), 1e-9),
        ("cylinder", lambda a: _cylinder_points(8.0, a), 1e-9),
        ("sphere", lambda a: _sphere_points(12.5, a, n=4000), 2e-3),
    ],
)
def test_ripple_of_amplitude_a_gives_a_form_error_of_2a(kind, points, tolerance):
    a = 0.01
    fit = fit_feature(kind, points(a))
    assert fit.zone is not None and fit.zone.converged
    assert fit.form_mm == pytest.approx(2 * a, rel=tolerance, abs=0)
    assert fit.peak_to_valley_mm >= fit.form_mm - 1e-12
    assert fit.to_dict()["form"] == {"name": fit.form_name, "value_mm": fit.form_mm, "method": "minimum_zone"}


def test_a_tilted_noisy_plane_zone_is_narrower_than_least_squares():
    """On random points the minimum zone is a feasible zone (all points within it) of width at most
    the least-squares peak to valley."""
    rng = np.random.default_rng(RNG_SEED)
    points = _plane_points() + rng.normal(0, 0.005, size=(31 * 81, 3))
    fit = fit_plane(points)
    assert fit.zone is not None
    assert fit.form_mm <= fit.peak_to_valley_mm
    n = np.array(fit.zone.geometry["normal"])
    r = (points - np.array(fit.zone.geometry["point_mm"])) @ n
    assert np.ptp(r) == pytest.approx(fit.form_mm, rel=1e-12)


NOISE_MM = 0.01
DRAWS = 300


def _scatter_and_prediction(
    kind: str, make, names: tuple[str, ...], with_sigma: bool, draws: int = DRAWS, **kw
) -> None:
    rng = np.random.default_rng(RNG_SEED)
    base = make()
    values, predicted = [], []
    fitter = fit_cylinder if kind == "cylinder" else lambda *a, **k: fit_feature(kind, *a, **k)
    for _ in range(draws):
        points = base + rng.normal(0, NOISE_MM, size=base.shape)  # isotropic: NOISE_MM along any normal
        sigma = np.full(len(points), NOISE_MM) if with_sigma else None
        fit = fitter(points, sigma, minimum_zone=False, **kw)
        g = fit.geometry
        values.append(
            [
                g["radius_mm"] if name == "radius_mm" else float(np.array(g["point_mm"]) @ ROTATION[:, 2])
                for name in names
            ]
        )
        predicted.append([fit.std[name] for name in names])
    observed = np.std(np.array(values), axis=0, ddof=1)
    expected = np.mean(np.array(predicted), axis=0)
    ratio = expected / observed
    print(kind, names, "predicted/observed", ratio)
    assert np.all(np.abs(ratio - 1) < 0.2), ratio


@pytest.mark.parametrize("with_sigma", [False, True])
def test_predicted_std_matches_scatter_sphere(with_sigma):
    _scatter_and_prediction("sphere", lambda: _sphere_points(12.5, n=300), ("radius_mm",), with_sigma)


@pytest.mark.parametrize("with_sigma", [False, True])
def test_predicted_std_matches_scatter_plane(with_sigma):
    x, y = np.meshgrid(np.linspace(-20.0, 20.0, 15), np.linspace(-15.0, 15.0, 11))  # centred: offset at the centroid
    local = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    _scatter_and_prediction("plane", lambda: _place(local), ("offset_mm",), with_sigma)


def test_predicted_std_matches_scatter_cylinder_and_circle():
    """(The cylinder from a hint of its axis and 120 draws, to keep the test short: the scatter of a
    120-sample standard deviation is about 7 %.)"""
    _scatter_and_prediction(
        "cylinder", lambda: _cylinder_points(8.0)[::3], ("radius_mm",), False, draws=120, axis_hint=ROTATION[:, 2]
    )
    _scatter_and_prediction("circle", lambda: _circle_points(6.0, n=60), ("radius_mm",), False)


def test_zone_uncertainty_with_sigma_is_that_of_the_two_contacts():
    points = _circle_points(6.0, 0.01)
    sigma = np.linspace(0.001, 0.002, len(points))
    fit = fit_circle(points, sigma)
    assert fit.zone is not None
    r = feature_residuals(fit, points)  # unsigned distance to the LS circle; contacts are the crest/troughs
    assert fit.sigma_given and math.isfinite(fit.zone.u_width_mm)
    assert 0.001 * math.sqrt(2) <= fit.zone.u_width_mm <= 0.002 * math.sqrt(2)
    assert r.max() < 0.011


def _uv_sphere(radius: float, centre: np.ndarray, rings: int = 24, sectors: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A tessellated sphere whose vertices lie exactly on it."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, sectors, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    vertices = centre + radius * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    faces = []
    for i in range(rings - 2):
        for j in range(sectors):
            a, b = 1 + i * sectors + j, 1 + i * sectors + (j + 1) % sectors
            faces += [[a, a + sectors, b], [b, a + sectors, b + sectors]]
    return vertices, np.array(faces)


def test_compare_with_nominal_sphere():
    """A measured sphere 20 um larger than the nominal, 5 um off its centre: the nominal's radius
    comes from its vertices, and the differences are the planted ones."""
    centre = np.array([10.0, 20.0, 600.0])
    vertices, faces = _uv_sphere(12.5, centre)
    points = _sphere_points(12.52) - SHIFT + centre + np.array([0.005, 0.0, 0.0])
    comparison = compare_with_nominal(fit_sphere(points), vertices, faces, band_mm=0.5)
    assert comparison.nominal.radius_mm == pytest.approx(12.5, abs=1e-9)
    assert comparison.quantity("radius_mm").difference == pytest.approx(0.02, abs=1e-9)
    assert comparison.quantity("centre_offset_mm").measured == pytest.approx(0.005, abs=1e-9)
    assert comparison.quantity("sphericity_mm").nominal < 1e-9
    assert comparison.to_dict()["quantities"][0]["name"] == "radius_mm"


def test_compare_with_nominal_plane():
    """A box face as two triangles; the measured plane 0.1 mm above it and tilted 0.01 degree."""
    vertices = np.array([[0, 0, 0], [40, 0, 0], [40, 30, 0], [0, 30, 0], [0, 0, -10]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    tilt = math.radians(0.01)
    x, y = np.meshgrid(np.linspace(5, 35, 31), np.linspace(5, 25, 21))
    points = np.stack([x.ravel(), y.ravel(), 0.1 + (x.ravel() - 20) * math.tan(tilt)], axis=1)
    comparison = compare_with_nominal(fit_plane(points), vertices, faces, band_mm=0.5)
    assert comparison.vertices_used == 4
    assert comparison.quantity("offset_mm").measured == pytest.approx(0.1, abs=1e-9)
    assert comparison.quantity("tilt_deg").measured == pytest.approx(0.01, abs=1e-9)


def test_bad_input_is_refused_with_a_message():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        fit_plane(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="at least 4"):
        fit_sphere(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="sigma_mm must have shape"):
        fit_plane(np.eye(3), np.ones(2))
    with pytest.raises(ValueError, match="unknown feature"):
        fit_feature("cone", np.eye(3))
    assert set(KINDS) == {"plane", "sphere", "cylinder", "circle"}
