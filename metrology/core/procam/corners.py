"""Board corners mapped into the projector by local homographies (Moreno and Taubin, 2012).

For a corner at camera point ``p`` (pixels), the decoded projector coordinates ``(u, v)`` of the
camera pixels ``q`` in a square window of half-size ``w`` around it are fitted by a homography
``H`` (3x3, camera pixels to projector units): ``(u, v) ~ H (q_x, q_y, 1)``. The board is a
plane, so ``H`` is exact up to lens distortion, which is negligible over the window. The fit is
RANSAC (``cv2.findHomography``, reprojection threshold in projector units: decoding errors,
slips and pixels off the board are outliers) refined by Levenberg-Marquardt on the inliers; the
corner's projector point is ``H p``.

Each corner records the decoded fraction of its window (pixels with both u and v decoded), the
inlier fraction and the RMS of the inliers' residuals (projector units).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

MIN_WINDOW_POINTS = 12
"""Fewest decoded pixels a window needs for a homography."""


@dataclass(frozen=True)
class ProjectedCorner:
    """One corner mapped into the projector.

    Attributes
    ----------
    projector_px : (2,) float64
        ``H p``, projector units; NaN when the window could not be fitted.
    decoded_fraction : float
        Fraction of the window's pixels with both axes decoded, 0..1.
    inlier_fraction : float
        Fraction of the decoded pixels the RANSAC fit kept, 0..1.
    fit_rms : float
        RMS distance of the inliers to the fitted homography, projector units (NaN if no fit).
    """

    projector_px: FloatArray
    decoded_fraction: float
    inlier_fraction: float
    fit_rms: float

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.projector_px).all())


def auto_window(corners_px: npt.ArrayLike, cols: int) -> int:
    """Default half-window, pixels: half the median distance between neighbouring corners, 4..30."""
    pts = np.asarray(corners_px, dtype=np.float64).reshape(-1, cols, 2)
    step = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    return int(np.clip(round(0.5 * float(np.median(step))), 4, 30))


def project_corners(
    corners_px: npt.ArrayLike,
    u: npt.ArrayLike,
    v: npt.ArrayLike,
    half_window: int,
    ransac_threshold: float = 1.5,
) -> list[ProjectedCorner]:
    """Map camera corners into the projector by local homographies of the decoded ``(u, v)``.

    Parameters
    ----------
    corners_px : (N, 2) float
        Camera corners, pixels (centres at integers).
    u, v : (H, W) float
        Decoded projector column and row coordinates, projector units, NaN where not decoded.
    half_window : int
        The window is ``(2 w + 1)^2`` pixels centred on the corner's nearest pixel.
    ransac_threshold : float
        RANSAC reprojection threshold, projector units (1.5 suits single-pixel gray codes,
        whose decoded coordinates are quantised to +-0.5).

    Returns
    -------
    list of ProjectedCorner, one per corner.
    """
    pts = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    U = np.asarray(u)
    V = np.asarray(v)
    if U.shape != V.shape or U.ndim != 2:
        raise ValueError(f"u and v must be (H, W) arrays of one shape, got {U.shape} and {V.shape}")
    if half_window < 1:
        raise ValueError(f"half_window must be >= 1 pixel, got {half_window}")
    H_img, W_img = U.shape
    w = int(half_window)
    offsets = np.arange(-w, w + 1)
    out: list[ProjectedCorner] = []
    nan2 = np.full(2, np.nan)
    for px, py in pts:
        cx, cy = round(px), round(py)
        x0, x1 = max(cx - w, 0), min(cx + w + 1, W_img)
        y0, y1 = max(cy - w, 0), min(cy + w + 1, H_img)
        total = offsets.size**2
        if x1 <= x0 or y1 <= y0:
            out.append(ProjectedCorner(nan2.copy(), 0.0, 0.0, float("nan")))
            continue
        uu = np.asarray(U[y0:y1, x0:x1], dtype=np.float64)
        vv = np.asarray(V[y0:y1, x0:x1], dtype=np.float64)
        ok = np.isfinite(uu) & np.isfinite(vv)
        n = int(ok.sum())
        decoded = n / total
        if n < MIN_WINDOW_POINTS:
            out.append(ProjectedCorner(nan2.copy(), decoded, 0.0, float("nan")))
            continue
        yy, xx = np.nonzero(ok)
        src = np.stack([xx + x0 - px, yy + y0 - py], axis=1)  # centred on the corner: well conditioned
        dst = np.stack([uu[ok], vv[ok]], axis=1)
        H, mask = cv2.findHomography(src, dst, cv2.RANSAC, ransac_threshold, maxIters=2000, confidence=0.999)
        if H is None or mask is None:
            out.append(ProjectedCorner(nan2.copy(), decoded, 0.0, float("nan")))
            continue
        inl = mask.ravel().astype(bool)
        mapped = cv2.perspectiveTransform(src[inl].reshape(-1, 1, 2), H).reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((mapped - dst[inl]) ** 2, axis=1))))
        p = H @ np.array([0.0, 0.0, 1.0])
        out.append(ProjectedCorner(p[:2] / p[2], decoded, float(inl.mean()), rms))
    return out
