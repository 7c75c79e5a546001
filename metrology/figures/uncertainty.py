"""Figure of a measurement's per-point uncertainty: the sigma map (mm) over the field."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import plotly.graph_objects as go

from metrology.figures import base_layout, empty_figure, fit_image_axes
from metrology.figures.measurement import block_factors, decimate, decimate_axis


def sigma_map_figure(sigma_mm: npt.ArrayLike, x_mm: npt.ArrayLike, y_mm: npt.ArrayLike) -> go.Figure:
    """Heatmap of the per-point standard uncertainty (decimated by block means), colour bar in mm.

    Parameters
    ----------
    sigma_mm : (H, W) float array, mm, NaN where not measured
    x_mm : (W,) X of each column, mm;  y_mm : (H,) Y of each row, mm
    """
    s = np.asarray(sigma_mm, dtype=np.float32)
    title = "Per-point uncertainty (sigma)"
    if not np.isfinite(s).any():
        return empty_figure(title, "No pixel was measured.")
    fr, fc = block_factors(s.shape)
    x = decimate_axis(np.asarray(x_mm, dtype=np.float64), fc)
    y = decimate_axis(np.asarray(y_mm, dtype=np.float64), fr)
    fig = go.Figure(
        data=[
            go.Heatmap(
                z=decimate(s),
                x=x.astype(np.float32),
                y=y.astype(np.float32),
                colorscale="Magma",
                reversescale=True,
                colorbar={"title": {"text": "sigma (mm)", "side": "right"}},
                hovertemplate="X = %{x:.1f} mm<br>Y = %{y:.1f} mm<br>sigma = %{z:.4f} mm<extra></extra>",
            )
        ],
        layout=base_layout(title, "X (mm)", "Y (mm)", height=480),
    )
    return fit_image_axes(fig, x, y)
