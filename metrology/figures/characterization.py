"""Figures of a characterization (paper section 5, Figs. 12 and 13) and its summary table.

Input is the dict produced by :func:`metrology.core.characterize.characterize` (stored as
``Characterization.results``)::

    {"z_in_mm": [...], "mean_error_mm": [...], "std_error_mm": [...], "n_samples": [...],
     "test_points": [{"x_mm", "y_mm", "slope", "intercept_mm", "r2", "sigma_mm", ...}, ...],
     "overall": {...}, "edge_sigma_ratio": float, "sigma_vs_x": {"x_mm": [...], "sigma_mm": [...]},
     "patch_px": int, "repeats": int}

Missing keys and ``None`` values (a test point without a line fit) are tolerated: the figure
then shows what there is. A test point may carry ``z_out_mm`` (its per-position means, same
order as ``z_in_mm``); without it the in-out curve is the fitted line at the stage positions.

VDI/VDE 2634 part 2 quantities (:mod:`metrology.core.acceptance`) are listed in the summary when
the result holds them under ``"vdi_2634"`` (keys ``flatness``, ``probing``, ``sphere_spacing``
with the dicts of :func:`~metrology.core.acceptance.flatness_error`,
:func:`~metrology.core.acceptance.probing_error`,
:func:`~metrology.core.acceptance.sphere_spacing_error`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import plotly.graph_objects as go

from metrology.figures import PALETTE, base_layout, empty_figure

FIGURE_TITLES: dict[str, str] = {
    "in_out": "Fig. 12 - In-out characteristic per test point",
    "error_vs_z": "Fig. 13 - Mean error and standard deviation versus Z_in",
    "slope_vs_x": "Slope of the in-out line versus X",
    "intercept_vs_x": "Intercept of the in-out line versus X",
    "sigma_vs_x": "Repeatability (sigma) versus X",
}
"""Key -> title of every figure :func:`characterization_figures` returns, in display order."""

UM = 1000.0


def _num(value: Any) -> float:
    """A float, NaN for None or anything not finite (plotly leaves a gap)."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out if math.isfinite(out) else math.nan


def _rows_of_points(points: list[dict[str, Any]]) -> list[tuple[float, list[dict[str, Any]]]]:
    """Test points grouped by image row (their ``y_mm``), each group sorted by X."""
    groups: dict[float, list[dict[str, Any]]] = defaultdict(list)
    for point in points:
        groups[round(_num(point.get("y_mm")), 6)].append(point)
    return [(y, sorted(group, key=lambda p: _num(p.get("x_mm")))) for y, group in sorted(groups.items())]


def in_out_figure(result: dict[str, Any]) -> go.Figure:
    """Fig. 12: Z_out versus Z_in for every test point, with the ideal line Z_out = Z_in."""
    z_in = [_num(z) for z in result.get("z_in_mm") or []]
    points = result.get("test_points") or []
    title = FIGURE_TITLES["in_out"]
    if len(z_in) < 2 or not points:
        return empty_figure(title, "No stage positions or test points in this result.")
    fig = go.Figure(layout=base_layout(title, "Z_in (mm)", "Z_out (mm)"))
    many = len(points) > 8
    for index, point in enumerate(points):
        x_mm = _num(point.get("x_mm"))
        measured = point.get("z_out_mm")
        if measured is not None:
            z_out = [_num(v) for v in measured]
        else:
            slope, intercept = _num(point.get("slope")), _num(point.get("intercept_mm"))
            z_out = [slope * z + intercept for z in z_in]
        fig.add_trace(
            go.Scatter(
                x=z_in,
                y=z_out,
                mode="lines+markers",
                name=f"X = {x_mm:.1f} mm",
                legendgroup="points" if many else None,
                showlegend=not many or index == 0,
                line={"width": 1, "color": PALETTE[index % len(PALETTE)]},
                marker={"size": 4},
                hovertemplate=(
                    f"X = {x_mm:.2f} mm, Y = {_num(point.get('y_mm')):.2f} mm<br>"
                    f"slope = {_num(point.get('slope')):.6f}<br>"
                    "Z_in = %{x:.3f} mm<br>Z_out = %{y:.4f} mm<extra></extra>"
                ),
            )
        )
    if many:
        fig.data[0].name = f"{len(points)} test points"
    lo, hi = min(z_in), max(z_in)
    fig.add_trace(
        go.Scatter(
            x=[lo, hi], y=[lo, hi], mode="lines", name="ideal Z_out = Z_in", line={"color": "#222", "dash": "dash"}
        )
    )
    return fig


