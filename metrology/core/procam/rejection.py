"""Poses and corners a calibration leaves out because they disagree with the others.

- :func:`mirrored_poses`: a pose whose grid turns the other way from the majority (before any fit);
- :func:`flipped_poses`: a pose whose projector corners run the other way round from its camera
  corners (after the devices' own fits);
- :func:`outlier_corners` and :func:`reject_outlier_corners`: corners whose residual in their
  device's fit is far above the noise, and the poses with too many of them.

The first three find (they return what they found, by pose name); the selection's
:meth:`~metrology.core.procam.poses.PoseSelection.leave_out` and :func:`reject_outlier_corners`
return the new selection. Both flip checks give the cause ``corner_order_flipped``, the outlier
check ``outlier_corners``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.procam.diagnostics import rotation_angle_deg
from metrology.core.procam.fit import DeviceFit, DeviceFits, project_board
from metrology.core.procam.poses import MIN_POSE_CORNERS, BoolArray, PoseSelection

FloatArray = npt.NDArray[np.float64]

FLIP_ANGLE_DEG = 10.0
"""A pose is flipped when its camera-to-projector rotation is this far from the other poses'."""
MAX_OUTLIER_FRACTION = 0.2
"""A pose with more outlier corners than this fraction is left out (the board moved, or the
detection went wrong); fewer are left out one by one."""
OUTLIER_FACTOR = 5.0
OUTLIER_FLOOR_PX = 0.5
"""A corner is left out when its residual in its device's fit exceeds this factor times the
device's median residual and this many pixels (see :func:`outlier_corners`)."""


