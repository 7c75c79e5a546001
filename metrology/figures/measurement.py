"""Figures of a measurement: height map, row profiles, gray-code-only vs GCPS, 3D surface.

The browser gets decimated data: :func:`decimate` reduces a height map by block means (NaN
ignored) to at most ``max_rows x max_cols`` (default 320 x 400), so a 1280 x 1024 map is sent as
320 x 256 values and the page renders in well under a second on the server.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import plotly.graph_objects as go

from metrology.figures import PALETTE, base_layout, empty_figure, fit_image_axes

MAX_ROWS = 320
MAX_COLS = 400
MAX_ROWS_3D = 160
MAX_COLS_3D = 200
UM = 1000.0
ROBUST_PERCENTILES = (1.0, 99.0)
"""The colours of a map and the 3D view's box span these percentiles of the finite values, so that a
few outliers (a shattered border, a reflection) neither wash out the colours nor flatten the
object; the full range stays in the hover, the colour bar's title and the statistics."""


def robust_range(values: npt.ArrayLike) -> tuple[float, float] | None:
    """The (p1, p99) percentiles of the finite ``values`` (:data:`ROBUST_PERCENTILES`); ``None`` when none is finite.

    A range of zero width (a flat map) is returned as it is.

    >>> robust_range(np.r_[np.arange(101.0), np.nan, 1e6])
    (1.01, 99.99)
    """
    v = np.asarray(values, dtype=np.float64)
    finite = v[np.isfinite(v)]
    if finite.size == 0:
        return None
    low, high = np.percentile(finite, ROBUST_PERCENTILES)
    return round(float(low), 9), round(float(high), 9)


def full_range(values: npt.ArrayLike) -> tuple[float, float] | None:
    """(min, max) of the finite ``values``; ``None`` when none is finite."""
    v = np.asarray(values, dtype=np.float64)
    finite = v[np.isfinite(v)]
    return (float(finite.min()), float(finite.max())) if finite.size else None


def _range_note(colour: tuple[float, float], full: tuple[float, float]) -> str:
    """``colours p1-p99: 0.012 to 25.1 mm; full range -61.2 to 58.7 mm`` (what a colour bar stands for)."""
    return f"colours p1-p99: {colour[0]:.4g} to {colour[1]:.4g} mm; full range {full[0]:.4g} to {full[1]:.4g} mm"


def block_factors(shape: tuple[int, int], max_rows: int = MAX_ROWS, max_cols: int = MAX_COLS) -> tuple[int, int]:
    """Integer block sizes (rows, columns) that bring ``shape`` within ``max_rows x max_cols``."""
    if max_rows < 1 or max_cols < 1:
        raise ValueError(f"max_rows and max_cols must be >= 1, got {max_rows}, {max_cols}")
    return max(1, math.ceil(shape[0] / max_rows)), max(1, math.ceil(shape[1] / max_cols))


def decimate(values: npt.ArrayLike, max_rows: int = MAX_ROWS, max_cols: int = MAX_COLS) -> np.ndarray:
    """Block means of a 2D array (NaN ignored; NaN where a block has no finite value).

    Parameters
    ----------
    values : (H, W) float array
        E.g. a height map in mm, NaN where invalid.
    max_rows, max_cols : int
        Largest output shape.

    Returns
    -------
    (ceil(H / fr), ceil(W / fc)) float32 array, with ``(fr, fc) = block_factors((H, W), ...)``;
    edge blocks that are cut short average what they hold.

    >>> decimate(np.arange(16.0).reshape(4, 4), 2, 2).tolist()
    [[2.5, 4.5], [10.5, 12.5]]
    """
    z = np.asarray(values, dtype=np.float32)
    if z.ndim != 2:
        raise ValueError(f"values must be a 2D array, got shape {z.shape}")
    fr, fc = block_factors(z.shape, max_rows, max_cols)
    if fr == 1 and fc == 1:
        return z.copy()
    h, w = z.shape
    hp, wp = math.ceil(h / fr) * fr, math.ceil(w / fc) * fc
    padded = np.full((hp, wp), np.nan, dtype=np.float32)
    padded[:h, :w] = z
    blocks = padded.reshape(hp // fr, fr, wp // fc, fc)
    finite = np.isfinite(blocks)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, blocks, 0.0).sum(axis=(1, 3), dtype=np.float64)
    out = np.full(count.shape, np.nan, dtype=np.float32)
    np.divide(total, count, out=out, where=count > 0, casting="unsafe")
    return out


