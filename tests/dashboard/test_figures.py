"""Figure builders and page summaries on plain data (no database, no browser)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize

from metrology.dashboard.selectors import calibration_stop_reason
from metrology.dashboard.templatetags.dashboard import sig
from metrology.figures.calibration import iteration_points, parameters_figure


def paper_history(values: list[tuple[float, float]]) -> list[dict]:
    return [
        {"L_mm": L, "alpha_rad": a, "d_mm": 352.0, "mean_height_mm": 40.0 + i, "slope": 1e-3, "step": "alpha"}
        for i, (L, a) in enumerate(values)
    ]


def test_iteration_points_start_at_zero_and_end_on_the_result():
    history = paper_history([(1080.0, 0.4871), (1080.0, 0.35), (1030.0, 0.35)])
    # converged: the last profiled estimate is the result, three points, two iterations
    converged = iteration_points(history, {"L_mm": 1030.0, "alpha_rad": 0.35, "d_mm": 352.0})
    assert len(converged) == 3
    # stopped at the limit: the last update was never profiled, so the result is appended
    stopped = iteration_points(history, {"L_mm": 1022.5, "alpha_rad": 0.332, "d_mm": 352.0})
    assert len(stopped) == 4 and stopped[-1]["L_mm"] == 1022.5 and math.isnan(stopped[-1]["mean_height_mm"])
    fig = parameters_figure(history, {"L_mm": 1022.5, "alpha_rad": 0.332, "d_mm": 352.0})
    assert list(fig.data[0].x) == [0, 1, 2, 3]
    assert fig.data[0].text[0].startswith("start") and fig.data[0].text[-1].endswith("(result)")
    assert list(fig.data[0].y) == [1080.0, 1080.0, 1030.0, 1022.5]


def scipy_message(**tolerances: float) -> str:
    """A real message of scipy's least_squares on y = a x fitted to a line."""
    x = np.linspace(0.0, 1.0, 20)
    y = 2.0 * x + 0.01 * np.sin(7 * x)
    options = {"ftol": 1e-15, "xtol": 1e-15, "gtol": 1e-15, **tolerances}
    sol = optimize.least_squares(lambda p: p[0] * x + p[1] - y, [0.0, 0.0], method="trf", **options)
    return str(sol.message)


@pytest.mark.parametrize(
    ("tolerances", "words"),
    [
        ({"ftol": 0.5}, "residuals stopped decreasing"),
        ({"xtol": 0.5}, "fitted values stopped changing"),
        ({"gtol": 0.5}, "gradient vanished"),
        ({"max_nfev": 1}, "iteration limit (8)"),
    ],
)
def test_optimizer_messages_become_plain_words(tolerances, words):
    message = scipy_message(**tolerances)
    assert "`" in message or "maximum" in message  # scipy's own wording, as stored
    text = calibration_stop_reason(
        "lsq", {"message": message, "converged": True, "parameters": {"tolerance": 1e-10, "max_iterations": 8}}
    )
    assert words in text and "`" not in text and "tol" not in text.replace("tolerance", "")


def test_paper_stop_reasons_in_words():
    options = {"delta_z_mm": 0.025, "m_hat": 0.0001, "max_iterations": 30}
    done = calibration_stop_reason("paper", {"message": "converged", "converged": True, "parameters": options})
    assert done == "the master's mean height is within 25 µm of H and its slope within 0.0001"
    limit = calibration_stop_reason("paper", {"message": "not converged after 30 iterations", "parameters": options})
    assert "iteration limit (30)" in limit


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (0.02134, "0.021"),
        (12.34, "12"),
        (1.5, "1.5"),
        (0.0, "0"),
        (3.1e-9, "3.1e-09"),
        (None, "n/a"),
        (math.nan, "n/a"),
    ],
)
def test_significant_digits(value, text):
    assert sig(value) == text


def paper_rig_axes(width: int = 640, height: int = 480) -> tuple[np.ndarray, np.ndarray]:
    """Column X and row Y of the paper's rig (d = 352 mm, FW = 500 mm): x_A = d - FW/2 + (j + 0.5) FW/N."""
    pitch = 500.0 / width
    x = 352.0 - 250.0 + (np.arange(width) + 0.5) * pitch
    y = (np.arange(height) + 0.5 - height / 2) * pitch
    return x, y


def test_height_map_axes_span_the_data_and_say_y_runs_down():
    from metrology.figures.measurement import height_map_figure

    x, y = paper_rig_axes()
    z = np.zeros((y.size, x.size), dtype=np.float32)
    layout = height_map_figure(z, x, y).layout
    half = 0.5 * (x[1] - x[0])
    assert layout.xaxis.range == pytest.approx((x[0] - half, x[-1] + half))  # 102.0 .. 602.0 mm, not -150 .. 860
    assert layout.xaxis.range[0] == pytest.approx(102.0) and layout.xaxis.range[1] == pytest.approx(602.0)
    assert layout.yaxis.range == pytest.approx((y[-1] + half, y[0] - half))  # reversed: image rows run down
    assert layout.xaxis.constrain == layout.yaxis.constrain == "domain"  # equal scale shrinks the plot, not the data
    assert "down" in layout.yaxis.title.text


