"""Plotly figure builders for the dashboard and the reports (one module per result type).

Every builder is a pure function: plain data (the JSON stored on a model, numpy arrays) in, a
``plotly.graph_objects.Figure`` out. Nothing here reads the database or files, and the
measurement core never imports plotly (``tests/core/test_core_boundary.py``).

Shared helpers:

- :func:`base_layout` -- the house layout (white background, readable fonts, margins);
- :func:`plot_config` -- the browser config: a toolbar whose camera button saves a PNG named
  after the figure; the dashboard's ``figures.js`` adds a second button that saves an SVG
  (plotly's toolbar exports one format per button);
- :func:`figure_json` -- the figure as JSON text for ``Plotly.newPlot`` (numpy arrays become
  compact base64 typed arrays);
- :func:`empty_figure` / :func:`is_empty` -- a figure without data that says why, and the test
  for one (pages show its message instead of a blank plot with download buttons);
- :func:`fit_image_axes` -- axes of an image-like heatmap: equal scale, fitted to the data, Y down.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import plotly.graph_objects as go
import plotly.io as pio

PALETTE = ("#1f5fa8", "#d1495b", "#2e933c", "#edae49", "#7a4ea3", "#00798c", "#8c564b", "#e377c2")
"""Line colours, in order (colour-blind friendly enough for a handful of traces)."""


def base_layout(title: str, x_title: str, y_title: str, **extra: Any) -> dict[str, Any]:
    """The house layout: title, axis titles with units, white background, legend on top."""
    layout: dict[str, Any] = {
        "title": {"text": title, "x": 0.0, "xanchor": "left", "font": {"size": 15}},
        "xaxis": {"title": {"text": x_title}, "zeroline": False, "gridcolor": "#e5e5e5"},
        "yaxis": {"title": {"text": y_title}, "zeroline": False, "gridcolor": "#e5e5e5"},
        "template": "plotly_white",
        "margin": {"l": 70, "r": 20, "t": 60, "b": 55},
        "legend": {"orientation": "h", "yanchor": "bottom", "y": 1.0, "xanchor": "right", "x": 1.0},
        "font": {"family": "system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif", "size": 12},
        "height": 420,
    }
    layout.update(extra)
    return layout


def plot_config(filename: str, image_format: str = "png") -> dict[str, Any]:
    """Plotly browser config: responsive, a toolbar that saves ``filename.<format>`` at 2x scale."""
    return {
        "responsive": True,
        "displaylogo": False,
        "toImageButtonOptions": {"format": image_format, "filename": filename, "scale": 2},
        "modeBarButtonsToRemove": ["select2d", "lasso2d"],
    }


def figure_json(fig: go.Figure) -> str:
    """The figure as JSON text (``{"data": [...], "layout": {...}}``) for ``Plotly.newPlot``."""
    return pio.to_json(fig, validate=False, remove_uids=True)


def empty_figure(title: str, message: str) -> go.Figure:
    """A figure without data that says why (e.g. "no iterations stored"); ``layout.meta`` holds the message."""
    fig = go.Figure(layout=base_layout(title, "", "", height=260))
    fig.update_xaxes(visible=False)
    fig.update_yaxes(visible=False)
    fig.add_annotation(text=message, showarrow=False, x=0.5, y=0.5, xref="paper", yref="paper", font={"size": 14})
    fig.update_layout(meta={"empty": message})
    return fig


def is_empty(fig: go.Figure) -> bool:
    """True for a figure without data traces (nothing to look at or to download)."""
    return len(fig.data) == 0


def empty_message(fig: go.Figure) -> str:
    """Why an empty figure is empty (the message given to :func:`empty_figure`)."""
    meta = fig.layout.meta
    return str(meta.get("empty", "")) if isinstance(meta, dict) else ""


def fit_image_axes(fig: go.Figure, x_mm: npt.ArrayLike, y_mm: npt.ArrayLike) -> go.Figure:
    """Axes of an image-like heatmap: one mm per mm on both, spanning exactly the data, Y running down.

    ``x_mm`` (W,) and ``y_mm`` (H,) are the (increasing) centres of the columns and rows, mm. The
    ranges reach half a cell beyond the outer centres. ``constrain="domain"`` makes the equal scale
    shrink the plot area instead of widening the X range beyond the data (which showed -150 to
    860 mm for a field of 102 to 602 mm). Y is reversed, as image rows run down.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(y_mm, dtype=np.float64)
    half_x = 0.5 * abs(float(x[-1] - x[0])) / max(x.size - 1, 1) if x.size > 1 else 0.5
    half_y = 0.5 * abs(float(y[-1] - y[0])) / max(y.size - 1, 1) if y.size > 1 else 0.5
    fig.update_xaxes(range=[float(x.min()) - half_x, float(x.max()) + half_x], constrain="domain")
    fig.update_yaxes(
        range=[float(y.max()) + half_y, float(y.min()) - half_y],
        scaleanchor="x",
        scaleratio=1,
        constrain="domain",
        title_text="Y (mm), running down the image rows",
    )
    return fig