def decimate_axis(coords: npt.ArrayLike, factor: int) -> np.ndarray:
    """Means of consecutive groups of ``factor`` coordinates (the last group may be shorter)."""
    c = np.asarray(coords, dtype=np.float64)
    n = math.ceil(len(c) / factor)
    padded = np.full(n * factor, np.nan)
    padded[: len(c)] = c
    groups = padded.reshape(n, factor)
    return np.array([g[np.isfinite(g)].mean() for g in groups])


def height_map_figure(
    z_mm: npt.ArrayLike,
    x_mm: npt.ArrayLike,
    y_mm: npt.ArrayLike,
    title: str = "",
    *,
    quantity: str = "height",
    x_label: str = "X (mm)",
    y_label: str = "Y (mm)",
    unit: str = "mm",
    colour_range: tuple[float, float] | None = None,
    value_range: tuple[float, float] | None = None,
) -> go.Figure:
    """Heatmap of a (decimated) map of heights (or depths) with a colour bar in mm.

    The colours span ``colour_range`` (default: :func:`robust_range` of ``z_mm``, its p1-p99), so
    that outliers do not wash out the object; values beyond it take the end colours. The hover
    shows every cell's own value, and the colour bar's title the full range ``value_range``
    (default: that of ``z_mm``; give the full-resolution map's, as decimation averages extremes
    away). ``layout.meta`` holds both (``colour_range_mm``, ``full_range_mm``).

    Parameters
    ----------
    z_mm : (h, w) float array, mm, NaN where invalid (shown blank)
    x_mm : (w,) float array, the coordinate of each column (``unit``)
    y_mm : (h,) float array, the coordinate of each row (``unit``)
    quantity : {'height', 'depth'}
        What ``z_mm`` is (the title and the colour bar say it).
    x_label, y_label, unit : str
        The axes' titles and the coordinates' unit (the paper's X, Y in mm; camera pixels).
    colour_range, value_range : (low, high) mm, optional
        The colours' span and the full range of the values (see above).
    """
    z = np.asarray(z_mm, dtype=np.float32)
    title = title or f"{quantity.capitalize()} map"
    colours = colour_range or robust_range(z)
    full = value_range or full_range(z)
    if colours is None or full is None:
        return empty_figure(title, "No pixel was measured.")
    fig = go.Figure(
        data=[
            go.Heatmap(
                z=z,
                x=np.asarray(x_mm, dtype=np.float32),
                y=np.asarray(y_mm, dtype=np.float32),
                zmin=colours[0],
                zmax=colours[1],
                colorscale="Viridis",
                colorbar={
                    "title": {"text": f"{quantity} (mm)<br><sub>{_range_note(colours, full)}</sub>", "side": "right"}
                },
                hovertemplate=_hover(x_label, y_label, unit, quantity),
            )
        ],
        layout=base_layout(title, x_label, y_label, height=480),
    )
    fig.update_layout(meta={"colour_range_mm": list(colours), "full_range_mm": list(full)})
    return fit_image_axes(fig, x_mm, y_mm)


def _hover(x_label: str, y_label: str, unit: str, quantity: str) -> str:
    """``X = %{x:.1f} mm<br>Y = ...<br>height = %{z:.3f} mm``: the axes' names (their titles before the unit)."""
    x_name, y_name = x_label.split(" (")[0], y_label.split(" (")[0]
    return f"{x_name} = %{{x:.1f}} {unit}<br>{y_name} = %{{y:.1f}} {unit}<br>{quantity} = %{{z:.3f}} mm<extra></extra>"


def profile_figure(
    x_mm: npt.ArrayLike,
    z_row_mm: npt.ArrayLike,
    row: int,
    gray_row_mm: npt.ArrayLike | None = None,
    *,
    quantity: str = "height",
    x_label: str = "X (mm)",
) -> go.Figure:
    """Height (or depth) along one image row (full resolution), GCPS; the gray-code-only profile if given."""
    fig = go.Figure(layout=base_layout(f"Profile along row {row}", x_label, f"{quantity} (mm)"))
    fig.add_trace(
        go.Scatter(
            x=np.asarray(x_mm, dtype=np.float32),
            y=np.asarray(z_row_mm, dtype=np.float32),
            mode="lines",
            name="GCPS",
            line={"color": PALETTE[0], "width": 1.5},
        )
    )
    if gray_row_mm is not None:
        fig.add_trace(
            go.Scatter(
                x=np.asarray(x_mm, dtype=np.float32),
                y=np.asarray(gray_row_mm, dtype=np.float32),
                mode="lines",
                name="gray code only",
                line={"color": PALETTE[1], "width": 1},
            )
        )
    return fig


