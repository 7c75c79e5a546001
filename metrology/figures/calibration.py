"""Figures of a calibration (paper section 4): L and alpha per iteration, master profiles, residuals.

Inputs are what the Calibration row stores: ``iterations`` (the core's ``history``: one dict per
profile evaluated with ``L_mm``, ``alpha_rad``, ``d_mm``, ``mean_height_mm``, ``slope`` and, for
least squares, ``rms_mm``), the master's known height, and the residual map (least squares only).
The per-iteration profiles are not stored as pixels: each iteration's regression line
``z(X) = mean + slope (X - X_c)`` is drawn from its stored mean and slope over the master's width.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from metrology.figures import PALETTE, base_layout, empty_figure, fit_image_axes
from metrology.figures.measurement import block_factors, decimate, decimate_axis

UM = 1000.0


def _num(value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out if math.isfinite(out) else math.nan


def iteration_points(iterations: list[dict[str, Any]], result: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The fit's path, point 0 being the start: one point per iteration, the last one the result.

    ``iterations`` is the stored history. Its first entry is evaluated at the starting values
    (iteration 0). The paper's method profiles every estimate it makes; when it stops at its
    iteration limit, the last estimate (the result) was never profiled, so it is appended here
    from ``result`` (``L_mm``, ``alpha_rad``, ``d_mm``; mean height and slope unknown, NaN).
    Least squares stores its final point itself (``step == "final"``). The number of
    iterations is therefore ``len(points) - 1``, the same count the page states.
    """
    points = [dict(it) for it in iterations]
    if not points or not result:
        return points
    last = points[-1]
    keys = ("L_mm", "alpha_rad", "d_mm")
    values = [_num(result.get(k)) for k in keys]
    if any(math.isnan(v) for v in values):
        return points
    fitted = dict(zip(keys, values, strict=True))
    if any(not math.isclose(_num(last.get(k)), v, rel_tol=1e-12) for k, v in fitted.items()):
        points.append({**fitted, "mean_height_mm": math.nan, "slope": math.nan, "step": "result"})
    return points


def iteration_label(index: int, count: int) -> str:
    """``"start"`` for point 0, ``"iteration k"`` otherwise, ``"(result)"`` on the last point."""
    if index == 0:
        return "start (iteration 0)"
    return f"iteration {index}" + (" (result)" if index == count - 1 else "")


def parameters_figure(iterations: list[dict[str, Any]], result: dict[str, Any] | None = None) -> go.Figure:
    """L (left axis, mm) and alpha (right axis, rad) at every iteration; iteration 0 is the start."""
    title = "L and alpha per iteration"
    points = iteration_points(iterations, result)
    if not points:
        return empty_figure(title, "No iteration was stored.")
    steps = list(range(len(points)))
    labels = [iteration_label(i, len(points)) for i in steps]
    fig = make_subplots(specs=[[{"secondary_y": True}]])
    fig.add_trace(
        go.Scatter(
            x=steps,
            y=[_num(it.get("L_mm")) for it in points],
            text=labels,
            mode="lines+markers",
            name="L (mm)",
            line={"color": PALETTE[0]},
            hovertemplate="%{text}<br>L = %{y:.3f} mm<extra></extra>",
        ),
        secondary_y=False,
    )
    fig.add_trace(
        go.Scatter(
            x=steps,
            y=[_num(it.get("alpha_rad")) for it in points],
            text=labels,
            mode="lines+markers",
            name="alpha (rad)",
            line={"color": PALETTE[1], "dash": "dot"},
            hovertemplate="%{text}<br>alpha = %{y:.5f} rad<extra></extra>",
        ),
        secondary_y=True,
    )
    fig.update_layout(base_layout(title, "iteration (0 = start)", "L (mm)"))
    fig.update_yaxes(title_text="alpha (rad)", secondary_y=True, showgrid=False, tickformat=".4f")
    fig.update_yaxes(tickformat=".1f", secondary_y=False)
    fig.update_xaxes(dtick=1 if len(steps) <= 30 else None)
    return fig


