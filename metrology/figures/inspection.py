"""Figures of an inspection: the deviation colour map on the measured points, the deviation histogram,
and a plan's trends across measurements (the deviations, and each feature's differences from the nominal).

Inputs are plain arrays and the stored ``gcps-inspection/1`` report (docs/inspection.md). The
deviation scale is diverging and centred at 0 (blue inside the material, red outside), symmetric
about 0 from ``-limit`` to ``+limit`` with ``limit = max(1.5 T, p99 |dev|)`` where ``T`` is the
tolerance (without one, ``p99 |dev|``); the tolerance is marked on the colour bar and on the
histogram.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import plotly.graph_objects as go

from metrology.figures import PALETTE, base_layout, empty_figure

MAX_POINTS = 60_000
"""Points drawn in the 3-D view at most (every k-th measured point beyond that)."""
DIVERGING = "RdBu_r"


def deviation_limit_mm(deviations_mm: np.ndarray, tolerance_mm: float | None) -> float:
    """Half-width of the colour scale, mm: ``max(1.5 T, p99 |dev|)`` (module doc); 1e-3 at least."""
    finite = np.abs(deviations_mm[np.isfinite(deviations_mm)])
    p99 = float(np.percentile(finite, 99)) if finite.size else 0.0
    return max(1.5 * tolerance_mm if tolerance_mm else 0.0, p99, 1e-3)


def _colour_bar(limit: float, tolerance_mm: float | None) -> dict[str, Any]:
    ticks = [-limit, 0.0, limit]
    labels = [f"{-limit * 1000:.0f}", "0", f"{limit * 1000:.0f}"]
    if tolerance_mm and tolerance_mm < limit:
        ticks += [-tolerance_mm, tolerance_mm]
        labels += [f"-T {-tolerance_mm * 1000:.0f}", f"+T {tolerance_mm * 1000:.0f}"]
    return {"title": {"text": "deviation (um)"}, "tickvals": ticks, "ticktext": labels}


def deviation_map(points_mm: np.ndarray, deviations_mm: np.ndarray, tolerance_mm: float | None) -> go.Figure:
    """The measured points coloured by their signed deviation (3-D scatter, camera frame, mm).

    Parameters
    ----------
    points_mm : (H, W, 3) or (N, 3) float array
        Points in the measurement's frame, mm, NaN where not measured.
    deviations_mm : (H, W) or (N,) float array
        Signed deviation of each point, mm (positive outside the material), NaN where none.
    tolerance_mm : float or None
        Marked on the colour bar.
    """
    title = "Deviation from the nominal model"
    xyz = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    dev = np.asarray(deviations_mm, dtype=np.float64).reshape(-1)
    keep = np.flatnonzero(np.isfinite(dev) & np.isfinite(xyz).all(axis=1))
    if keep.size == 0:
        return empty_figure(title, "no point has a deviation")
    keep = keep[:: max(1, -(-keep.size // MAX_POINTS))]
    limit = deviation_limit_mm(dev, tolerance_mm)
    marker = {
        "size": 2,
        "color": dev[keep].astype(np.float32),
        "colorscale": DIVERGING,
        "cmin": -limit,
        "cmax": limit,
        "cmid": 0.0,
        "colorbar": _colour_bar(limit, tolerance_mm),
    }
    fig = go.Figure(
        go.Scatter3d(
            x=xyz[keep, 0].astype(np.float32),
            y=xyz[keep, 1].astype(np.float32),
            z=xyz[keep, 2].astype(np.float32),
            mode="markers",
            marker=marker,
            hovertemplate="x %{x:.3f} y %{y:.3f} z %{z:.3f} mm<br>deviation %{marker.color:.4f} mm<extra></extra>",
        )
    )
    layout = base_layout(title, "", "", height=560)
    # a grey backdrop: the scale's white (no deviation) must stand out
    axis = {"showbackground": True, "backgroundcolor": "#c9ced6", "gridcolor": "#f4f5f7"}
    layout["scene"] = {
        "xaxis": {**axis, "title": {"text": "X (mm)"}},
        "yaxis": {**axis, "title": {"text": "Y (mm)"}},
        "zaxis": {**axis, "title": {"text": "Z (mm)"}},
        "aspectmode": "data",
        "camera": {"eye": {"x": 0.0, "y": -0.9, "z": 1.6}},
    }
    fig.update_layout(**layout)
    return fig


def deviation_histogram(deviations_mm: np.ndarray, tolerance_mm: float | None) -> go.Figure:
    """Histogram of the finite deviations (um), with the tolerance's bounds as dashed lines."""
    title = "Distribution of the deviations"
    dev = np.asarray(deviations_mm, dtype=np.float64).reshape(-1)
    dev = dev[np.isfinite(dev)]
    if dev.size == 0:
        return empty_figure(title, "no point has a deviation")
    limit = deviation_limit_mm(dev, tolerance_mm)
    counts, edges = np.histogram(np.clip(dev, -limit, limit) * 1000.0, bins=101, range=(-limit * 1000, limit * 1000))
    fig = go.Figure(
        go.Bar(
            x=(0.5 * (edges[:-1] + edges[1:])).astype(np.float32),
            y=counts,
            marker={"color": PALETTE[0]},
            name="points",
            hovertemplate="%{x:.1f} um: %{y} points<extra></extra>",
        )
    )
    fig.update_layout(**base_layout(title, "deviation (um, clipped to the scale)", "points", bargap=0))
    if tolerance_mm:
        for sign in (-1, 1):
            fig.add_vline(x=sign * tolerance_mm * 1000, line={"dash": "dash", "color": PALETTE[1]})
    return fig


