"""Board corners mapped into the projector by local homographies (Moreno and Taubin, 2012).

For a corner at camera point ``p`` (pixels), the decoded projector coordinates ``(u, v)`` of the
camera pixels ``q`` in a square window of half-size ``w`` around it are fitted by a homography
``H`` (3x3, camera pixels to projector units): ``(u, v) ~ H (q_x, q_y, 1)``. The board is a
plane, so ``H`` is exact up to lens distortion, which is negligible over the window.

The fit has two stages:

1. RANSAC (``cv2.findHomography``, reprojection threshold in projector units) picks the inliers:
   decoding errors, slips and pixels off the board are outliers;
2. weighted least squares on the inliers (Gauss-Newton, ``h33 = 1``, camera offsets
   ``(q - p) / w`` so that the corner sits at the origin and ``H p = (h13, h23)``) minimises
   ``sum_i a_i (H_u(q_i) - u_i)^2 + b_i (H_v(q_i) - v_i)^2``.

The weights are the inverse variances of the decoded coordinates. An N-step phase gives a
coordinate noise ``sigma_u = P / (2 pi) sqrt(2 / N) sigma_I / B`` (``B`` the modulation, grey
levels), so with the camera noise ``sigma_I`` the same over the window ``a_i = B_u,i^2`` and
``b_i = B_v,i^2`` (up to a common factor). On a chessboard this matters: the dark squares'
modulation is about a tenth of the light squares', their coordinates about ten times noisier
(0.1 projector units per pixel on the light squares, 1 on the dark ones, on the virtual rig with
8-bit images and 1.5 grey levels of noise), and an unweighted fit lets them dominate the corner's
error (the same renders, true camera corners, half-window 21 px: 0.0096 projector units RMS
unweighted, 0.0041 weighted). Without modulation maps all weights are 1.

RANSAC's own estimate is not used: ``cv2.findHomography(..., cv2.RANSAC)`` of OpenCV 5.0.0 does
not return the least-squares minimum over its inliers (0.021 projector units RMS in the example
above against 0.0096 for the unweighted least squares on the same inliers; its sum of squared
residuals over the inliers is about 3 % above the minimum). OpenCV 4.x documents a Levenberg-Marquardt
refinement on the inliers; this was not checked against 4.x here.

Each corner records the decoded fraction of its window (pixels with both u and v decoded), the
inlier fraction and the RMS of the inliers' residuals (projector units, unweighted).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

MIN_WINDOW_POINTS = 12
"""Fewest decoded pixels a window needs for a homography."""

REFINE_ITERATIONS = 20
"""Gauss-Newton iterations of the weighted refinement at most."""

REFINE_TOLERANCE = 1e-9
"""The refinement stops when the corner's projector point moves less than this, projector units."""


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


def refine_homography(
    H: npt.ArrayLike,
    src: npt.ArrayLike,
    dst: npt.ArrayLike,
    weights_u: npt.ArrayLike | None = None,
    weights_v: npt.ArrayLike | None = None,
) -> FloatArray:
    """Weighted least-squares homography by Gauss-Newton from a starting ``H``.

    Minimises ``sum_i a_i (H_u(s_i) - d_i,u)^2 + b_i (H_v(s_i) - d_i,v)^2`` over the 8 entries of
    ``H`` with ``h33 = 1``, where ``H_u(s) = (h11 x + h12 y + h13) / (h31 x + h32 y + 1)`` and
    likewise ``H_v``.

    Parameters
    ----------
    H : (3, 3) float, the start (``h33 != 0``)
    src : (n, 2) float, source points (best centred and scaled to about unit size)
    dst : (n, 2) float, target points
    weights_u, weights_v : (n,) float >= 0, optional (default 1)

    Returns
    -------
    (3, 3) float64 with ``h33 = 1``.
    """
    H0 = np.asarray(H, dtype=np.float64)
    h = (H0 / H0[2, 2]).ravel()[:8].copy()
    s = np.asarray(src, dtype=np.float64)
    d = np.asarray(dst, dtype=np.float64)
    x, y = s[:, 0], s[:, 1]
    n = x.size
    ra = np.sqrt(np.ones(n) if weights_u is None else np.asarray(weights_u, dtype=np.float64))
    rb = np.sqrt(np.ones(n) if weights_v is None else np.asarray(weights_v, dtype=np.float64))
    zero = np.zeros(n)
    for _ in range(REFINE_ITERATIONS):
        w = h[6] * x + h[7] * y + 1.0
        u = (h[0] * x + h[1] * y + h[2]) / w
        v = (h[3] * x + h[4] * y + h[5]) / w
        ju = np.stack([x / w, y / w, 1.0 / w, zero, zero, zero, -u * x / w, -u * y / w], axis=1) * ra[:, None]
        jv = np.stack([zero, zero, zero, x / w, y / w, 1.0 / w, -v * x / w, -v * y / w], axis=1) * rb[:, None]
        J = np.concatenate([ju, jv])
        r = np.concatenate([ra * (u - d[:, 0]), rb * (v - d[:, 1])])
        try:
            step = np.linalg.solve(J.T @ J, -(J.T @ r))
        except np.linalg.LinAlgError:
            return np.full((3, 3), np.nan)
        h += step
        if not np.all(np.isfinite(h)):
            break
        if abs(step[2]) < REFINE_TOLERANCE and abs(step[5]) < REFINE_TOLERANCE:
            break
    return np.append(h, 1.0).reshape(3, 3)


