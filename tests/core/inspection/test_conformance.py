"""Conformance decisions at their thresholds (worked by hand) and the projection of a ray sigma
onto the normal."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.inspection.conformance import (
    CONFORMING,
    NONCONFORMING,
    UNDECIDED,
    combined_uncertainty,
    counts,
    decide,
    point_uncertainty,
)


def test_thresholds_with_t_0_1_k_2_u_0_01() -> None:
    """T = 0.1, k u = 0.02: conforming up to |dev| = 0.08, nonconforming beyond 0.12."""
    deviation = np.array([0.0, 0.08, -0.08, 0.0801, 0.12, -0.12, 0.1201, -0.13, np.nan])
    decision = decide(deviation, np.full(deviation.size, 0.01), 0.1, 2.0)
    expected = [
        CONFORMING,
        CONFORMING,
        CONFORMING,
        UNDECIDED,
        UNDECIDED,
        UNDECIDED,
        NONCONFORMING,
        NONCONFORMING,
        UNDECIDED,
    ]
    np.testing.assert_array_equal(decision, expected)
    assert counts(decision) == {"conforming": 3, "nonconforming": 2, "undecided": 4}


def test_unknown_uncertainty_is_undecided_and_k_0_decides_everything() -> None:
    assert decide(np.array([0.0]), np.array([np.nan]), 0.1)[0] == UNDECIDED
    np.testing.assert_array_equal(decide(np.array([0.1, 0.1001]), np.array([1.0, 1.0]), 0.1, 0.0), [1, -1])
    with pytest.raises(ValueError, match="tolerance"):
        decide(np.array([0.0]), np.array([0.0]), 0.0)


def test_ray_sigma_is_projected_onto_the_normal() -> None:
    """A ray along +z and normals at 0, 60 and 90 degrees: sigma 0.01 becomes 0.01, 0.005 and 0."""
    angles = np.radians([0.0, 60.0, 90.0])
    normals = np.stack([np.sin(angles), np.zeros(3), np.cos(angles)], axis=1)
    rays = np.tile([0.0, 0.0, 250.0], (3, 1))
    u = point_uncertainty(np.full(3, 0.01), normals, rays=rays)
    np.testing.assert_allclose(u, [0.01, 0.005, 0.0], atol=1e-15)
    np.testing.assert_allclose(point_uncertainty(np.full(3, 0.01), normals), 0.01)  # PLY: as is
    np.testing.assert_allclose(point_uncertainty(None, normals), 0.0)


def test_combined_uncertainty_adds_in_quadrature() -> None:
    np.testing.assert_allclose(combined_uncertainty(np.array([0.003]), np.array([0.004]), 0.012), [0.013])