def plan_trend(rows: Sequence[dict[str, Any]]) -> go.Figure:
    """A plan's inspections across measurements: mean, RMS and p99 of the deviations (um) per
    measurement, in order. ``rows``: ``{"measurement": id, "deviation": report["deviation"]}``."""
    title = "Deviation across measurements"
    rows = [row for row in rows if row.get("deviation")]
    if not rows:
        return empty_figure(title, "no finished inspection yet")
    labels = [f"#{row['measurement']}" for row in rows]
    fig = go.Figure()
    for index, key in enumerate(("mean_mm", "rms_mm", "p99_mm")):
        values = [row["deviation"].get(key) for row in rows]
        fig.add_trace(
            go.Scatter(
                x=labels,
                y=[None if v is None else v * 1000.0 for v in values],
                mode="lines+markers",
                name=key.removesuffix("_mm"),
                line={"color": PALETTE[index]},
            )
        )
    fig.update_layout(**base_layout(title, "measurement", "deviation (um)"))
    return fig


def feature_trend(name: str, rows: Sequence[dict[str, Any]]) -> go.Figure:
    """One feature of a plan across measurements: each compared quantity's difference from the
    nominal (``measured - nominal``; um for the ``*_mm`` quantities, the form error among them), in
    order. ``rows``: ``{"measurement": id, "feature": the report's feature entry or None}``
    (docs/inspection.md); a measurement where the feature has no numbers is a gap."""
    title = f"Feature {name} across measurements"
    rows = [row for row in rows if row.get("feature") and not row["feature"].get("error")]
    if not rows:
        return empty_figure(title, "no finished inspection with this feature yet")
    labels = [f"#{row['measurement']}" for row in rows]
    names: list[str] = []
    for row in rows:
        names += [q["name"] for q in row["feature"].get("quantities") or [] if q["name"] not in names]
    fig = go.Figure()
    for index, quantity in enumerate(q for q in names if q.endswith("_mm")):
        values = []
        for row in rows:
            found = [q for q in row["feature"].get("quantities") or [] if q["name"] == quantity]
            difference = found[0].get("difference") if found else None
            values.append(None if difference is None else float(difference) * 1000.0)
        fig.add_trace(
            go.Scatter(
                x=labels,
                y=values,
                mode="lines+markers",
                name=quantity.removesuffix("_mm").replace("_", " "),
                line={"color": PALETTE[index % len(PALETTE)]},
            )
        )
    fig.update_layout(**base_layout(title, "measurement", "measured - nominal (um)"))
    return fig
