"""Triangulation of the crossed-axes rig: light codes to abscissae on R (Eq. 14) and heights (Eqs. 16-17).

The functions live in :mod:`metrology.core.geometry.crossed_axes`, with the rest of the paper's
model; this module keeps their historical import path.
"""

from __future__ import annotations

from metrology.core.geometry.crossed_axes import (
    FloatArray,
    abscissa_from_codes,
    abscissa_from_codes_eq14,
    camera_ray_point,
    codes_from_abscissa,
    codes_of_points,
    codes_on_camera_rays,
    displacement_from_codes,
    height_from_abscissae,
    height_from_codes,
    height_from_displacement,
    points_from_heights,
    projector_abscissa,
    reference_slope_mm,
)

__all__ = [
    "FloatArray",
    "abscissa_from_codes",
    "abscissa_from_codes_eq14",
    "camera_ray_point",
    "codes_from_abscissa",
    "codes_of_points",
    "codes_on_camera_rays",
    "displacement_from_codes",
    "height_from_abscissae",
    "height_from_codes",
    "height_from_displacement",
    "points_from_heights",
    "projector_abscissa",
    "reference_slope_mm",
]