def _signed_area(pts: FloatArray, cols: int) -> float:
    """Shoelace area of the quadrilateral of the grid's four outer points, in their grid order."""
    rows = pts.shape[0] // cols
    q = pts[[0, cols - 1, rows * cols - 1, (rows - 1) * cols]]
    x, y = q[:, 0], q[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def mirrored_poses(selection: PoseSelection, board_cols: int) -> dict[str, str]:
    """Corner handedness: the used poses whose camera grid, or whose projector grid relative to its
    camera grid, turns the other way from the majority's, with their reasons (empty when fewer
    than two poses can be compared, or when the mirrored ones are not a minority). A pose mirrored
    in both gets the projector's reason."""
    usable = selection.used
    if len(usable) < 2:
        return {}
    cam_sign: dict[str, float] = {}
    rel_sign: dict[str, float] = {}
    for p in usable:
        assert p.camera_px is not None and p.projector_px is not None
        proj = p.projector_px
        if not np.isfinite(proj[[0, board_cols - 1, -1, -board_cols]]).all():
            continue
        a_c = _signed_area(p.camera_px, board_cols)
        a_p = _signed_area(proj, board_cols)
        cam_sign[p.name] = float(np.sign(a_c))
        rel_sign[p.name] = float(np.sign(a_c * a_p))
    reasons: dict[str, str] = {}
    for signs, what in ((cam_sign, "camera"), (rel_sign, "projector")):
        if len(signs) < 2:
            continue
        majority = np.sign(sum(signs.values())) or 1.0
        flipped = [name for name, s in signs.items() if s != majority]
        if flipped and len(flipped) < len(signs) / 2:
            reason = f"corner order mirrored in the {what} (its grid turns the other way from the other poses)"
            reasons.update(dict.fromkeys(flipped, reason))
    return reasons


def flipped_poses(selection: PoseSelection, fits: DeviceFits) -> dict[str, str]:
    """The used poses whose projector corners run the other way round from their camera corners,
    with their reasons.

    Each pose's relative rotation ``R_p,i R_c,i^T`` (its board's rotation in the projector's own
    fit times the inverse of the camera's) is the devices' relative rotation, the same for every
    pose; the reference is the pose whose median angle to the others is least, and a pose more
    than :data:`FLIP_ANGLE_DEG` from it is flipped, provided the flipped ones are a minority.
    Empty for fewer than three poses. ``fits`` are of ``selection``'s used poses, in order.
    """
    used = selection.used
    if len(used) < 3:
        return {}
    rel = []
    for k in range(len(used)):
        Rc = cv2.Rodrigues(fits.camera.rvecs[k])[0]
        Rp = cv2.Rodrigues(fits.projector.rvecs[k])[0]
        rel.append(Rp @ Rc.T)
    dists = np.array([[rotation_angle_deg(a, b) for b in rel] for a in rel])
    ref = int(np.argmin(np.median(dists, axis=1)))
    bad = [k for k in range(len(used)) if dists[ref, k] > FLIP_ANGLE_DEG]
    if not bad or len(bad) >= len(used) / 2:
        return {}
    return {
        used[k].name: (
            f"corner order flipped between camera and projector (its camera-to-projector rotation is "
            f"{dists[ref, k]:.0f} degrees from the other poses')"
        )
        for k in bad
    }


def _corner_residuals(selection: PoseSelection, fit: DeviceFit, key: str) -> dict[str, FloatArray]:
    """Each used pose's used corners' residual ``|observed - projected|`` in one device's fit,
    ``(N,)`` float64 (pixels or projector units; NaN at corners not used). ``key``: the points,
    ``"camera_px"`` or ``"projector_px"``."""
    K, dist = np.asarray(fit.intrinsics.K, np.float64), np.asarray(fit.intrinsics.dist, np.float64)
    out: dict[str, FloatArray] = {}
    for k, p in enumerate(selection.used):
        mask = selection.masks[p.name]
        observed = np.asarray(getattr(p, key), np.float64)
        assert p.object_mm is not None
        r = np.full(mask.size, np.nan)
        projected = project_board(
            p.object_mm[mask],
            np.ravel(fit.rvecs[k]).astype(np.float64),
            np.ravel(fit.tvecs[k]).astype(np.float64),
            K,
            dist,
        )
        r[mask] = np.linalg.norm(observed[mask] - projected, axis=1)
        out[p.name] = r
    return out


def outlier_corners(selection: PoseSelection, fits: DeviceFits) -> dict[str, BoolArray]:
    """Corners whose residual in their device's own fit is an outlier, per pose ``(N,)`` bool.

    A used corner's residual ``|observed - projected|`` (pixels, camera or projector, through that
    device's fit of its pose) is an outlier above ``max(OUTLIER_FACTOR * m, OUTLIER_FLOOR_PX)`` with
    ``m`` the median residual of the device's used corners. For Gaussian noise (per-axis sigma)
    the residual's median is ``1.18 sigma``, so the factor 5 sits at 5.9 sigma, where a clean
    corner lands with probability 3e-8. A corner is an outlier when it is one in either device.
    Returns only poses with at least one outlier. ``fits`` are of ``selection``'s used poses.
    """
    used = selection.used
    out: dict[str, BoolArray] = {}
    for fit, key in ((fits.camera, "camera_px"), (fits.projector, "projector_px")):
        residuals = _corner_residuals(selection, fit, key)
        values = np.concatenate([residuals[p.name] for p in used])
        typical = float(np.nanmedian(values)) if np.isfinite(values).any() else math.nan
        limit = max(OUTLIER_FACTOR * typical, OUTLIER_FLOOR_PX)
        for p in used:
            with np.errstate(invalid="ignore"):
                flagged = np.asarray(np.nan_to_num(residuals[p.name], nan=0.0) > limit, dtype=bool)
            if flagged.any():
                out[p.name] = out.get(p.name, np.zeros(flagged.size, bool)) | flagged
    return out


def outlier_reason(counts: str) -> str:
    """Why a pose with too many outlier corners is left out; ``counts``: how many, e.g. ``"15 of 54"``."""
    return (
        f"{counts} corners disagree with the calibration by more than {OUTLIER_FACTOR:g} times the typical "
        f"residual (and {OUTLIER_FLOOR_PX:g} px): part of the board shadowed, cut by the image's border or moved "
        "during the sequence"
    )


def reject_outlier_corners(selection: PoseSelection, flagged: Mapping[str, BoolArray]) -> PoseSelection:
    """A selection without the outlier corners ``flagged`` (of :func:`outlier_corners`).

    Each flagged pose's mask loses them and the pose records them (``outliers``); a pose with
    more than :data:`MAX_OUTLIER_FRACTION` of its corners flagged, or fewer than
    :data:`~metrology.core.procam.poses.MIN_POSE_CORNERS` left, is left out (``outlier_corners``).
    """
    masks = dict(selection.masks)
    marked: dict[str, BoolArray] = {}
    reasons: dict[str, str] = {}
    for p in selection.used:
        flags = flagged.get(p.name)
        if flags is None:
            continue
        masks[p.name] = masks[p.name] & ~flags
        marked[p.name] = flags
        n = int(flags.size)
        if flags.sum() > MAX_OUTLIER_FRACTION * n or masks[p.name].sum() < MIN_POSE_CORNERS:
            reasons[p.name] = outlier_reason(f"{int(flags.sum())} of {n}")
    poses = tuple(replace(p, outliers=marked[p.name]) if p.name in marked else p for p in selection.poses)
    return PoseSelection(poses=poses, masks=masks).leave_out(reasons, "outlier_corners")
