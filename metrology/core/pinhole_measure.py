"""Measuring with a pinhole rig: decoded projector coordinates to points, depth or heights, and sigma.

The measurement a ``gcps measure --rig PINHOLE.json`` run makes once the captures are decoded
(docs/pinhole.md):

- points ``(H, W, 3)`` float32 mm in the camera frame, NaN where not triangulated (``--xyz``);
- without a reference capture, ``z_mm`` is the depth (camera Z, mm); with one, the signed
  distance to the total-least-squares plane through every triangulated point of the reference,
  positive towards the camera (``--out``);
- with a per-pixel sigma of the triangulated axis's coordinate (projector units), the points'
  standard uncertainty in mm (``--sigma``), first-order propagation through the triangulation.

:func:`metrology.core.uncertainty.coordinate_sigma` gives that coordinate sigma from an N-step phase decoding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.geometry.base import check_axes, check_frame
from metrology.core.geometry.pinhole import PinholeReference, PinholeRig, PreparedPinhole
from metrology.core.tiling import run_tiled


@dataclass(frozen=True)
class PinholeMeasurement:
    """Output of :func:`measure_pinhole`.

    Attributes
    ----------
    points_mm : (H, W, 3) float32
        Points in the camera frame, mm, NaN where not triangulated.
    z_mm : (H, W) float32
        Depth (camera Z) without a reference; height above the reference plane with one (mm).
    sigma_mm : (H, W) float32 or None
        Standard uncertainty of each point along its camera ray, mm (when a sigma map was given).
    reference : PinholeReference or None
        The reference plane used (centroid, unit normal towards the camera, point count).
    axis, method : str
        The projector axis triangulated (u or v) and the method (plane or midpoint).
    """

    points_mm: np.ndarray
    z_mm: np.ndarray
    sigma_mm: np.ndarray | None
    reference: PinholeReference | None
    axis: str
    method: str


def measure_pinhole(
    rig: PinholeRig,
    u: np.ndarray | None,
    v: np.ndarray | None,
    *,
    reference_uv: tuple[np.ndarray | None, np.ndarray | None] | None = None,
    sigma: np.ndarray | None = None,
    axis: str = "auto",
    method: str = "plane",
    projector_size: tuple[float, float] | None = None,
    threads: int | None = None,
) -> PinholeMeasurement:
    """Triangulate decoded projector coordinates with a pinhole rig.

    Parameters
    ----------
    rig : PinholeRig
    u, v : (H, W) float32 arrays or None
        Decoded projector coordinates of the object capture (NaN where not decoded).
    reference_uv : (u, v) of the reference capture, optional
        When given, ``z_mm`` holds heights above the plane fitted to it.
    sigma : (H, W) float array, optional
        Sigma of the triangulated axis's coordinate, projector units
        (:func:`metrology.core.uncertainty.coordinate_sigma`).
    axis, method : str
        ``auto|u|v`` and ``plane|midpoint`` (see :meth:`PinholeRig.prepare`).
    projector_size : (width, height), optional
        The codec's projector size; must equal the rig's.
    """
    prep: PreparedPinhole = rig.prepare(rig.shape, projector_size, axis=axis, method=method)
    check_axes(prep, u, v)
    check_frame(prep, "u", u)
    check_frame(prep, "v", v)
    check_frame(prep, "sigma", sigma)
    reference = None
    if reference_uv is not None:
        reference = prep.reference(reference_uv[0], reference_uv[1], threads=threads)
    h, w = prep.shape
    points = np.empty((h, w, 3), np.float32)
    z = np.empty((h, w), np.float32)
    sigma_mm = np.empty((h, w), np.float32) if sigma is not None else None
    sig = None if sigma is None else np.asarray(sigma, np.float32)

    def run(rows: slice) -> None:
        prep.triangulate_rows(
            rows,
            None if u is None else u[rows],
            None if v is None else v[rows],
            reference=reference,
            points_out=points[rows],
            height_out=z[rows] if reference is not None else None,
            sigma_in=None if sig is None else sig[rows],
            sigma_out=None if sigma_mm is None else sigma_mm[rows],
        )
        if reference is None:
            z[rows] = points[rows, :, 2]

    run_tiled(run, h, w, threads)
    if sigma_mm is not None:
        sigma_mm[np.isnan(points[..., 2])] = np.nan
    return PinholeMeasurement(
        points_mm=points, z_mm=z, sigma_mm=sigma_mm, reference=reference, axis=prep.axis, method=prep.method
    )
