"""What a calibration's report measures about its poses, beside the fit: how much of each image
their corners cover, how varied the boards are, the projector's response.

- :func:`image_coverage`: the cells of an ``8 x 8`` grid of each image holding a used corner, and
  each image edge's distance to the nearest one (:class:`Coverage`);
- :func:`pose_diversity`: the boards' tilts, the largest angle between two boards, the
  near-identical pairs and the boards' distances (:class:`PoseDiversity`);
- :func:`gamma_estimate`: the median of the used poses' gamma estimates;
- :func:`rotation_angle_deg`: the angle between two rotations.

Images span ``-0.5 .. W - 0.5`` (pixel centres at integers); sizes are ``(width, height)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.procam.fit import StereoFit
from metrology.core.procam.poses import PoseSelection

FloatArray = npt.NDArray[np.float64]

COVERAGE_CELLS = 8
EDGES = ("left", "right", "top", "bottom")
SIMILAR_ANGLE_DEG = 3.0
SIMILAR_SHIFT = 0.05
"""Two boards are near-identical when their orientations differ by less than this angle and their
positions by less than this fraction of the first one's distance from the camera."""


def rotation_angle_deg(Ra: npt.ArrayLike, Rb: npt.ArrayLike | None = None) -> float:
    """The angle of the rotation ``Ra Rb^T`` (``Ra`` alone when ``Rb`` is None), degrees:
    ``acos((trace - 1) / 2)``, the cosine clipped to ``[-1, 1]``. ``Ra``, ``Rb``: (3, 3); ValueError
    for another shape (TypeError for entries that are not numbers)."""
    A = np.asarray(Ra, dtype=np.float64)
    B = np.eye(3) if Rb is None else np.asarray(Rb, dtype=np.float64)
    if A.shape != (3, 3) or B.shape != (3, 3):
        raise ValueError(f"rotations must be 3x3, got {A.shape} and {B.shape}")
    M = A @ B.T
    c = (float(np.trace(M)) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def tilt_deg(R: FloatArray) -> float:
    """Angle between a board's normal ``R e_z`` and the camera's axis ``e_z``, degrees (0..90); ``R`` (3, 3)."""
    return math.degrees(math.acos(min(1.0, abs(float(R[2, 2])))))


def _coverage(points: list[FloatArray], width: float, height: float) -> float:
    """Fraction of an ``8 x 8`` grid of the image's cells holding at least one point (``(n, 2)`` each)."""
    cells = np.zeros((COVERAGE_CELLS, COVERAGE_CELLS), bool)
    for p in points:
        i = np.floor((p[:, 1] + 0.5) / height * COVERAGE_CELLS).astype(int)
        j = np.floor((p[:, 0] + 0.5) / width * COVERAGE_CELLS).astype(int)
        keep = (i >= 0) & (i < COVERAGE_CELLS) & (j >= 0) & (j < COVERAGE_CELLS)
        cells[i[keep], j[keep]] = True
    return float(cells.mean())


def _edge_gaps(points: list[FloatArray], width: float, height: float) -> dict[str, float]:
    """Distance from each edge of the image to the nearest point, as a fraction of the image's width
    (left, right) or height (top, bottom). 1.0 for every edge when there are no points."""
    pts = np.concatenate([p for p in points if p.size]) if any(p.size for p in points) else np.zeros((0, 2))
    pts = pts[np.isfinite(pts).all(axis=1)]
    if pts.shape[0] == 0:
        return dict.fromkeys(EDGES, 1.0)
    x, y = pts[:, 0], pts[:, 1]
    gaps = (
        (float(x.min()) + 0.5) / width,
        (width - 0.5 - float(x.max())) / width,
        (float(y.min()) + 0.5) / height,
        (height - 0.5 - float(y.max())) / height,
    )
    return {edge: max(0.0, g) for edge, g in zip(EDGES, gaps, strict=True)}


@dataclass(frozen=True)
class Coverage:
    """How much of each image the used corners of the used poses cover.

    Attributes
    ----------
    camera, projector : float
        Fraction (0..1) of the cells of a ``COVERAGE_CELLS x COVERAGE_CELLS`` grid of the image
        holding a corner.
    edge_gaps : mapping ``"camera"``/``"projector"`` -> mapping edge -> float
        Distance from the image's ``left``, ``right``, ``top`` and ``bottom`` edge to the nearest
        corner, a fraction of its width (left, right) or height (top, bottom).
    """

    camera: float
    projector: float
    edge_gaps: Mapping[str, Mapping[str, float]]


def image_coverage(selection: PoseSelection, camera_size: tuple[int, int], projector_size: tuple[int, int]) -> Coverage:
    """The :class:`Coverage` of ``selection``'s used corners (float64 points, as observed)."""
    cam_points, proj_points = [], []
    for p in selection.used:
        assert p.camera_px is not None and p.projector_px is not None
        mask = selection.masks[p.name]
        cam_points.append(p.camera_px[mask])
        proj_points.append(p.projector_px[mask])
    (cam_w, cam_h), (proj_w, proj_h) = camera_size, projector_size
    return Coverage(
        camera=_coverage(cam_points, cam_w, cam_h),
        projector=_coverage(proj_points, proj_w, proj_h),
        edge_gaps={
            "camera": _edge_gaps(cam_points, cam_w, cam_h),
            "projector": _edge_gaps(proj_points, proj_w, proj_h),
        },
    )


@dataclass(frozen=True)
class PoseDiversity:
    """How varied the fitted boards are.

    Attributes
    ----------
    names : tuple of str
        The used poses, in order.
    tilts_deg : tuple of float
        Each used pose's board tilt from the camera's axis (:func:`tilt_deg`), degrees, in order.
    max_angle_deg : float
        The largest angle between two boards' normals (0 for one pose), degrees.
    similar_pairs : tuple of (str, str)
        The pairs of poses whose boards are near-identical (:data:`SIMILAR_ANGLE_DEG`,
        :data:`SIMILAR_SHIFT`), each in pose order, in pose order.
    distances_mm : tuple of float
        Each used pose's board distance ``|t_i|`` from the camera, mm.
    """

    names: tuple[str, ...]
    tilts_deg: tuple[float, ...]
    max_angle_deg: float
    similar_pairs: tuple[tuple[str, str], ...]
    distances_mm: tuple[float, ...]

    @property
    def median_distance_mm(self) -> float:
        return float(np.median(self.distances_mm))


def pose_diversity(stereo: StereoFit) -> PoseDiversity:
    """The :class:`PoseDiversity` of the stereo fit's board poses (camera frame).

    Pair ``(a, b)`` is near-identical when ``rotation_angle_deg(R_a, R_b) < SIMILAR_ANGLE_DEG``
    and ``|t_a - t_b| / |t_a| < SIMILAR_SHIFT``; the angle between boards is that between their
    normals ``R e_z`` (either side), ``acos |n_a . n_b|``.
    """
    names = stereo.names
    poses = [stereo.board_pose(name) for name in names]
    similar: list[tuple[str, str]] = []
    max_pair = 0.0
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            (Ra, ta), (Rb, tb) = poses[a], poses[b]
            ang = rotation_angle_deg(Ra, Rb)
            max_pair = max(max_pair, math.degrees(math.acos(float(np.clip(abs(Ra[:, 2] @ Rb[:, 2]), -1, 1)))))
            shift = float(np.linalg.norm(ta - tb)) / max(float(np.linalg.norm(ta)), 1e-9)
            if ang < SIMILAR_ANGLE_DEG and shift < SIMILAR_SHIFT:
                similar.append((names[a], names[b]))
    return PoseDiversity(
        names=names,
        tilts_deg=tuple(tilt_deg(R) for R, _ in poses),
        max_angle_deg=max_pair,
        similar_pairs=tuple(similar),
        distances_mm=tuple(float(np.linalg.norm(t)) for _, t in poses),
    )


def gamma_estimate(selection: PoseSelection) -> float | None:
    """The median of the used poses' finite gamma estimates (None when none has one)."""
    gammas = [p.gamma for p in selection.used if p.gamma is not None and math.isfinite(p.gamma)]
    return float(np.median(gammas)) if gammas else None