def error_vs_z_figure(result: dict[str, Any]) -> go.Figure:
    """Fig. 13: mean of dz = Z_out - Z_in (with +-sigma bars) and sigma, in µm, versus Z_in."""
    z_in = [_num(z) for z in result.get("z_in_mm") or []]
    title = FIGURE_TITLES["error_vs_z"]
    if not z_in:
        return empty_figure(title, "No stage positions in this result.")
    mean_um = [_num(v) * UM for v in result.get("mean_error_mm") or [None] * len(z_in)]
    std_um = [_num(v) * UM for v in result.get("std_error_mm") or [None] * len(z_in)]
    fig = go.Figure(layout=base_layout(title, "Z_in (mm)", "error (µm)"))
    fig.add_trace(
        go.Scatter(
            x=z_in,
            y=mean_um,
            mode="lines+markers",
            name="mean error",
            line={"color": PALETTE[0]},
            error_y={"type": "data", "array": std_um, "visible": True, "thickness": 1},
            hovertemplate="Z_in = %{x:.3f} mm<br>mean error = %{y:.1f} µm<extra></extra>",
        )
    )
    fig.add_trace(
        go.Scatter(
            x=z_in,
            y=std_um,
            mode="lines+markers",
            name="sigma",
            line={"color": PALETTE[1], "dash": "dot"},
            hovertemplate="Z_in = %{x:.3f} mm<br>sigma = %{y:.1f} µm<extra></extra>",
        )
    )
    fig.add_hline(y=0, line={"color": "#888", "width": 1})
    return fig


def _per_x_figure(
    result: dict[str, Any],
    key: str,
    value_of: Callable[[dict[str, Any]], float],
    y_title: str,
    ideal: float | None,
    hover: str,
) -> go.Figure:
    points = result.get("test_points") or []
    title = FIGURE_TITLES[key]
    if not points:
        return empty_figure(title, "No test points in this result.")
    fig = go.Figure(layout=base_layout(title, "X (mm)", y_title))
    groups = _rows_of_points(points)
    for index, (y_mm, group) in enumerate(groups):
        fig.add_trace(
            go.Scatter(
                x=[_num(p.get("x_mm")) for p in group],
                y=[value_of(p) for p in group],
                mode="lines+markers",
                name=f"row Y = {y_mm:.1f} mm",
                showlegend=len(groups) > 1,
                line={"color": PALETTE[index % len(PALETTE)]},
                hovertemplate=f"X = %{{x:.2f}} mm<br>{hover}<extra></extra>",
            )
        )
    if ideal is not None:
        fig.add_hline(y=ideal, line={"color": "#222", "dash": "dash", "width": 1})
    return fig


def slope_vs_x_figure(result: dict[str, Any]) -> go.Figure:
    """Slope of each test point's in-out line versus its X (ideal 1)."""
    fig = _per_x_figure(result, "slope_vs_x", lambda p: _num(p.get("slope")), "slope (-)", 1.0, "slope = %{y:.6f}")
    fig.update_yaxes(tickformat=".5f")
    return fig


def intercept_vs_x_figure(result: dict[str, Any]) -> go.Figure:
    """Intercept of each test point's in-out line versus its X, in µm (ideal 0)."""
    return _per_x_figure(
        result,
        "intercept_vs_x",
        lambda p: _num(p.get("intercept_mm")) * UM,
        "intercept (µm)",
        0.0,
        "intercept = %{y:.1f} µm",
    )


def sigma_vs_x_figure(result: dict[str, Any]) -> go.Figure:
    """Repeatability of each test point versus its X, in µm: it grows towards the field edges."""
    fig = _per_x_figure(
        result, "sigma_vs_x", lambda p: _num(p.get("sigma_mm")) * UM, "sigma (µm)", None, "sigma = %{y:.1f} µm"
    )
    ratio = _num(result.get("edge_sigma_ratio"))
    if math.isfinite(ratio) and fig.data:
        fig.add_annotation(
            text=f"edge / centre sigma = {ratio:.2f}",
            showarrow=False,
            xref="paper",
            yref="paper",
            x=0.01,
            y=0.98,
            xanchor="left",
            bgcolor="rgba(255,255,255,0.8)",
        )
    return fig