def gray_vs_gcps_figure(
    x_mm: npt.ArrayLike, z_row_mm: npt.ArrayLike, gray_row_mm: npt.ArrayLike, row: int, *, x_label: str = "X (mm)"
) -> go.Figure:
    """Gray-code-only minus GCPS height along one row, in µm: the staircase the phase shift removes."""
    x = np.asarray(x_mm, dtype=np.float32)
    diff = (np.asarray(gray_row_mm, dtype=np.float64) - np.asarray(z_row_mm, dtype=np.float64)) * UM
    fig = go.Figure(layout=base_layout(f"Gray code only minus GCPS, row {row}", x_label, "difference (µm)"))
    fig.add_trace(
        go.Scatter(x=x, y=diff.astype(np.float32), mode="lines", name="gray only - GCPS", line={"color": PALETTE[4]})
    )
    fig.update_yaxes(tickformat=",.0f")  # "-10,000 µm", not "-10k µm"
    return fig


def surface_figure(
    xyz_mm: npt.ArrayLike, title: str = "3D view", max_jump_mm: float = math.inf, *, camera_frame: bool = False
) -> go.Figure:
    """3D view: the mesh of (decimated) grid points ``(h, w, 3)`` = X, Y, z in mm of the model frame.

    The triangles are those of the measurement's mesh files (:func:`metrology.core.mesh.grid_triangles`
    on the decimated grid): neighbouring finite points joined, steps higher than ``max_jump_mm``
    not bridged, NaN leaves holes. Drawn as a plotly ``Mesh3d`` coloured by z.

    The box fits the object, not its outliers: its aspect comes from the p1-p99 span of each
    coordinate (:func:`robust_range`), z is shown (and coloured) over its p1-p99 range widened by a
    tenth on each side, and the title says so when points lie beyond it (the hover shows every
    point's own value). ``layout.meta`` holds the z ranges (``z_shown_mm``, ``full_range_mm``).

    With ``camera_frame`` (points in a camera frame, OpenCV's axes: y down, z away from the camera)
    the y and z axes are drawn reversed, a rotation of 180 degrees about x (no mirror image), so the
    object faces the viewer as the camera saw it, nearer points up; otherwise (the paper's frame,
    z the height towards the rig) z is drawn upwards as it is.
    """
    from metrology.core.mesh import grid_triangles

    xyz = np.asarray(xyz_mm, dtype=np.float32)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz_mm must have shape (h, w, 3), got {xyz.shape}")
    valid = np.isfinite(xyz).all(axis=2)
    if not valid.any():
        return empty_figure(title, "No pixel was measured.")
    z = xyz[..., 2]
    triangles = grid_triangles(valid, np.where(valid, z, 0.0), max_jump_mm)
    points = xyz[valid]
    ranges = [robust_range(points[:, i]) or (0.0, 0.0) for i in range(3)]
    span = [(high - low) or 1.0 for low, high in ranges]
    biggest = max(span[0], span[1])
    z_low, z_high = ranges[2][0] - 0.1 * span[2], ranges[2][1] + 0.1 * span[2]
    full = full_range(points[:, 2]) or (z_low, z_high)
    beyond = int(np.count_nonzero((points[:, 2] < z_low) | (points[:, 2] > z_high)))
    if beyond:
        title = f"{title}; z shown over p1-p99, {beyond} point(s) beyond (full range {full[0]:.4g} to {full[1]:.4g} mm)"
    layout = base_layout(title, "", "", height=520, margin={"l": 0, "r": 0, "t": 50, "b": 0})
    layout["scene"] = {
        "xaxis": {"title": {"text": "X (mm)"}},
        "yaxis": {"title": {"text": "Y (mm)"}},
        # a flat box: few z labels
        "zaxis": {"title": {"text": "z (mm)"}, "nticks": 4, "tickformat": ".4~g", "range": [z_low, z_high]},
        "aspectmode": "manual",
        "aspectratio": {"x": span[0] / biggest, "y": span[1] / biggest, "z": max(0.15, min(1.0, span[2] / biggest))},
    }
    if camera_frame:  # y down and z away from the camera: turned 180 degrees about x to face the viewer
        y_low, y_high = ranges[1][0] - 0.1 * span[1], ranges[1][1] + 0.1 * span[1]
        layout["scene"]["yaxis"]["range"] = [y_high, y_low]
        layout["scene"]["zaxis"]["range"] = [z_high, z_low]
    layout["meta"] = {"z_shown_mm": [z_low, z_high], "full_range_mm": list(full), "camera_frame": camera_frame}
    fig = go.Figure(
        data=[
            go.Mesh3d(
                x=points[:, 0],
                y=points[:, 1],
                z=points[:, 2],
                i=triangles[:, 0],
                j=triangles[:, 1],
                k=triangles[:, 2],
                intensity=points[:, 2],
                cmin=ranges[2][0],
                cmax=ranges[2][1],
                colorscale="Viridis",
                colorbar={"title": {"text": "z (mm)"}},
                flatshading=False,
                hovertemplate="X = %{x:.1f} mm<br>Y = %{y:.1f} mm<br>z = %{z:.3f} mm<extra></extra>",
            )
        ],
        layout=layout,
    )
    return fig


