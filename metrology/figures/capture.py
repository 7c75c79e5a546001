"""Figures of a capture's decoding (docs/codecs.md): projector coordinate maps u and v, the
modulation map, the refusal reasons per pixel and, for a multi-exposure capture
(docs/exposures.md), which exposure each pixel used.

Inputs are the decoder's arrays per coded axis (``(H, W)`` float32 coordinates in projector
units, NaN where not decoded; float32 modulation in grey levels; uint8 reason codes). Continuous
maps are decimated by block means (:func:`~metrology.figures.measurement.decimate`); the reason
map by taking every k-th pixel (a mean of reason codes means nothing), with one colour per code.
Axes are camera pixels, rows running down.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import plotly.graph_objects as go

from metrology.figures import base_layout, empty_figure
from metrology.figures.measurement import MAX_COLS, MAX_ROWS, block_factors, decimate, decimate_axis

REASON_COLOURS: dict[int, tuple[str, str]] = {
    0: ("valid", "#2e933c"),
    1: ("too dark", "#3b3b3b"),
    2: ("saturated", "#d1495b"),
    3: ("outside the projector", "#7a4ea3"),
    4: ("gray/phase inconsistent", "#edae49"),
    5: ("low inverse contrast", "#00798c"),
    6: ("slip repaired but kept", "#1f5fa8"),
    7: ("gray level ambiguous", "#8c564b"),
}
"""Name and colour of each reason code (docs/codecs.md, "Reason codes")."""


def _pixel_axes(shape: tuple[int, int], factors: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.arange(shape[0], dtype=np.float64), np.arange(shape[1], dtype=np.float64)
    return decimate_axis(cols, factors[1]), decimate_axis(rows, factors[0])


def _image_axes(fig: go.Figure, x: np.ndarray, y: np.ndarray) -> go.Figure:
    half_x = 0.5 * (float(x[-1] - x[0]) / max(x.size - 1, 1)) if x.size > 1 else 0.5
    half_y = 0.5 * (float(y[-1] - y[0]) / max(y.size - 1, 1)) if y.size > 1 else 0.5
    fig.update_xaxes(range=[float(x[0]) - half_x, float(x[-1]) + half_x], constrain="domain")
    fig.update_yaxes(
        range=[float(y[-1]) + half_y, float(y[0]) - half_y], scaleanchor="x", scaleratio=1, constrain="domain"
    )
    return fig


def map_figure(values: npt.ArrayLike, title: str, unit: str, colorscale: str = "Viridis") -> go.Figure:
    """Heatmap of an (H, W) map over camera pixels (decimated by block means), colour bar in ``unit``."""
    v = np.asarray(values, dtype=np.float32)
    if not np.isfinite(v).any():
        return empty_figure(title, "No pixel was decoded.")
    factors = block_factors(v.shape, MAX_ROWS, MAX_COLS)
    x, y = _pixel_axes(v.shape, factors)
    fig = go.Figure(
        data=[
            go.Heatmap(
                z=decimate(v),
                x=x,
                y=y,
                colorscale=colorscale,
                colorbar={"title": {"text": unit, "side": "right"}},
                hovertemplate="column %{x:.0f}<br>row %{y:.0f}<br>%{z:.3f} " + unit + "<extra></extra>",
            )
        ],
        layout=base_layout(title, "camera column (px)", "camera row (px), running down", height=420),
    )
    return _image_axes(fig, x, y)


def reason_figure(reason: npt.ArrayLike, title: str) -> go.Figure:
    """Categorical heatmap of the reason codes (one colour per code present), and their counts in the legend."""
    return category_figure(reason, REASON_COLOURS, title, "reason")


EXPOSURE_COLOURS = ("#440154", "#3b528b", "#21918c", "#5ec962", "#fde725", "#f89540", "#cc4778", "#7e03a8")
"""Colours of exposures 0, 1, ... (least exposed first; repeated beyond eight)."""


def exposure_figure(exposure: npt.ArrayLike, names: Sequence[str], title: str) -> go.Figure:
    """Categorical heatmap of which exposure of a multi-exposure capture each pixel used
    (docs/exposures.md): ``exposure`` (H, W) uint8 index into ``names`` (least exposed first), 255
    where none measured; the pixels of each exposure in the legend."""
    categories = {i: (name, EXPOSURE_COLOURS[i % len(EXPOSURE_COLOURS)]) for i, name in enumerate(names)}
    categories[255] = ("none", "#d0d0d0")
    return category_figure(exposure, categories, title, "exposure")


def category_figure(
    codes: npt.ArrayLike, categories: Mapping[int, tuple[str, str]], title: str, legend: str
) -> go.Figure:
    """Categorical heatmap of (H, W) uint8 ``codes`` (every k-th pixel: a mean of codes means
    nothing): one colour band per code present (``categories``: code -> (name, colour)), their
    pixel counts in the colour bar."""
    r = np.asarray(codes, dtype=np.uint8)
    factors = block_factors(r.shape, MAX_ROWS, MAX_COLS)
    sampled = r[:: factors[0], :: factors[1]]
    x = np.arange(r.shape[1], dtype=np.float64)[:: factors[1]]
    y = np.arange(r.shape[0], dtype=np.float64)[:: factors[0]]
    counts = np.bincount(r.ravel(), minlength=256)
    present = [code for code in categories if counts[code] > 0]
    colours: list[list[Any]] = []
    n = len(present)
    for index, code in enumerate(present):  # a stepped colour scale: one band per present code
        colour = categories[code][1]
        colours += [[index / n, colour], [(index + 1) / n, colour]]
    rank = np.zeros(256, np.float32)
    names = np.full(256, "?", dtype=object)
    for index, code in enumerate(present):
        rank[code] = index
        names[code] = categories[code][0]
    ticks = [f"{categories[code][0]} ({int(counts[code])} px)" for code in present]
    fig = go.Figure(
        data=[
            go.Heatmap(
                z=rank[sampled],
                x=x,
                y=y,
                zmin=-0.5,
                zmax=n - 0.5,
                colorscale=colours,
                customdata=names[sampled],
                colorbar={"tickvals": list(range(n)), "ticktext": ticks, "title": {"text": legend}},
                hovertemplate="column %{x:.0f}<br>row %{y:.0f}<br>%{customdata}<extra></extra>",
            )
        ],
        layout=base_layout(title, "camera column (px)", "camera row (px), running down", height=420),
    )
    return _image_axes(fig, x, y)


def decoding_figures(
    axes: Mapping[str, Mapping[str, np.ndarray]], exposure_names: Sequence[str] = ()
) -> dict[str, go.Figure]:
    """Figures of a decoding: for each coded axis a in {u, v}, ``coordinate_a`` (projector units),
    ``modulation_a`` (grey levels) and ``reason_a``; for a multi-exposure capture also
    ``exposure_a`` (which exposure each pixel used, :func:`exposure_figure`).

    Parameters
    ----------
    axes : mapping of axis name to a mapping with ``coordinate``, ``modulation`` and ``reason``
        arrays, and ``exposure`` (uint8) for a multi-exposure capture
    exposure_names : sequence of str
        The exposures' names, least exposed first (empty for a single stack).
    """
    figures: dict[str, go.Figure] = {}
    for name in ("u", "v"):
        if name not in axes:
            continue
        arrays = axes[name]
        what = "column" if name == "u" else "row"
        figures[f"coordinate_{name}"] = map_figure(
            arrays["coordinate"], f"Decoded {name}: projector {what} of each camera pixel", "projector px"
        )
        figures[f"modulation_{name}"] = map_figure(
            arrays["modulation"], f"Modulation B of the {name} fringes", "grey levels", colorscale="Gray"
        )
        figures[f"reason_{name}"] = reason_figure(arrays["reason"], f"Why {name} pixels were refused")
        if "exposure" in arrays:
            figures[f"exposure_{name}"] = exposure_figure(
                arrays["exposure"], exposure_names, f"Which exposure measured each {name} pixel"
            )
    return figures