def profiles_figure(
    iterations: list[dict[str, Any]], master_height_mm: float, x_range_mm: tuple[float, float]
) -> go.Figure:
    """Each iteration's master profile regression line ``mean + slope (X - X_c)``, and the known height."""
    title = "Master top-face regression line per iteration"
    points = [it for it in iteration_points(iterations) if math.isfinite(_num(it.get("mean_height_mm")))]
    if not points:
        return empty_figure(title, "No iteration was stored.")
    lo, hi = x_range_mm
    centre = 0.5 * (lo + hi)
    xs = [lo, hi]
    fig = go.Figure(layout=base_layout(title, "X (mm)", "height (mm)"))
    last = len(points) - 1
    for index, it in enumerate(points):
        mean, slope = _num(it.get("mean_height_mm")), _num(it.get("slope"))
        final = index == last
        label = iteration_label(index, len(points))
        fig.add_trace(
            go.Scatter(
                x=xs,
                y=[mean + slope * (x - centre) for x in xs],
                mode="lines",
                name=label,
                line={"color": PALETTE[index % len(PALETTE)], "width": 3 if final else 1},
                opacity=1.0 if final else 0.6,
                hovertemplate=f"{label}<br>mean = {mean:.4f} mm<br>slope = {slope:.2e}<extra></extra>",
            )
        )
    fig.add_hline(
        y=master_height_mm,
        line={"color": "#222", "dash": "dash", "width": 1},
        annotation_text=f"H = {master_height_mm:g} mm",
        annotation_position="top left",
    )
    return fig


def residual_figure(residual_mm: npt.ArrayLike | None, x_mm: npt.ArrayLike, y_mm: npt.ArrayLike) -> go.Figure:
    """Heatmap of the residual map (measured minus known height), in µm, decimated."""
    title = "Residual map of the master (measured - known)"
    if residual_mm is None:
        return empty_figure(title, "This method stores no residual map (the paper's method); see the profiles.")
    r = np.asarray(residual_mm, dtype=np.float32)
    if not np.isfinite(r).any():
        return empty_figure(title, "The residual map holds no finite value.")
    fr, fc = block_factors(r.shape)
    small = decimate(r) * UM
    limit = float(np.nanpercentile(np.abs(small), 99)) or 1.0
    fig = go.Figure(
        data=[
            go.Heatmap(
                z=small,
                x=decimate_axis(x_mm, fc).astype(np.float32),
                y=decimate_axis(y_mm, fr).astype(np.float32),
                colorscale="RdBu",
                reversescale=True,
                zmin=-limit,
                zmax=limit,
                colorbar={"title": {"text": "residual (µm)"}},
                hovertemplate="X = %{x:.1f} mm<br>Y = %{y:.1f} mm<br>%{z:.1f} µm<extra></extra>",
            )
        ],
        layout=base_layout(title, "X (mm)", "Y (mm)", height=460),
    )
    return fit_image_axes(fig, decimate_axis(x_mm, fc), decimate_axis(y_mm, fr))


def calibration_figures(
    iterations: list[dict[str, Any]],
    master_height_mm: float,
    *,
    residual_mm: npt.ArrayLike | None = None,
    x_mm: npt.ArrayLike | None = None,
    y_mm: npt.ArrayLike | None = None,
    x_range_mm: tuple[float, float] | None = None,
    result: dict[str, Any] | None = None,
) -> dict[str, go.Figure]:
    """Every figure of a calibration.

    Parameters
    ----------
    iterations : list of dict
        ``Calibration.iterations``.
    master_height_mm : float
        Known height H of the master, mm.
    residual_mm : (H, W) float array, optional
        Residual map, mm, NaN outside the fitted pixels.
    x_mm, y_mm : (W,), (H,) float arrays, optional
        Column and row coordinates, mm (default: pixel indices).
    x_range_mm : (float, float), optional
        X extent of the profile lines (default: where the residual map is finite, else the
        extent of ``x_mm``).
    result : dict, optional
        ``Calibration.result`` (the fitted values), to draw the result as the last point when
        the history does not end on it (see :func:`iteration_points`).

    Returns
    -------
    dict of str -> Figure
        ``parameters``, ``profiles``, ``residual``.
    """
    shape = None if residual_mm is None else np.asarray(residual_mm).shape
    if x_mm is None:
        x_mm = np.arange(shape[1] if shape else 2, dtype=np.float64)
    if y_mm is None:
        y_mm = np.arange(shape[0] if shape else 2, dtype=np.float64)
    x = np.asarray(x_mm, dtype=np.float64)
    if x_range_mm is None:
        if residual_mm is not None and np.isfinite(residual_mm).any():
            cols = np.flatnonzero(np.isfinite(np.asarray(residual_mm)).any(axis=0))
            x_range_mm = (float(x[cols[0]]), float(x[cols[-1]]))
        else:
            x_range_mm = (float(x.min()), float(x.max()))
    return {
        "parameters": parameters_figure(iterations or [], result),
        "profiles": profiles_figure(iterations or [], master_height_mm, x_range_mm),
        "residual": residual_figure(residual_mm, x_mm, y_mm),
    }