def test_residual_map_axes_span_the_data():
    from metrology.figures.calibration import residual_figure

    x, y = paper_rig_axes(160, 120)
    residual = np.full((120, 160), 1e-4)
    layout = residual_figure(residual, x, y).layout
    half = 0.5 * (x[1] - x[0])
    assert layout.xaxis.range == pytest.approx((x[0] - half, x[-1] + half))
    assert layout.xaxis.constrain == "domain" and "down" in layout.yaxis.title.text


def test_surface_z_axis_has_few_ticks():
    from metrology.figures.measurement import surface_figure

    x, y = paper_rig_axes(160, 120)
    xx, yy = np.meshgrid(x, y)
    z = np.where((xx > 200) & (xx < 400), 40.0, 0.0)
    zaxis = surface_figure(np.stack([xx, yy, z], axis=-1)).layout.scene.zaxis
    assert zaxis.nticks is not None and zaxis.nticks <= 4


def test_a_camera_frame_surface_faces_the_viewer_nearer_points_up():
    """Camera-frame points (y down, z away from the camera, a pinhole rig's): the 3D view reverses y
    and z (a 180-degree turn about x, no mirror), so a sphere standing 60 mm out of a plane 1300 mm
    away is drawn above it, not behind it; the paper's frame keeps z upwards."""
    from metrology.figures.measurement import surface_figure

    yy, xx = np.mgrid[-100:100:41j, -150:150:61j]
    z = 1300.0 - 60.0 * np.clip(1 - (xx**2 + yy**2) / 50.0**2, 0, None)
    xyz = np.stack([xx, yy, z], axis=-1)
    camera = surface_figure(xyz, camera_frame=True).layout.scene
    assert camera.zaxis.range[0] > camera.zaxis.range[1]  # nearer (smaller z) drawn higher
    assert camera.yaxis.range[0] > camera.yaxis.range[1]  # and y turned with it: not mirrored
    assert camera.zaxis.range[0] >= 1300.0 > 1240.0 >= camera.zaxis.range[1]
    paper = surface_figure(xyz).layout.scene
    assert paper.zaxis.range[0] < paper.zaxis.range[1] and paper.yaxis.range is None


def test_empty_figures_say_why_and_offer_no_download():
    from metrology.dashboard.templatetags.dashboard import plotly_figure
    from metrology.figures import empty_figure, is_empty
    from metrology.figures.calibration import residual_figure

    empty = residual_figure(None, *paper_rig_axes(160, 120))
    assert is_empty(empty)
    html = str(plotly_figure(empty, "calibration_residual", "Residual map"))
    assert 'id="fig-calibration_residual"' in html and "This method stores no residual map" in html
    assert "js-download" not in html and "PNG" not in html and "application/json" not in html
    drawn = str(plotly_figure(residual_figure(np.zeros((120, 160)), *paper_rig_axes(160, 120)), "residual"))
    assert "js-download" in drawn and "PNG" in drawn
    assert not is_empty(empty_figure("t", "m").add_scatter(x=[1], y=[1]))  # a figure with data is not empty


def test_maps_and_the_3d_view_fit_the_object_not_its_outliers():
    """A 25 mm block on a plane, with a shattered border of +-60 mm: the colours span p1-p99 (the
    object), the colour bar states the full range, and the 3D box's z fits the object."""
    from metrology.figures.measurement import measurement_figures

    rng = np.random.default_rng(3)
    h, w = 120, 160
    z = np.zeros((h, w), dtype=np.float32)
    z[40:80, 50:110] = 25.0
    border = rng.random((h, w)) < 0.004
    z[border] = rng.choice([-60.0, 60.0], size=int(border.sum()))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    xyz = np.stack([xx * 0.5, yy * 0.5, z], axis=-1)
    figures = measurement_figures(z, xyz, 60)
    heatmap = figures["height_map"].data[0]
    assert (heatmap.zmin, heatmap.zmax) == (0.0, 25.0)
    assert figures["height_map"].layout.meta["full_range_mm"] == [-60.0, 60.0]
    assert "full range -60 to 60 mm" in heatmap.colorbar.title.text
    surface = figures["surface"]
    low, high = surface.layout.scene.zaxis.range
    assert -5.0 < low < 0.0 and 25.0 < high < 30.0, (low, high)
    assert (surface.data[0].cmin, surface.data[0].cmax) == (0.0, 25.0)
    assert surface.layout.scene.aspectratio.z == pytest.approx(25.0 / (w * 0.5 - 0.5), rel=0.05)
    assert "point(s) beyond (full range -60 to 60 mm)" in surface.layout.title.text
    # the hover shows each cell's own value, not the clipped colour
    assert "%{z:.3f} mm" in heatmap.hovertemplate


def test_a_map_without_outliers_keeps_its_whole_range_and_a_plain_title():
    from metrology.figures.measurement import measurement_figures

    z = np.tile(np.linspace(0.0, 10.0, 100, dtype=np.float32), (50, 1))
    yy, xx = np.mgrid[0:50, 0:100].astype(np.float32)
    figures = measurement_figures(z, np.stack([xx, yy, z], axis=-1), 10)
    heatmap = figures["height_map"].data[0]
    assert 0.0 <= heatmap.zmin < 0.2 and 9.8 < heatmap.zmax <= 10.0
    assert "beyond" not in figures["surface"].layout.title.text