def project_corners(
    corners_px: npt.ArrayLike,
    u: npt.ArrayLike,
    v: npt.ArrayLike,
    half_window: int,
    ransac_threshold: float = 1.5,
    modulation_u: npt.ArrayLike | None = None,
    modulation_v: npt.ArrayLike | None = None,
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
    modulation_u, modulation_v : (H, W) float, optional
        The decoder's modulation ``B`` of each axis, grey levels; the least-squares weights are
        ``B^2`` (the inverse variance of the coordinate, module docstring). Both or neither.

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
    if (modulation_u is None) != (modulation_v is None):
        raise ValueError("modulation_u and modulation_v must be given together")
    BU = BV = None
    if modulation_u is not None and modulation_v is not None:
        BU, BV = np.asarray(modulation_u), np.asarray(modulation_v)
        if BU.shape != U.shape or BV.shape != U.shape:
            raise ValueError(f"modulation maps must have the shape of u and v {U.shape}, got {BU.shape} and {BV.shape}")
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
        weights: tuple[FloatArray, FloatArray] | None = None
        if BU is not None and BV is not None:
            bu = np.asarray(BU[y0:y1, x0:x1], dtype=np.float64)
            bv = np.asarray(BV[y0:y1, x0:x1], dtype=np.float64)
            ok &= np.isfinite(bu) & np.isfinite(bv) & (bu > 0) & (bv > 0)
            weights = (bu[ok] ** 2, bv[ok] ** 2)
        n = int(ok.sum())
        decoded = n / total
        if n < MIN_WINDOW_POINTS:
            out.append(ProjectedCorner(nan2.copy(), decoded, 0.0, float("nan")))
            continue
        yy, xx = np.nonzero(ok)
        # centred on the corner and scaled by the half-window: well conditioned, and H p = (h13, h23)
        src = np.stack([xx + x0 - px, yy + y0 - py], axis=1) / w
        dst = np.stack([uu[ok], vv[ok]], axis=1)
        H, mask = cv2.findHomography(src, dst, cv2.RANSAC, ransac_threshold, maxIters=2000, confidence=0.999)
        if H is None or mask is None:
            out.append(ProjectedCorner(nan2.copy(), decoded, 0.0, float("nan")))
            continue
        inl = mask.ravel().astype(bool)
        if int(inl.sum()) < MIN_WINDOW_POINTS:
            out.append(ProjectedCorner(nan2.copy(), decoded, float(inl.mean()), float("nan")))
            continue
        a, b = (weights[0][inl], weights[1][inl]) if weights is not None else (None, None)
        if a is not None and b is not None:
            a, b = a / a.mean(), b / b.mean()
        H = refine_homography(H, src[inl], dst[inl], a, b)
        if not np.all(np.isfinite(H)):
            out.append(ProjectedCorner(nan2.copy(), decoded, float(inl.mean()), float("nan")))
            continue
        mapped = cv2.perspectiveTransform(src[inl].reshape(-1, 1, 2), H).reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((mapped - dst[inl]) ** 2, axis=1))))
        out.append(ProjectedCorner(H[:2, 2].copy(), decoded, float(inl.mean()), rms))
    return out
