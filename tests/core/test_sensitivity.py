"""Systematic-error analysis (paper section 3) against the exact model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.sensitivity import relative_height_error, sensitivity_curves

RIG = PAPER_RIG.with_parameters(width_px=160, height_px=120)


@pytest.fixture(scope="module")
def curves() -> dict:
    return sensitivity_curves(RIG, None, z_mm=40.0, n=21)


def test_output_is_strict_json(curves: dict) -> None:
    text = json.dumps(curves, allow_nan=False)
    assert set(json.loads(text)["params"]) == {"L", "d", "alpha"}
    assert len(curves["params"]["L"]["relative_error"]) == 21
    assert len(curves["params"]["L"]["exact"]) == len(curves["columns_px"])


def test_zero_error_gives_zero_height_error() -> None:
    for p in ("L", "d", "alpha"):
        err = relative_height_error(RIG, p, [0.0], z_mm=40.0)
        assert np.nanmax(np.abs(err)) < 1e-12


def test_exact_L_coefficient_is_about_one_not_two(curves: dict) -> None:
    e = curves["params"]["L"]
    # Eq. 23 (constant C2, d >> C2 L) says 2; Eq. 22 with constant C2 says 2 - D/(d + D) ~ 1.96
    assert e["coefficient_eq23"] == 2.0
    assert all(c == pytest.approx(1.9608, abs=2e-3) for c in e["coefficient_eq22"])
    # the exact model (gamma and C1 move with L): ~1.0 at the centre, 1.13 .. 0.87 across X
    assert e["coefficient_exact_centre"] == pytest.approx(1.0, abs=0.01)
    lo, hi = e["coefficient_exact_range"]
    assert 0.85 < lo < 0.9 and 1.1 < hi < 1.15
    assert e["eq23_holds"] is False
    assert "not Eq. 23's 2" in curves["finding"]
    # the curve is nearly linear over -10..+10 % with that slope
    assert e["linear_fit_slope_exact_centre"] == pytest.approx(e["coefficient_exact_centre"], abs=0.01)


def test_exact_L_is_eq22_with_moving_c2() -> None:
    # Re-triangulating with L_e: z_e = L_e D_e / (d + D_e); with D_e = D (C2 ~ 1/L) the error is L_e/L - 1.
    err = relative_height_error(RIG, "L", [0.05], z_mm=40.0)[0]
    centre = np.nanargmin(np.abs(RIG.column_x_mm() - RIG.d_mm))
    assert err[centre] == pytest.approx(0.05, abs=0.002)


def test_d_coefficient_close_to_minus_one(curves: dict) -> None:
    e = curves["params"]["d"]
    assert e["coefficient_exact_centre"] == pytest.approx(-1.0, abs=0.06)
    assert e["eq25_holds"] is True
    # Eq. 25 and the exact curve agree at the column of the field centre within 0.5 % of dd/d
    exact = np.array(e["exact"], dtype=float)
    eq25 = np.array(e["eq25"], dtype=float)
    mid = len(curves["columns_px"]) // 2
    assert np.max(np.abs(exact[mid] - eq25[mid])) < 0.005


def test_alpha_slope_along_x_grows_with_j(curves: dict) -> None:
    e = curves["params"]["alpha"]
    assert e["monotonic_in_j"] is True
    rel = np.array(e["relative_error"])
    slopes = np.array(e["slope_along_x_per_mm"])
    assert np.all(np.sign(slopes[rel != 0]) == np.sign(rel[rel != 0]))
    assert np.all(np.diff(slopes) > 0)  # steeper tilt for larger dalpha/alpha
    coeff = np.array(e["coefficient_exact"], dtype=float)
    assert np.all(np.diff(coeff) > 0)  # Fig. 6: the higher j, the higher the influence
    assert abs(slopes[-1]) > 1e-4  # dz/z tilts by > 1e-4 per mm at dalpha/alpha = 40 %


def test_single_parameter_and_columns() -> None:
    out = sensitivity_curves(RIG, "alpha", n=5, columns=[10, 80, 150])
    assert list(out["params"]) == ["alpha"]
    assert out["columns_px"] == [10, 80, 150]
    assert out["params"]["alpha"]["relative_error"] == pytest.approx([-0.4, -0.2, 0.0, 0.2, 0.4])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"param": "FW"}, "param"),
        ({"n": 2}, "n must"),
        ({"z_mm": 0.0}, "z_mm"),
        ({"z_mm": 2000.0}, "z_mm"),
        ({"columns": [0, 999]}, "columns"),
        ({"row": -1}, "row"),
    ],
)
def test_bad_arguments(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        sensitivity_curves(RIG, **kwargs)
