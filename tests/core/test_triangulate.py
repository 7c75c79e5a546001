"""Eq. 14 (code to abscissa), Eqs. 16-17 (heights) and the 3D points of docs/conventions.md."""

import math

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import (
    PAPER_RIG,
    Rig,
    abscissa_from_codes,
    abscissa_from_codes_eq14,
    codes_from_abscissa,
    displacement_from_codes,
    height_from_abscissae,
    height_from_codes,
    points_from_heights,
)

RIGS = [
    PAPER_RIG,
    Rig(L_mm=1080.0, d_mm=352.0, alpha_rad=0.4871, fw_mm=500.0, nlp=128, width_px=64, height_px=48),
    Rig(L_mm=600.0, d_mm=150.0, alpha_rad=0.9, fw_mm=400.0, nlp=100, width_px=64, height_px=48),  # gamma < 0
]


@pytest.mark.parametrize("rig", RIGS)
def test_codes_0_and_nlp_map_to_field_edges(rig):
    x = abscissa_from_codes(rig, np.array([0.0, rig.nlp]))
    np.testing.assert_allclose(x, [rig.d_mm - rig.fw_mm / 2, rig.d_mm + rig.fw_mm / 2], atol=1e-9)


@pytest.mark.parametrize("rig", RIGS)
def test_mobius_equals_eq14(rig):
    codes = np.linspace(-5, rig.nlp + 5, 2001)
    np.testing.assert_allclose(abscissa_from_codes(rig, codes), abscissa_from_codes_eq14(rig, codes), atol=1e-9)


@pytest.mark.parametrize("rig", RIGS)
def test_code_abscissa_round_trip(rig):
    codes = np.random.default_rng(1).uniform(0, rig.nlp, 1000)
    np.testing.assert_allclose(codes_from_abscissa(rig, abscissa_from_codes(rig, codes)), codes, atol=1e-9)


@pytest.mark.parametrize("rig", RIGS)
def test_eq14_is_the_tilted_line_geometry(rig):
    """Codes are linear along a line through S at angle alpha to R, ending on ray PT (Fig. 3)."""
    L, fw, d, a = rig.L_mm, rig.fw_mm, rig.d_mm, rig.alpha_rad
    s_x, t_x = d - fw / 2, d + fw / 2
    direction = np.array([math.cos(a), math.sin(a)])  # the line S T', rising away from S

    def hit(x_on_r):  # where ray P -> (x_on_r, 0) crosses the line S + u * direction
        ray = np.array([x_on_r, -L])  # from P = (0, L)
        m = np.array([[direction[0], -ray[0]], [direction[1], -ray[1]]])
        u, _ = np.linalg.solve(m, np.array([0 - s_x, L - 0]))
        return u

    u_total = hit(t_x)
    for x in np.linspace(s_x, t_x, 17):
        code = rig.nlp * hit(x) / u_total
        assert abscissa_from_codes(rig, code) == pytest.approx(x, abs=1e-9)


@pytest.mark.parametrize("rig", RIGS)
def test_displacement_is_the_difference_of_abscissae_without_cancellation(rig):
    rng = np.random.default_rng(5)
    ref, obj = rng.uniform(0, rig.nlp, 10_000), rng.uniform(0, rig.nlp, 10_000)
    exact = abscissa_from_codes(rig, obj) - abscissa_from_codes(rig, ref)
    np.testing.assert_allclose(displacement_from_codes(rig, ref, obj), exact, rtol=0, atol=1e-9)
    # float32: the displacement keeps the codes' relative precision (a few ulp of D), where the
    # difference of two float32 abscissae of ~500 mm is off by up to ~3e-5 mm whatever D is
    ref32 = ref.astype(np.float32)
    obj32 = np.clip(ref + rng.uniform(-3, 3, ref.size), 0, rig.nlp).astype(np.float32)
    d32 = displacement_from_codes(rig, ref32, obj32)
    assert d32.dtype == np.float32
    exact32 = abscissa_from_codes(rig, obj32.astype(float)) - abscissa_from_codes(rig, ref32.astype(float))
    np.testing.assert_allclose(d32, exact32, rtol=1e-6, atol=1e-9)


def test_eq17_exact_for_points_on_camera_rays():
    rig = PAPER_RIG
    z = np.random.default_rng(2).uniform(0, 150, rig.shape)
    x_a = np.broadcast_to(rig.column_x_mm(), rig.shape)
    x_h = rig.d_mm + (1 - z / rig.L_mm) * (x_a - rig.d_mm)
    x_b = x_h * rig.L_mm / (rig.L_mm - z)  # projector ray through H meets R at B
    np.testing.assert_allclose(height_from_abscissae(rig, x_a, x_b), z, atol=1e-9)
    ref, obj = codes_from_abscissa(rig, x_a), codes_from_abscissa(rig, x_b)
    np.testing.assert_allclose(height_from_codes(rig, ref, obj), z, atol=1e-9)
    z32 = height_from_codes(rig, ref.astype(np.float32), obj.astype(np.float32))
    assert z32.dtype == np.float32
    np.testing.assert_allclose(z32, z, atol=2e-3)  # float32 codes carry ~1e-5 code units


def test_nan_propagates():
    z = height_from_codes(PAPER_RIG, np.array([10.0, np.nan]), np.array([np.nan, 10.0]))
    assert np.all(np.isnan(z))


def test_points_lie_on_camera_rays():
    rig = PAPER_RIG
    z = np.full(rig.shape, 40.0)
    z[0, 0] = np.nan
    xyz = points_from_heights(rig, z)
    assert xyz.shape == (*rig.shape, 3)
    assert np.isnan(xyz[0, 0]).all()
    camera = np.array([rig.d_mm, 0.0, rig.L_mm])
    a = np.array([rig.column_x_mm()[5], rig.row_y_mm()[7], 0.0])
    h = xyz[7, 5]
    np.testing.assert_allclose(np.cross(h - camera, a - camera), 0, atol=1e-9)
    assert h[2] == 40.0


def test_points_shape_checked():
    with pytest.raises(ValueError, match="rig's shape"):
        points_from_heights(PAPER_RIG, np.zeros((3, 3)))
