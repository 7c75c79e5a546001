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
  compact base64 typed arrays).
"""

from __future__ import annotations

from typing import Any

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
    """A figure without data that says why (e.g. "no iterations stored")."""
    fig = go.Figure(layout=base_layout(title, "", "", height=260))
    fig.update_xaxes(visible=False)
    fig.update_yaxes(visible=False)
    fig.add_annotation(text=message, showarrow=False, x=0.5, y=0.5, xref="paper", yref="paper", font={"size": 14})
    return fig
