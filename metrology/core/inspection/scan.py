"""The scan of an inspection: points in the input's order, with their sigma and how it is meant.

Two forms (docs/inspection.md):

- a point cloud (a PLY's vertices): ``shape = (N,)``, ``sigma_mm`` (optional) the point's
  standard uncertainty in every direction, used as is along the normal;
- a point map (``gcps measure --xyz``): ``shape = (H, W)``, NaN meaning no point, ``sigma_mm``
  (optional, ``gcps measure --sigma``) along the camera ray from the scan frame's origin
  (``sigma_along_ray``), projected onto the normal by the conformance step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metrology.core.io.meshes import read_ply_vertices


@dataclass(frozen=True, eq=False)
class Scan:
    """Scan points (module docstring).

    Attributes
    ----------
    points_mm : (N, 3) float64
        Every input point in input order (a point map's pixels row-major), NaN rows for no point.
    shape : tuple of int
        ``(N,)`` or ``(H, W)``: the shape of per-point outputs (the deviation map).
    sigma_mm : (N,) float64 or None
        Standard uncertainty of each point, mm.
    sigma_along_ray : bool
        ``sigma_mm`` is along the camera ray from ``ray_origin_mm`` (else in every direction).
    ray_origin_mm : (3,) float64
        The camera's centre in the scan frame (the origin for ``gcps measure`` points).
    source : dict
        Where the points come from, for the report's provenance (file names and hashes).
    """

    points_mm: np.ndarray
    shape: tuple[int, ...]
    sigma_mm: np.ndarray | None = None
    sigma_along_ray: bool = False
    ray_origin_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    source: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        points = self.points_mm
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] != int(np.prod(self.shape)):
            raise ValueError(f"scan: points must be (N, 3) with N = {int(np.prod(self.shape))}, got {points.shape}")
        if self.sigma_mm is not None and self.sigma_mm.shape != (points.shape[0],):
            raise ValueError(f"scan: sigma has {self.sigma_mm.size} values for {points.shape[0]} points")

    @property
    def valid(self) -> np.ndarray:
        """``(N,)`` bool: points whose three coordinates are finite."""
        return np.isfinite(self.points_mm).all(axis=1)


def scan_from_ply(data: bytes, source: dict[str, Any] | None = None) -> Scan:
    """The scan of a PLY file's bytes: vertices ``x y z`` (mm) and, when present, ``sigma_mm``."""
    columns = read_ply_vertices(data)
    points = np.stack([columns[k].astype(np.float64) for k in ("x", "y", "z")], axis=1)
    sigma = columns["sigma_mm"].astype(np.float64) if "sigma_mm" in columns else None
    return Scan(points, (points.shape[0],), sigma, False, source=dict(source or {}))


def scan_from_point_map(
    points_mm: np.ndarray, sigma_mm: np.ndarray | None = None, source: dict[str, Any] | None = None
) -> Scan:
    """The scan of an ``(H, W, 3)`` point map (mm, NaN for no point) and its ``(H, W)`` sigma along the rays."""
    points = np.asarray(points_mm)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"scan: a point map must be (H, W, 3), got shape {points.shape}")
    height, width = points.shape[:2]
    sigma = None
    if sigma_mm is not None:
        sigma_map = np.asarray(sigma_mm)
        if sigma_map.shape != (height, width):
            raise ValueError(f"--sigma has shape {sigma_map.shape}, the points (H, W) = {(height, width)}")
        sigma = sigma_map.astype(np.float64).reshape(-1)
    flat = points.astype(np.float64).reshape(-1, 3)
    return Scan(flat, (height, width), sigma, True, source=dict(source or {}))
