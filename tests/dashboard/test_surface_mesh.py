"""The measurement page's 3D view: a decimated mesh built on request, steps not bridged."""

from __future__ import annotations

import numpy as np

from metrology.core.geometry.crossed_axes import PAPER_RIG, points_from_heights
from metrology.core.mesh import default_max_jump_mm
from metrology.figures.measurement import MAX_COLS_3D, MAX_ROWS_3D, measurement_figures, surface_figure


def test_surface_is_a_mesh_that_does_not_bridge_steps() -> None:
    rig = PAPER_RIG  # 640 x 480: decimated by blocks of 3 rows x 4 columns to 160 x 160 points
    z = np.zeros(rig.shape)
    z[:, 320:] = 30.0  # a 30 mm step along a block boundary
    z[99:141, 100:140] = np.nan  # a hole of 14 x 10 blocks
    figures = measurement_figures(z, points_from_heights(rig, z), 10, max_jump_mm=default_max_jump_mm(rig))
    (trace,) = figures["surface"].data
    assert trace.type == "mesh3d"
    x, y, zz = (np.asarray(trace[name]) for name in ("x", "y", "z"))
    i, j, k = (np.asarray(trace[name]) for name in ("i", "j", "k"))
    assert len(x) == 160 * 160 - 14 * 10 and len(x) <= MAX_ROWS_3D * MAX_COLS_3D
    corners = np.stack([zz[i], zz[j], zz[k]], axis=1)
    assert np.ptp(corners, axis=1).max() == 0.0  # no triangle joins the two levels
    # a 159 x 159-cell grid less the step's column of cells and the 15 x 11 cells touching the hole
    assert len(i) == 2 * (159 * 159 - 159 - 15 * 11) + 4  # the hole's four corner cells keep one triangle each
    assert np.isclose(np.sort(np.unique(zz)), [0.0, 30.0]).all()
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(y))


def test_surface_of_nothing_measured_says_so() -> None:
    xyz = np.full((4, 5, 3), np.nan)
    fig = surface_figure(xyz)
    assert "No pixel was measured" in str(fig.layout.annotations[0].text)
