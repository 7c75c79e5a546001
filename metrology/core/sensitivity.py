"""Systematic height errors caused by wrong estimates of L, d and alpha (paper section 3).

For a surface at constant height ``z`` the exact reference and object codes are
built from the true rig (:mod:`metrology.core.synthetic`), then re-triangulated
(Eqs. 14, 16, 17) with one parameter replaced by its estimate. The relative error
``dz/z = z_e/z - 1`` is computed per pixel column ``j`` (along X) and compared
with the paper's closed forms:

- Eq. 22: ``(C2 Le^2 / (d + C2 Le)) / (C2 L^2 / (d + C2 L)) - 1`` with ``C2 = D_R / L``
  (Eq. 20) held constant;
- Eq. 23: ``(Le / L)^2 - 1 = 2 dL/L + (dL/L)^2`` (Eq. 22 with ``d >> C2 L``);
- Eq. 25: ``-(dd/d) / (1 + dd/d + D_R/d)``;
- alpha has no closed form (Fig. 6): the exact model is the paper's own method.

Finding (reported in the output under ``"finding"``): Eq. 23's coefficient 2
does **not** hold for the exact model. The constants of Eq. 14 depend on L:
``gamma = atan((d - FW/2)/L)`` and ``C1`` move so that codes 0 and nlp stay pinned
to ``x = d -+ FW/2``; ``D_R`` therefore barely changes when L is re-estimated and
``z = L D_R/(d + D_R)`` (Eq. 17) scales as ``L_e^1``, not ``L_e^2``. For the
paper's rig the exact coefficient is ~1.0 at the field centre and varies across
the field (about 1.13 at ``j = 0`` to 0.87 at ``j = N-1``), so an L error also
tilts a flat profile along X -- which matters for the calibration loop of
section 4 (:mod:`metrology.core.calibrate`). Eq. 25's coefficient (~ -1) and the
alpha behaviour of Fig. 6 (error growing with ``j``) are reproduced.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from metrology.core.geometry.crossed_axes import Rig, abscissa_from_codes, height_from_codes
from metrology.core.synthetic import exact_codes, reference_codes

Param = Literal["L", "d", "alpha"]
PARAMS: tuple[Param, ...] = ("L", "d", "alpha")
DEFAULT_RANGES: dict[str, float] = {"L": 0.10, "d": 0.10, "alpha": 0.40}
"""Half-width of the relative-error range per parameter (paper Figs. 4-6)."""
_FIELD = {"L": "L_mm", "d": "d_mm", "alpha": "alpha_rad"}
_EPS = 1e-5


def relative_height_error(
    rig: Rig, param: Param, relative_errors: Sequence[float] | np.ndarray, z_mm: float = 40.0, row: int | None = None
) -> np.ndarray:
    """Exact-model relative height error ``z_e / z - 1`` per relative parameter error and column.

    Parameters
    ----------
    rig : Rig
        The true geometry.
    param : {'L', 'd', 'alpha'}
    relative_errors : (n,) sequence of float
        ``(p_e - p) / p`` values, dimensionless.
    z_mm : float
        Constant true height of the surface, mm, in (0, L).
    row : int, optional
        Image row k (default: the middle row). Codes do not depend on k, heights neither.

    Returns
    -------
    error : (n, width_px) float64 array
        Relative error ``dz/z``, dimensionless; NaN where the surface is outside the coded field.
    """
    _check_param(param)
    z_mm = _check_height(rig, z_mm)
    k = _check_row(rig, row)
    ref = reference_codes(rig)[k]
    obj = exact_codes(rig, z_mm)[k]
    true_value = getattr(rig, _FIELD[param])
    out = np.empty((len(relative_errors), rig.width_px))
    for i, eps in enumerate(np.asarray(relative_errors, dtype=np.float64)):
        estimate = rig.with_parameters(**{_FIELD[param]: true_value * (1.0 + eps)})
        out[i] = height_from_codes(estimate, ref, obj) / z_mm - 1.0
    return out


def sensitivity_curves(
    rig: Rig,
    param: Param | None = None,
    z_mm: float = 40.0,
    n: int = 21,
    columns: Sequence[int] | int | None = None,
    row: int | None = None,
) -> dict[str, Any]:
    """Curves of relative height error versus relative parameter error (Figs. 4-6), as JSON.

    Parameters
    ----------
    rig : Rig
        True geometry.
    param : {'L', 'd', 'alpha'} or None
        One parameter, or all three (None).
    z_mm : float
        Constant height of the surface, mm (default 40).
    n : int
        Number of relative errors, evenly spread over -10..+10 % (L, d) or -40..+40 % (alpha); >= 3.
    columns : int or sequence of int, optional
        Pixel columns for which curves are written: a count spread evenly over the
        columns where the surface is coded (default 9, including both ends of that
        range) or explicit indices (NaN -> None where a column is not coded).
    row : int, optional
        Image row (default: the middle row).

    Returns
    -------
    dict
        JSON-serialisable (plain lists and floats)::

            {"z_mm", "row", "columns_px", "x_mm", "rig": {...},
             "params": {"L": {...}, "d": {...}, "alpha": {...}}, "finding": str}

        Per parameter: ``"relative_error"`` (n,), ``"exact"`` (n_columns lists of n:
        the exact-model curve of each column), ``"coefficient_exact"`` (per column,
        d(dz/z)/d(dp/p) at 0 by central difference), ``"coefficient_exact_centre"``,
        and the closed forms: for L ``"eq22"``, ``"eq23"`` (n) and
        ``"coefficient_eq23"`` = 2, ``"coefficient_eq22"`` (per column); for d ``"eq25"``
        (per column) and ``"coefficient_eq25"`` (per column); for alpha
        ``"slope_along_x_per_mm"`` (n: regression slope of dz/z against X) and
        ``"monotonic_in_j"``.

    Raises
    ------
    ValueError
        For an unknown ``param``, ``n < 3``, a height outside (0, L) or bad columns.
    """
    if param is not None:
        _check_param(param)
    if not isinstance(n, (int, np.integer)) or n < 3:
        raise ValueError(f"n must be an integer >= 3, got {n!r}")
    z_mm = _check_height(rig, z_mm)
    k = _check_row(rig, row)
    x_a = rig.column_x_mm()
    ref = reference_codes(rig)[k]
    obj = exact_codes(rig, z_mm)[k]
    cols = _columns(rig, columns, np.flatnonzero(np.isfinite(obj)))
    d_r = abscissa_from_codes(rig, obj) - abscissa_from_codes(rig, ref)  # Eq. 16

    out: dict[str, Any] = {
        "z_mm": z_mm,
        "row": k,
        "columns_px": cols.tolist(),
        "x_mm": x_a[cols].tolist(),
        "rig": {key: value for key, value in rig.to_dict().items() if key in _RIG_KEYS},
        "params": {},
    }
    for p in PARAMS if param is None else (param,):
        half = DEFAULT_RANGES[p]
        rel = np.linspace(-half, half, n)
        err = relative_height_error(rig, p, rel, z_mm, k)
        deriv = relative_height_error(rig, p, [-_EPS, _EPS], z_mm, k)
        coeff = (deriv[1] - deriv[0]) / (2 * _EPS)
        centre = int(np.argmin(np.abs(x_a - rig.d_mm)))
        entry: dict[str, Any] = {
            "relative_error": rel.tolist(),
            "exact": _lists(err[:, cols].T),
            "coefficient_exact": _lists(coeff[cols]),
            "coefficient_exact_centre": float(coeff[centre]),
            "coefficient_exact_range": [float(np.nanmin(coeff)), float(np.nanmax(coeff))],
            "linear_fit_slope_exact_centre": float(np.polyfit(rel, err[:, centre], 1)[0]),
        }
        if p == "L":
            c2 = d_r / rig.L_mm  # Eq. 20
            le = rig.L_mm * (1 + rel[:, None])
            eq22 = (c2 * le**2 / (rig.d_mm + c2 * le)) / (c2 * rig.L_mm**2 / (rig.d_mm + c2 * rig.L_mm)) - 1
            entry["eq22"] = _lists(eq22[:, cols].T)
            entry["eq23"] = ((1 + rel) ** 2 - 1).tolist()
            entry["coefficient_eq23"] = 2.0
            # d/dLe of Eq. 22 at Le = L, times L
            entry["coefficient_eq22"] = _lists((2 - c2 * rig.L_mm / (rig.d_mm + c2 * rig.L_mm))[cols])
            # how much C2 really moves with L in the exact model (the paper's assumption is 0)
            c2_e = _exact_c2(rig.with_parameters(L_mm=rig.L_mm * (1 + half)), ref, obj)
            entry["c2_relative_change_at_max"] = float(np.nanmedian(c2_e / c2 - 1))
            entry["eq23_holds"] = bool(abs(coeff[centre] - 2.0) < 0.1)
        elif p == "d":
            eq25 = -rel[:, None] / (1 + rel[:, None] + d_r[None, :] / rig.d_mm)
            entry["eq25"] = _lists(eq25[:, cols].T)
            entry["coefficient_eq25"] = _lists((-1 / (1 + d_r / rig.d_mm))[cols])
            entry["eq25_holds"] = bool(abs(coeff[centre] + 1 / (1 + d_r[centre] / rig.d_mm)) < 0.1)
        else:
            valid = np.isfinite(err).all(axis=0)
            slopes = [float(np.polyfit(x_a[valid], e[valid], 1)[0]) for e in err]
            entry["slope_along_x_per_mm"] = slopes
            entry["monotonic_in_j"] = bool(
                all(
                    np.all(np.diff(e[valid]) > 0) if r > 0 else np.all(np.diff(e[valid]) < 0)
                    for e, r in zip(err, rel, strict=True)
                    if r != 0
                )
            )
        out["params"][p] = entry
    out["finding"] = _finding(out["params"])
    return out


_RIG_KEYS = ("L_mm", "d_mm", "alpha_rad", "fw_mm", "nlp", "width_px", "height_px")


def _exact_c2(estimate: Rig, ref: np.ndarray, obj: np.ndarray) -> np.ndarray:
    return (abscissa_from_codes(estimate, obj) - abscissa_from_codes(estimate, ref)) / estimate.L_mm


def _finding(params: dict[str, Any]) -> str:
    parts = []
    if "L" in params:
        e = params["L"]
        lo, hi = e["coefficient_exact_range"]
        parts.append(
            f"L: exact coefficient {e['coefficient_exact_centre']:.3f} at the field centre "
            f"({lo:.3f}..{hi:.3f} across X), not Eq. 23's 2: in the exact model gamma and C1 move with L "
            f"(C2 changes by {100 * e['c2_relative_change_at_max']:+.1f} % at dL/L = +10 %), so height scales "
            "about linearly with L and an L error also tilts a flat profile along X."
        )
    if "d" in params:
        e = params["d"]
        parts.append(
            f"d: exact coefficient {e['coefficient_exact_centre']:.3f} at the centre, Eq. 25 "
            f"{'holds' if e['eq25_holds'] else 'does not hold'} (close to -1)."
        )
    if "alpha" in params:
        e = params["alpha"]
        parts.append(
            "alpha: the error grows with j "
            f"({'monotonically' if e['monotonic_in_j'] else 'not monotonically'}), a slope along X of "
            f"{e['slope_along_x_per_mm'][-1]:.2e}/mm at dalpha/alpha = {e['relative_error'][-1]:+.2f} (Fig. 6)."
        )
    return " ".join(parts)


def _lists(a: np.ndarray) -> list:
    """Nested lists with NaN replaced by None (valid JSON)."""
    return _nan_to_none(np.asarray(a, dtype=np.float64).tolist())


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, list):
        return [_nan_to_none(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _check_param(param: Any) -> None:
    if param not in PARAMS:
        raise ValueError(f"param must be one of {PARAMS} or None, got {param!r}")


def _check_height(rig: Rig, z_mm: float) -> float:
    if not isinstance(z_mm, (int, float, np.floating, np.integer)) or not (0.0 < float(z_mm) < rig.L_mm):
        raise ValueError(f"z_mm must be a number in (0, L = {rig.L_mm}), got {z_mm!r}")
    return float(z_mm)


def _check_row(rig: Rig, row: int | None) -> int:
    if row is None:
        return rig.height_px // 2
    if not isinstance(row, (int, np.integer)) or not (0 <= row < rig.height_px):
        raise ValueError(f"row must be an integer in [0, {rig.height_px}), got {row!r}")
    return int(row)


def _columns(rig: Rig, columns: Sequence[int] | int | None, coded: np.ndarray) -> np.ndarray:
    if columns is None:
        columns = 9
    if isinstance(columns, (int, np.integer)):
        if columns < 1:
            raise ValueError(f"columns must be >= 1, got {columns!r}")
        pick = np.unique(np.linspace(0, coded.size - 1, int(columns)).round().astype(int))
        return coded[pick]
    cols = np.asarray(columns)
    if cols.ndim != 1 or cols.dtype.kind not in "iu" or cols.size == 0:
        raise ValueError(f"columns must be a non-empty sequence of integers, got {columns!r}")
    if cols.min() < 0 or cols.max() >= rig.width_px:
        raise ValueError(f"columns must lie in [0, {rig.width_px}), got {columns!r}")
    return cols.astype(int)
