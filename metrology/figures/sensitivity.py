"""Figures 4-6 of the paper: relative height error versus relative error of L, d and alpha.

Input is the dict of :func:`metrology.core.sensitivity.sensitivity_curves` (all three
parameters): per parameter ``relative_error`` (n,), ``exact`` (one curve per column of
``columns_px`` / ``x_mm``), and the closed forms ``eq22``/``eq23`` (L) and ``eq25`` (d).
"""

from __future__ import annotations

from typing import Any

import plotly.graph_objects as go

from metrology.figures import base_layout, empty_figure

TITLES = {
    "L": "Fig. 4 - relative height error versus relative error of L",
    "d": "Fig. 5 - relative height error versus relative error of d",
    "alpha": "Fig. 6 - relative height error versus relative error of alpha",
}
SYMBOL = {"L": "dL/L", "d": "dd/d", "alpha": "dalpha/alpha"}


def _pct(values: list[Any]) -> list[float | None]:
    return [None if v is None else 100.0 * float(v) for v in values]


def _column_color(index: int, count: int) -> str:
    """Blue (left of the field) to red (right), so the X dependence reads at a glance."""
    t = index / max(1, count - 1)
    return f"rgb({int(30 + 200 * t)},{int(90 + 20 * (1 - abs(2 * t - 1)))},{int(200 - 170 * t)})"


def parameter_figure(curves: dict[str, Any], param: str) -> go.Figure:
    """One of Figs. 4-6: exact-model curves per column, and the paper's closed forms if any."""
    entry = (curves.get("params") or {}).get(param)
    title = TITLES[param]
    if not entry:
        return empty_figure(title, f"No curves for {param}.")
    rel = _pct(entry["relative_error"])
    x_mm = curves.get("x_mm") or []
    columns = curves.get("columns_px") or []
    fig = go.Figure(layout=base_layout(title, f"{SYMBOL[param]} (%)", "dz/z (%)", height=440))
    exact = entry.get("exact") or []
    for index, curve in enumerate(exact):
        label = f"column {columns[index]} (X = {x_mm[index]:.0f} mm)" if index < len(x_mm) else f"curve {index}"
        fig.add_trace(
            go.Scatter(
                x=rel,
                y=_pct(curve),
                mode="lines",
                name=label,
                legendgroup="exact",
                line={"color": _column_color(index, len(exact)), "width": 1.5},
                hovertemplate=f"{label}<br>{SYMBOL[param]} = %{{x:.1f}} %<br>dz/z = %{{y:.2f}} %<extra>exact</extra>",
            )
        )
    if param == "L" and entry.get("eq23"):
        fig.add_trace(
            go.Scatter(
                x=rel,
                y=_pct(entry["eq23"]),
                mode="lines",
                name="Eq. 23 (paper)",
                line={"color": "#222", "dash": "dash"},
            )
        )
    closed = {"L": "eq22", "d": "eq25"}.get(param)
    if closed and entry.get(closed):
        middle = len(entry[closed]) // 2
        fig.add_trace(
            go.Scatter(
                x=rel,
                y=_pct(entry[closed][middle]),
                mode="lines",
                name=f"Eq. {closed[2:]} (paper), field centre",
                line={"color": "#555", "dash": "dot"},
            )
        )
    fig.update_layout(legend={"orientation": "v", "x": 1.02, "xanchor": "left", "y": 1.0, "yanchor": "top"})
    return fig


def sensitivity_figures(curves: dict[str, Any]) -> dict[str, go.Figure]:
    """Figs. 4, 5, 6 keyed ``L``, ``d``, ``alpha`` (those present in ``curves``)."""
    params = curves.get("params") or {}
    return {param: parameter_figure(curves, param) for param in ("L", "d", "alpha") if param in params}