def measurement_figures(
    z_mm: npt.ArrayLike,
    xyz_mm: npt.ArrayLike,
    row: int,
    *,
    gray_z_mm: npt.ArrayLike | None = None,
    x_mm: npt.ArrayLike | None = None,
    y_mm: npt.ArrayLike | None = None,
    max_jump_mm: float = math.inf,
    quantity: str = "height",
    x_label: str = "camera column (px)",
    y_label: str = "camera row (px)",
    unit: str = "px",
    camera_frame: bool = False,
) -> dict[str, go.Figure]:
    """Every figure of a measurement, from full-resolution data (decimated here).

    Parameters
    ----------
    z_mm : (H, W) float array
        GCPS heights (or depths), mm, NaN where invalid.
    xyz_mm : (H, W, 3) float array
        The points of each pixel in the model frame, mm.
    row : int
        Image row of the profiles, in [0, H).
    gray_z_mm : (H, W) float array, optional
        Gray-code-only height map, mm.
    x_mm, y_mm : (W,), (H,) float arrays, optional
        Coordinates of columns and rows (the model's image axes; default: pixel indices).
    quantity : {'height', 'depth'}
        What ``z_mm`` is (titles and colour bars say it).
    x_label, y_label, unit : str
        The axes' titles and the coordinates' unit.
    camera_frame : bool
        ``xyz_mm`` is in a camera frame (y down, z away from the camera): the 3D view is turned to
        face the viewer (:func:`surface_figure`).
    max_jump_mm : float, optional
        Depth-discontinuity threshold of the full-resolution mesh, mm
        (:func:`metrology.core.mesh.default_max_jump_mm`); the 3D view, decimated by blocks of
        ``f`` pixels, joins neighbours up to ``f * max_jump_mm`` apart (default: all neighbours).

    Returns
    -------
    dict of str -> Figure
        ``height_map``, ``profile``, ``gray_vs_gcps`` (only with ``gray_z_mm``), ``surface``.
    """
    z = np.asarray(z_mm, dtype=np.float32)
    if z.ndim != 2:
        raise ValueError(f"z_mm must be a 2D height map, got shape {z.shape}")
    h, w = z.shape
    if not 0 <= row < h:
        raise ValueError(f"row must lie in [0, {h}), got {row}")
    x = np.arange(w, dtype=np.float64) if x_mm is None else np.asarray(x_mm, dtype=np.float64)
    y = np.arange(h, dtype=np.float64) if y_mm is None else np.asarray(y_mm, dtype=np.float64)
    fr, fc = block_factors(z.shape)
    small = decimate(z)
    # the colours from the full-resolution map: decimation averages outliers into their blocks
    colours, full = robust_range(z), full_range(z)
    figures = {
        "height_map": height_map_figure(
            small,
            decimate_axis(x, fc),
            decimate_axis(y, fr),
            f"{quantity.capitalize()} map ({w} x {h} px, shown as {small.shape[1]} x {small.shape[0]})",
            quantity=quantity,
            x_label=x_label,
            y_label=y_label,
            unit=unit,
            colour_range=colours,
            value_range=full,
        )
    }
    gray = None if gray_z_mm is None else np.asarray(gray_z_mm, dtype=np.float32)
    figures["profile"] = profile_figure(
        x, z[row], row, None if gray is None else gray[row], quantity=quantity, x_label=x_label
    )
    if gray is not None:
        figures["gray_vs_gcps"] = gray_vs_gcps_figure(x, z[row], gray[row], row, x_label=x_label)
    xyz = np.asarray(xyz_mm)
    xyz_small = np.stack([decimate(xyz[..., i], MAX_ROWS_3D, MAX_COLS_3D) for i in range(3)], axis=-1)
    factor = max(block_factors(z.shape, MAX_ROWS_3D, MAX_COLS_3D))
    figures["surface"] = surface_figure(
        xyz_small,
        f"3D view (mesh of {xyz_small.shape[1]} x {xyz_small.shape[0]} points)",
        factor * max_jump_mm,
        camera_frame=camera_frame,
    )
    return figures