def characterization_figures(result: dict[str, Any]) -> dict[str, go.Figure]:
    """Every figure of a characterization, keyed as :data:`FIGURE_TITLES` (in that order).

    Parameters
    ----------
    result : dict
        The output of :func:`metrology.core.characterize.characterize`.

    Returns
    -------
    dict of str -> plotly.graph_objects.Figure
        ``in_out`` (Fig. 12), ``error_vs_z`` (Fig. 13, µm), ``slope_vs_x``,
        ``intercept_vs_x`` (µm), ``sigma_vs_x`` (µm, edge growth).
    """
    result = result or {}
    return {
        "in_out": in_out_figure(result),
        "error_vs_z": error_vs_z_figure(result),
        "slope_vs_x": slope_vs_x_figure(result),
        "intercept_vs_x": intercept_vs_x_figure(result),
        "sigma_vs_x": sigma_vs_x_figure(result),
    }


def _um(value: Any) -> str:
    number = _num(value)
    return "n/a" if math.isnan(number) else f"{number * UM:.1f} µm"


def _pct(value: Any) -> str:
    number = _num(value)
    return "n/a" if math.isnan(number) else f"{number:.3f} %"


def _plain(value: Any, digits: int = 6) -> str:
    number = _num(value)
    return "n/a" if math.isnan(number) else f"{number:.{digits}f}"


def summary_rows(result: dict[str, Any]) -> list[tuple[str, str]]:
    """The summary table of a characterization as (label, value) text pairs.

    Mean error, variability (sigma), RMS error, full scale and the errors as % of full scale,
    the worst per-position mean error, the range of the in-out slopes, the edge/centre sigma
    ratio, the repeats and patch size, and the VDI/VDE 2634-2 quantities when present.
    """
    result = result or {}
    overall = result.get("overall") or {}
    full_scale = _num(overall.get("full_scale_mm"))
    rows: list[tuple[str, str]] = [
        ("Mean error (all test points, all positions)", _um(overall.get("mean_error_mm"))),
        ("Variability (standard deviation of the error)", _um(overall.get("std_error_mm"))),
        ("RMS error sqrt(mean^2 + sigma^2)", _um(overall.get("rms_error_mm"))),
        ("Full scale", "n/a" if math.isnan(full_scale) else f"{full_scale:.3f} mm"),
        ("RMS error, % of full scale", _pct(overall.get("error_pct_fs"))),
        ("Mean error, % of full scale", _pct(overall.get("mean_error_pct_fs"))),
        ("Variability, % of full scale", _pct(overall.get("std_error_pct_fs"))),
        ("Largest |mean error| at one position", _um(overall.get("max_abs_mean_error_mm"))),
        (
            "In-out slopes (min - max)",
            f"{_plain(overall.get('slope_min'))} - {_plain(overall.get('slope_max'))}",
        ),
        ("Largest |slope - 1|", _plain(overall.get("max_abs_slope_deviation"))),
        ("Edge / centre repeatability ratio", _plain(result.get("edge_sigma_ratio"), 2)),
    ]
    z_in = result.get("z_in_mm") or []
    points = result.get("test_points") or []
    rows.append(("Stage positions x repeats", f"{len(z_in)} x {result.get('repeats', 'n/a')}"))
    rows.append(("Test points (patch size)", f"{len(points)} ({result.get('patch_px', 'n/a')} px)"))
    vdi = result.get("vdi_2634") or {}
    flat = vdi.get("flatness") or {}
    if flat:
        rows.append(("VDI/VDE 2634-2 flatness error F", _um(flat.get("flatness_mm"))))
        rows.append(("VDI/VDE 2634-2 flatness error F (0.3 % rejected)", _um(flat.get("flatness_rejected_mm"))))
    probing = vdi.get("probing") or {}
    if probing:
        rows.append(("VDI/VDE 2634-2 probing error form P_F", _um(probing.get("form_error_mm"))))
        rows.append(("VDI/VDE 2634-2 probing error size P_S", _um(probing.get("size_error_mm"))))
    spacing = vdi.get("sphere_spacing") or {}
    if spacing:
        rows.append(("VDI/VDE 2634-2 sphere-spacing error SD", _um(spacing.get("spacing_error_mm"))))
    return rows
