"""Projector-camera calibration from board poses: both devices as OpenCV pinholes, the stereo
pose, and a report that explains the result (docs/procam-calibration.md).

Per pose ``i`` the board's points ``X_k`` (mm, board frame ``Z = 0``) are seen at camera pixels
``c_ik`` and, through the local homographies of :mod:`metrology.core.procam.corners`, at
projector points ``p_ik``. Then

1. camera: ``cv2.calibrateCameraExtended(X, c)`` -> ``K_c``, ``dist_c`` (5 coefficients),
   per-pose board poses and the intrinsics' standard deviations;
2. projector: the same with ``p`` -> ``K_p``, ``dist_p``;
3. stereo: ``cv2.stereoCalibrateExtended`` -> ``R``, ``T`` with ``X_p = R X_c + T`` (the pinhole
   rig file's convention), per-pose board poses and errors. By default (``joint=True``) it starts
   from 1. and 2. and refines both devices' intrinsics and distortion together with the pose
   (``CALIB_USE_INTRINSIC_GUESS``): one bundle adjustment in which each board pose is seen by both
   devices through one rigid transform, so the projector's intrinsics are constrained by the
   camera's view of every pose too. On the kamino410 five-pose set this predicts a left-out pose's
   projector corners to 0.32 px RMS against 0.78 px with the intrinsics of 1. and 2. held fixed
   (docs/procam-calibration.md). ``joint=False`` holds them fixed (OpenCV's default flag
   ``CALIB_FIX_INTRINSIC``).

The intrinsics' standard deviations are those of the final fit: from ``calibrateCameraExtended``
when the intrinsics are held fixed, otherwise from the joint fit's covariance
``s^2 (J^T J)^-1`` with ``s^2 = sum r^2 / (m - n)`` over its ``m`` residual components and ``n``
parameters (the estimate ``calibrateCameraExtended`` uses), ``J`` by central differences.

Every residual is ``observed - projected`` (pixels or projector units) through the stereo
solution: the camera sees board pose ``(R_i, t_i)``, the projector ``(R R_i, R t_i + T)``.
The RMS values are those OpenCV returns: ``sqrt(sum |r|^2 / n_points)`` per device and over
both devices for the stereo fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.geometry.pinhole import PROJECTOR_GAMMA_RANGE, PinholeCamera, PinholeProjector, PinholeRig
from metrology.core.procam.board import BoardSpec

FloatArray = npt.NDArray[np.float64]

MIN_DECODED_FRACTION = 0.25
"""A corner is usable when at least this fraction of its window is decoded (both axes)."""
MIN_USABLE_CORNERS = 0.9
"""A pose is used when at least this fraction of its corners is usable."""
MIN_POSES = 2
RECOMMENDED_POSES = 5
MAX_OUTLIER_FRACTION = 0.2
"""A pose with more outlier corners than this fraction is left out (the board moved, or the
detection went wrong); fewer are left out one by one."""
OUTLIER_FACTOR = 5.0
OUTLIER_FLOOR_PX = 0.5
"""A corner is left out when its residual in its device's fit exceeds this factor times the
device's median residual and this many pixels (see :func:`_outlier_corners`)."""
INCONSISTENT_POSE_RATIO = 3.0
INCONSISTENT_POSE_PX = 1.0
"""A pose is flagged when, left out, its projector corners are predicted worse than this ratio
times the other poses' median and than this many pixels (RMS)."""
SIMILAR_ANGLE_DEG = 3.0
SIMILAR_SHIFT = 0.05
MIN_TILT_RANGE_DEG = 15.0
FLIP_ANGLE_DEG = 10.0
COVERAGE_CELLS = 8
MIN_COVERAGE = 0.3
MAX_EDGE_GAP = 0.2
"""The corners of all poses should come within this fraction of an image's width of its left and
right edges and of its height of its top and bottom edges; beyond, the distortion is extrapolated.
On the virtual rig of tests/core/procam/test_virtual_calibration.py (8 poses, corner noise
0.005 px in the camera and 0.0085 in the projector, 40 draws), poses leaving 20 %, 18 %, 28 % and
5 % of the projector image free at its left, right, top and bottom edges miss the distortion's
displacements over the whole image by 0.19 px (median; 0.34 px one time in ten); poses reaching
within 6 %, 6 %, 15 % and 10 % by 0.046 px (0.069 px)."""
EDGES = ("left", "right", "top", "bottom")
MISMATCH_FRACTION = 0.02
GAMMA_TOLERANCE = 0.15
PLAUSIBLE_DISTANCE_MM = (100.0, 20000.0)
HIGH_RMS_PX = 1.0


class ProcamCalibrationError(ValueError):
    """The poses cannot give a calibration (the message says why, pose by pose)."""


@dataclass
class PoseObservation:
    """One board pose as seen by the camera and mapped into the projector.

    Attributes
    ----------
    name : str
    camera_px : (N, 2) float64 or None
        Board points in the camera, pixels; None when the board was not found.
    projector_px : (N, 2) float64 or None
        The same points in the projector, projector units; NaN rows where a corner has no fit.
    object_mm : (N, 3) float64 or None
        Board points, mm (default: the board spec's points).
    decoded_fraction : (N,) float64 or None
        Decoded fraction of each corner's window (None: given correspondences, all usable).
    fit_rms : (N,) float64 or None
        RMS of each local homography's inliers, projector units.
    reason : str or None
        Why the pose cannot be used, set before calibration (board not found, ...).
    mismatch_fraction : float or None
        Fraction of the board's decodable pixels refused as outside the projector or
        gray/phase inconsistent (a projector size or fringe period that does not match).
    gamma : float or None
        Response exponent estimated from the sine fringes' mean against white and black.
    outliers : (N,) bool or None
        Set by the calibration: corners left out because they disagreed with their device's fit.
    """

    name: str
    camera_px: FloatArray | None
    projector_px: FloatArray | None
    object_mm: FloatArray | None = None
    decoded_fraction: FloatArray | None = None
    fit_rms: FloatArray | None = None
    reason: str | None = None
    mismatch_fraction: float | None = None
    gamma: float | None = None
    cause: str | None = None
    outliers: npt.NDArray[np.bool_] | None = None


@dataclass
class ProcamCalibration:
    """The calibrated rig and the report (a JSON-ready dict, docs/procam-calibration.md)."""

    rig: PinholeRig
    report: dict[str, Any] = field(default_factory=dict)


def _warn(
    warnings: list[dict[str, Any]], cause: str, message: str, action: str, poses: list[str] | None = None
) -> None:
    entry: dict[str, Any] = {"cause": cause, "message": message, "action": action}
    if poses:
        entry["poses"] = poses
    warnings.append(entry)


def _signed_area(pts: FloatArray, cols: int) -> float:
    """Shoelace area of the quadrilateral of the grid's four outer points, in their grid order."""
    rows = pts.shape[0] // cols
    q = pts[[0, cols - 1, rows * cols - 1, (rows - 1) * cols]]
    x, y = q[:, 0], q[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


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


_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
"""Termination of every OpenCV fit here: 200 iterations or a step below 1e-12 (run to convergence)."""


def _device_flags(fix_k3: bool) -> int:
    """``calibrateCamera``'s flags: k3 held at 0 or not."""
    return cv2.CALIB_FIX_K3 if fix_k3 else 0


def _stereo_flags(joint: bool, fix_k3: bool) -> int:
    """``stereoCalibrate``'s flags: refine both devices' intrinsics from the given start (``joint``),
    or hold them fixed."""
    return (cv2.CALIB_USE_INTRINSIC_GUESS | _device_flags(fix_k3)) if joint else cv2.CALIB_FIX_INTRINSIC


def _coverage(points: list[FloatArray], width: float, height: float) -> float:
    """Fraction of an ``8 x 8`` grid of the image's cells holding at least one point."""
    cells = np.zeros((COVERAGE_CELLS, COVERAGE_CELLS), bool)
    for p in points:
        i = np.floor((p[:, 1] + 0.5) / height * COVERAGE_CELLS).astype(int)
        j = np.floor((p[:, 0] + 0.5) / width * COVERAGE_CELLS).astype(int)
        keep = (i >= 0) & (i < COVERAGE_CELLS) & (j >= 0) & (j < COVERAGE_CELLS)
        cells[i[keep], j[keep]] = True
    return float(cells.mean())


def _edge_gaps(points: list[FloatArray], width: float, height: float) -> dict[str, float]:
    """Distance from each edge of the image to the nearest point, as a fraction of the image's width
    (left, right) or height (top, bottom); the image spans ``-0.5 .. W - 0.5`` (pixel centres at
    integers). 1.0 for every edge when there are no points."""
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


def _std_dict(std: FloatArray, n_dist: int) -> dict[str, Any]:
    s = np.asarray(std, dtype=np.float64).ravel()
    return {
        "fx": float(s[0]),
        "fy": float(s[1]),
        "cx": float(s[2]),
        "cy": float(s[3]),
        "dist": [float(x) for x in s[4 : 4 + n_dist]],
    }


def _calibrate_device(
    obj: list[FloatArray], img: list[FloatArray], size: tuple[int, int], flags: int = 0
) -> tuple[float, FloatArray, FloatArray, list[FloatArray], list[FloatArray], FloatArray, FloatArray]:
    o = [x.astype(np.float32).reshape(-1, 1, 3) for x in obj]
    i = [x.astype(np.float32).reshape(-1, 1, 2) for x in img]
    rms, K, dist, rvecs, tvecs, std_int, _std_ext, per_view = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
        o, i, size, None, None, flags=flags, criteria=_CRITERIA
    )
    return float(rms), K, dist.ravel()[:5], list(rvecs), list(tvecs), std_int.ravel(), per_view.ravel()


def _joint_std(
    obj: list[FloatArray],
    cam: list[FloatArray],
    prj: list[FloatArray],
    Kc: FloatArray,
    dc: FloatArray,
    Kp: FloatArray,
    dp: FloatArray,
    R: FloatArray,
    T: FloatArray,
    rvecs: list[FloatArray],
    tvecs: list[FloatArray],
    fix_k3: bool,
) -> tuple[FloatArray, FloatArray]:
    """Standard deviations of both devices' intrinsics after the joint stereo fit.

    Parameters ``theta`` = camera ``(fx, fy, cx, cy, k1, k2, p1, p2[, k3])``, the projector's
    likewise, the stereo ``rvec(R)``, ``T`` and each pose's camera-frame ``rvec_i``, ``t_i``; the
    residuals are every used corner's camera and projector reprojection errors (pixels; the
    projector sees pose ``(R R_i, R t_i + T)``). ``cov = s^2 (J^T J)^-1``, ``s^2 = sum r^2 / (m - n)``,
    ``J`` by central differences (steps ``1e-6 max(1, |theta|)``). Returns two arrays in
    ``calibrateCameraExtended``'s order ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` (k3's entry 0
    when it is held at 0); NaN when ``J^T J`` is singular.
    """
    n_int = 8 if fix_k3 else 9

    def pack_int(K: FloatArray, d: FloatArray) -> list[float]:
        return [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *list(np.asarray(d, np.float64).ravel()[:5])][:n_int]

    def unpack_int(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        K = np.array([[v[0], 0.0, v[2]], [0.0, v[1], v[3]], [0.0, 0.0, 1.0]])
        d = np.zeros(5)
        d[: n_int - 4] = v[4:n_int]
        return K, d

    theta0 = np.array(
        [
            *pack_int(Kc, dc),
            *pack_int(Kp, dp),
            *np.asarray(cv2.Rodrigues(R)[0], np.float64).ravel(),
            *np.asarray(T, np.float64).ravel(),
            *[x for k in range(len(obj)) for x in (*np.ravel(rvecs[k]), *np.ravel(tvecs[k]))],
        ],
        dtype=np.float64,
    )
    observed = np.concatenate([np.concatenate([c.reshape(-1), q.reshape(-1)]) for c, q in zip(cam, prj, strict=True)])

    def residuals(theta: FloatArray) -> FloatArray:
        Kc_, dc_ = unpack_int(theta[:n_int])
        Kp_, dp_ = unpack_int(theta[n_int : 2 * n_int])
        Rs = np.asarray(cv2.Rodrigues(theta[2 * n_int : 2 * n_int + 3])[0], np.float64)
        Ts = theta[2 * n_int + 3 : 2 * n_int + 6]
        out = []
        for k, o in enumerate(obj):
            base = 2 * n_int + 6 + 6 * k
            rv, tv = theta[base : base + 3], theta[base + 3 : base + 6]
            Ri = np.asarray(cv2.Rodrigues(rv)[0], np.float64)
            out.append(_project(o, rv, tv, Kc_, dc_).reshape(-1))
            rp = np.asarray(cv2.Rodrigues(Rs @ Ri)[0], np.float64).ravel()
            out.append(_project(o, rp, Rs @ tv + Ts, Kp_, dp_).reshape(-1))
        return np.concatenate(out)

    r0 = residuals(theta0) - observed
    m, n = r0.size, theta0.size
    J = np.empty((m, n))
    for j in range(n):
        h = 1e-6 * max(1.0, abs(float(theta0[j])))
        up, down = theta0.copy(), theta0.copy()
        up[j] += h
        down[j] -= h
        J[:, j] = (residuals(up) - residuals(down)) / (2 * h)
    nan = np.full(9, np.nan)
    if m <= n:
        return nan, nan.copy()
    s2 = float(r0 @ r0) / (m - n)
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError:
        return nan, nan.copy()
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    cam_std, proj_std = np.zeros(9), np.zeros(9)
    cam_std[:n_int] = std[:n_int]
    proj_std[:n_int] = std[n_int : 2 * n_int]
    return cam_std, proj_std


def _leave_one_out(
    obj: list[npt.NDArray[np.float32]],
    cam: list[npt.NDArray[np.float32]],
    prj: list[npt.NDArray[np.float32]],
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    fix_k3: bool,
    joint: bool,
) -> list[float]:
    """Each pose's projector corners predicted by a calibration of the other poses, RMS pixels.

    For pose ``k``: calibrate both devices and the stereo pose on the others (as the full fit
    does), find pose ``k``'s board from its camera corners alone (``cv2.solvePnP`` with the
    camera's intrinsics), carry it into the projector (``R R_k``, ``R t_k + T``), project, and
    return ``sqrt(mean |p_observed - p_predicted|^2)``. Needs at least three poses; NaN where a
    fit fails. It measures what a calibration is for, predicting poses it has not seen, which
    the reprojection RMS of the poses it was fitted to does not.
    """
    flags, stereo_flags = _device_flags(fix_k3), _stereo_flags(joint, fix_k3)
    out: list[float] = []
    for k in range(len(obj)):
        o = [obj[i] for i in range(len(obj)) if i != k]
        c = [cam[i] for i in range(len(obj)) if i != k]
        q = [prj[i] for i in range(len(obj)) if i != k]
        try:
            _, Kc0, dc0, _, _ = cv2.calibrateCamera(o, c, camera_size, None, None, flags=flags, criteria=_CRITERIA)
            _, Kp0, dp0, _, _ = cv2.calibrateCamera(o, q, projector_size, None, None, flags=flags, criteria=_CRITERIA)
            st = cv2.stereoCalibrate(o, c, q, Kc0, dc0, Kp0, dp0, camera_size, flags=stereo_flags, criteria=_CRITERIA)
            Kc, dc = np.asarray(st[1], np.float64), np.asarray(st[2], np.float64).ravel()
            Kp, dp = np.asarray(st[3], np.float64), np.asarray(st[4], np.float64).ravel()
            R, T = np.asarray(st[5], np.float64), np.asarray(st[6], np.float64)
            ok, rvec, tvec = cv2.solvePnP(obj[k], cam[k], Kc, dc)
        except cv2.error:
            out.append(math.nan)
            continue
        if not ok:
            out.append(math.nan)
            continue
        Rb = np.asarray(cv2.Rodrigues(rvec)[0], np.float64)
        rp = np.asarray(cv2.Rodrigues(R @ Rb)[0], np.float64).ravel()
        predicted = _project(obj[k].reshape(-1, 3).astype(np.float64), rp, (R @ tvec).ravel() + T.ravel(), Kp, dp)
        err = predicted - prj[k].reshape(-1, 2)
        out.append(float(np.sqrt(np.mean(np.sum(err**2, axis=1)))))
    return out


def _outlier_corners(
    act: list[PoseObservation],
    used_mask: dict[str, npt.NDArray[np.bool_]],
    cam_cal: tuple[Any, ...],
    proj_cal: tuple[Any, ...],
) -> dict[str, npt.NDArray[np.bool_]]:
    """Corners whose residual in their device's own fit is an outlier, per pose ``(N,)`` bool.

    A used corner's residual ``|observed - projected|`` (pixels, camera or projector, through that
    device's fit of its pose) is an outlier above ``max(OUTLIER_FACTOR * m, OUTLIER_FLOOR_PX)`` with
    ``m`` the median residual of the device's used corners. For Gaussian noise (per-axis sigma)
    the residual's median is ``1.18 sigma``, so the factor 5 sits at 5.9 sigma, where a clean
    corner lands with probability 3e-8. Returns only poses with at least one outlier.
    """
    residuals: dict[str, list[FloatArray]] = {}
    for cal, key in ((cam_cal, "camera_px"), (proj_cal, "projector_px")):
        K, dist = np.asarray(cal[1], np.float64), np.asarray(cal[2], np.float64)
        for k, p in enumerate(act):
            mask = used_mask[p.name]
            observed = np.asarray(getattr(p, key), np.float64)
            assert p.object_mm is not None
            r = np.full(mask.size, np.nan)
            projected = _project(
                p.object_mm[mask],
                np.ravel(cal[3][k]).astype(np.float64),
                np.ravel(cal[4][k]).astype(np.float64),
                K,
                dist,
            )
            r[mask] = np.linalg.norm(observed[mask] - projected, axis=1)
            residuals.setdefault(p.name, []).append(r)
    out: dict[str, npt.NDArray[np.bool_]] = {}
    for index in (0, 1):
        values = np.concatenate([residuals[p.name][index] for p in act])
        typical = float(np.nanmedian(values)) if np.isfinite(values).any() else math.nan
        limit = max(OUTLIER_FACTOR * typical, OUTLIER_FLOOR_PX)
        for p in act:
            r = residuals[p.name][index]
            with np.errstate(invalid="ignore"):
                flagged = np.asarray(np.nan_to_num(r, nan=0.0) > limit, dtype=bool)
            if flagged.any():
                out[p.name] = out.get(p.name, np.zeros(flagged.size, bool)) | flagged
    return out


def _project(obj: FloatArray, rvec: FloatArray, tvec: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    pts, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, dist)
    return np.asarray(pts, dtype=np.float64).reshape(-1, 2)


def _pose_checks(poses: list[PoseObservation], board_cols: int, warnings: list[dict[str, Any]]) -> None:
    """Corner handedness: a pose whose camera grid, or whose projector grid relative to its
    camera grid, turns the other way from the majority has its corner order mirrored."""
    usable = [p for p in poses if p.reason is None and p.camera_px is not None and p.projector_px is not None]
    if len(usable) < 2:
        return
    cam_sign = {}
    rel_sign = {}
    for p in usable:
        assert p.camera_px is not None and p.projector_px is not None
        proj = p.projector_px
        if not np.isfinite(proj[[0, board_cols - 1, -1, -board_cols]]).all():
            continue
        a_c = _signed_area(p.camera_px, board_cols)
        a_p = _signed_area(proj, board_cols)
        cam_sign[p.name] = np.sign(a_c)
        rel_sign[p.name] = np.sign(a_c * a_p)
    for signs, what in ((cam_sign, "camera"), (rel_sign, "projector")):
        if len(signs) < 2:
            continue
        majority = np.sign(sum(signs.values())) or 1.0
        flipped = [name for name, s in signs.items() if s != majority]
        if flipped and len(flipped) < len(signs) / 2:
            for p in usable:
                if p.name in flipped:
                    p.reason = (
                        f"corner order mirrored in the {what} (its grid turns the other way from the other poses)"
                    )
                    p.cause = "corner_order_flipped"


def calibrate_procam(
    poses: list[PoseObservation],
    board: BoardSpec,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    *,
    min_decoded_fraction: float = MIN_DECODED_FRACTION,
    codec_gamma_precompensated: bool = False,
    fix_k3: bool = False,
    joint: bool = True,
) -> ProcamCalibration:
    """Calibrate camera, projector and their pose from board poses; explain the result.

    Parameters
    ----------
    poses : list of PoseObservation
        Poses whose ``reason`` is set are reported and left out; others are checked (decoded
        fraction around each corner, corner order) and used.
    board : BoardSpec
    camera_size : (width, height) pixels
    projector_size : (width, height) projector units
    min_decoded_fraction : float
        A corner is used when this fraction of its window is decoded.
    codec_gamma_precompensated : bool
        The patterns were pre-compensated for the projector's gamma (the codec's
        ``precompensated_gamma``): no gamma warning, and the rig's ``projector.gamma`` is not set.
        Otherwise a gamma estimated from the fringes (0.2..5) is written as ``projector.gamma``.
    fix_k3 : bool
        Hold the radial coefficient k3 at 0 for both devices (few poses, or mild distortion).
    joint : bool
        Refine both devices' intrinsics together with the stereo pose (default); False holds the
        per-device intrinsics fixed in the stereo fit.

    Returns
    -------
    ProcamCalibration
        ``rig`` (the pinhole rig, mm) and ``report`` (see docs/procam-calibration.md).

    Raises
    ------
    ProcamCalibrationError
        Fewer than two usable poses (the message lists every pose's reason).
    """
    if not poses:
        raise ProcamCalibrationError("no poses given")
    names = [p.name for p in poses]
    if len(set(names)) != len(names):
        raise ProcamCalibrationError(f"pose names must be unique, got {names}")
    warnings: list[dict[str, Any]] = []
    default_obj = board.object_points()
    used_mask: dict[str, npt.NDArray[np.bool_]] = {}
    for p in poses:
        if p.object_mm is None:
            p.object_mm = default_obj
        if p.reason is not None:
            continue
        if p.camera_px is None:
            p.reason, p.cause = "board not found in the board image", "board_not_found"
            continue
        if p.projector_px is None:
            p.reason, p.cause = "no projector points", "poorly_decoded"
            continue
        n = p.camera_px.shape[0]
        ok = np.isfinite(p.projector_px).all(axis=1) & np.isfinite(p.camera_px).all(axis=1)
        if p.decoded_fraction is not None:
            ok = np.asarray(ok & (p.decoded_fraction >= min_decoded_fraction), dtype=bool)
        if ok.sum() < max(MIN_USABLE_CORNERS * n, 6):
            p.reason = (
                f"only {int(ok.sum())} of {n} corners have >= {min_decoded_fraction:.0%} of their window decoded "
                "(part of the board shadowed, outside the projector's light, or too dark)"
            )
            p.cause = "poorly_decoded"
            continue
        used_mask[p.name] = np.asarray(ok, dtype=bool)
    _pose_checks(poses, board.cols, warnings)

    def active() -> list[PoseObservation]:
        return [p for p in poses if p.reason is None]

    cam_w, cam_h = int(camera_size[0]), int(camera_size[1])
    proj_w, proj_h = round(projector_size[0]), round(projector_size[1])

    def run_devices() -> tuple[Any, Any]:
        act = active()
        if len(act) < MIN_POSES:
            lines = "; ".join(f"{p.name}: {p.reason or 'usable'}" for p in poses)
            raise ProcamCalibrationError(f"need at least {MIN_POSES} usable poses, have {len(act)} ({lines})")
        obj = [p.object_mm[used_mask[p.name]] for p in act]  # type: ignore[index]
        cam = [p.camera_px[used_mask[p.name]] for p in act]  # type: ignore[index]
        prj = [p.projector_px[used_mask[p.name]] for p in act]  # type: ignore[index]
        flags = _device_flags(fix_k3)
        c = _calibrate_device(obj, cam, (cam_w, cam_h), flags)
        q = _calibrate_device(obj, prj, (proj_w, proj_h), flags)
        return c, q

    cam_cal, proj_cal = run_devices()
    # a pose whose projector corners run the other way round from its camera corners: its relative
    # rotation (projector board pose times the inverse camera board pose) differs from the others'
    act = active()
    if len(act) >= 3:
        rel = []
        for k in range(len(act)):
            Rc = cv2.Rodrigues(cam_cal[3][k])[0]
            Rp = cv2.Rodrigues(proj_cal[3][k])[0]
            rel.append(Rp @ Rc.T)
        dists = np.array([[rotation_angle_deg(a, b) for b in rel] for a in rel])
        ref = int(np.argmin(np.median(dists, axis=1)))
        bad = [act[k] for k in range(len(act)) if dists[ref, k] > FLIP_ANGLE_DEG]
        if bad and len(bad) < len(act) / 2:
            for p in bad:
                k = act.index(p)
                p.reason = (
                    f"corner order flipped between camera and projector (its camera-to-projector rotation is "
                    f"{dists[ref, k]:.0f} degrees from the other poses')"
                )
                p.cause = "corner_order_flipped"
            cam_cal, proj_cal = run_devices()
    # corners that disagree with their device's fit by far more than the noise (a corner located on
    # a shadowed or cut-off part of the board, a glint): left out, and the devices fitted again
    outliers = _outlier_corners(active(), used_mask, cam_cal, proj_cal)
    if outliers:
        for p in active():
            flagged = outliers.get(p.name)
            if flagged is None:
                continue
            used_mask[p.name] = used_mask[p.name] & ~flagged
            p.outliers = flagged
            n = int(flagged.size)
            if flagged.sum() > MAX_OUTLIER_FRACTION * n or used_mask[p.name].sum() < 6:
                p.reason = (
                    f"{int(flagged.sum())} of {n} corners disagree with the calibration by more than "
                    f"{OUTLIER_FACTOR:g} times the typical residual (and {OUTLIER_FLOOR_PX:g} px): part of the board "
                    "shadowed, cut by the image's border or moved during the sequence"
                )
                p.cause = "outlier_corners"
        cam_cal, proj_cal = run_devices()
    act = active()
    obj = [p.object_mm[used_mask[p.name]].astype(np.float32).reshape(-1, 1, 3) for p in act]  # type: ignore[index]
    cam = [p.camera_px[used_mask[p.name]].astype(np.float32).reshape(-1, 1, 2) for p in act]  # type: ignore[index]
    prj = [p.projector_px[used_mask[p.name]].astype(np.float32).reshape(-1, 1, 2) for p in act]  # type: ignore[index]
    Kc, dc = cam_cal[1], cam_cal[2]
    Kp, dp = proj_cal[1], proj_cal[2]
    stereo = cv2.stereoCalibrateExtended(  # type: ignore[call-overload]
        obj,
        cam,
        prj,
        Kc.copy(),
        dc.copy(),
        Kp.copy(),
        dp.copy(),
        (cam_w, cam_h),
        None,
        None,
        flags=_stereo_flags(joint, fix_k3),
        criteria=_CRITERIA,
    )
    stereo_rms = float(stereo[0])
    if joint:
        Kc, dc = np.asarray(stereo[1], np.float64), np.asarray(stereo[2], np.float64).ravel()[:5]
        Kp, dp = np.asarray(stereo[3], np.float64), np.asarray(stereo[4], np.float64).ravel()[:5]
    R = np.asarray(stereo[5], dtype=np.float64)
    T = np.asarray(stereo[6], dtype=np.float64).ravel()
    s_rvecs, s_tvecs, s_err = stereo[9], stereo[10], np.asarray(stereo[11]).reshape(-1, 2)
    if joint:
        cam_std, proj_std = _joint_std(
            [o.reshape(-1, 3).astype(np.float64) for o in obj],
            [c.reshape(-1, 2).astype(np.float64) for c in cam],
            [q.reshape(-1, 2).astype(np.float64) for q in prj],
            Kc,
            dc,
            Kp,
            dp,
            R,
            T,
            list(s_rvecs),
            list(s_tvecs),
            fix_k3,
        )
    else:
        cam_std, proj_std = cam_cal[5], proj_cal[5]
    loo = _leave_one_out(obj, cam, prj, (cam_w, cam_h), (proj_w, proj_h), fix_k3, joint) if len(act) >= 3 else []
    loo_by_name = {p.name: value for p, value in zip(act, loo, strict=False)}

    rig = PinholeRig(
        camera=PinholeCamera(
            width_px=cam_w,
            height_px=cam_h,
            K=tuple(tuple(float(x) for x in row) for row in Kc),  # type: ignore[arg-type]
            dist=tuple(float(x) for x in dc),
        ),
        projector=PinholeProjector(
            width=proj_w,
            height=proj_h,
            K=tuple(tuple(float(x) for x in row) for row in Kp),  # type: ignore[arg-type]
            dist=tuple(float(x) for x in dp),
        ),
        R=tuple(tuple(float(x) for x in row) for row in R),  # type: ignore[arg-type]
        T=(float(T[0]), float(T[1]), float(T[2])),
    )

    # ----------------------------------------------------------------- per pose, per corner
    pose_reports: list[dict[str, Any]] = []
    board_R: dict[str, FloatArray] = {}
    board_t: dict[str, FloatArray] = {}
    for p in poses:
        entry: dict[str, Any] = {"name": p.name, "used": p.reason is None, "reason": p.reason, "cause": p.cause}
        corners: list[dict[str, Any]] = []
        if p.reason is None:
            k = act.index(p)
            rvec, tvec = np.asarray(s_rvecs[k]).ravel(), np.asarray(s_tvecs[k]).ravel()
            Ri = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
            board_R[p.name], board_t[p.name] = Ri, tvec
            Rpi = R @ Ri
            tpi = R @ tvec + T
            assert p.object_mm is not None
            pc = _project(p.object_mm, rvec, tvec, Kc, dc)
            pp = _project(p.object_mm, np.asarray(cv2.Rodrigues(Rpi)[0], dtype=np.float64).ravel(), tpi, Kp, dp)
            e_c, e_p = float(s_err[k, 0]), float(s_err[k, 1])
            normal = Ri[:, 2]
            entry.update(
                {
                    "rms_px": math.sqrt((e_c**2 + e_p**2) / 2),
                    "camera_rms_px": e_c,
                    "projector_rms_px": e_p,
                    "tilt_deg": math.degrees(math.acos(min(1.0, abs(float(normal[2]))))),
                    "leave_one_out_projector_rms_px": loo_by_name.get(p.name),
                    "distance_mm": float(np.linalg.norm(tvec)),
                }
            )
        else:
            pc = pp = None  # type: ignore[assignment]
            entry["rms_px"] = None
        if p.camera_px is not None:
            mask = used_mask.get(p.name)
            for j in range(p.camera_px.shape[0]):
                cpx = p.camera_px[j]
                ppx = p.projector_px[j] if p.projector_px is not None else None
                c: dict[str, Any] = {
                    "camera_px": [float(cpx[0]), float(cpx[1])],
                    "projector_px": [float(ppx[0]), float(ppx[1])]
                    if ppx is not None and np.isfinite(ppx).all()
                    else None,
                    "used": bool(p.reason is None and mask is not None and mask[j]),
                }
                if p.outliers is not None and p.outliers[j]:
                    c["outlier"] = True
                if p.decoded_fraction is not None:
                    c["decoded_fraction"] = float(p.decoded_fraction[j])
                if p.fit_rms is not None and np.isfinite(p.fit_rms[j]):
                    c["homography_rms"] = float(p.fit_rms[j])
                if pc is not None and pp is not None:
                    c["residual_camera_px"] = [float(cpx[0] - pc[j, 0]), float(cpx[1] - pc[j, 1])]
                    c["residual_projector_px"] = (
                        [float(ppx[0] - pp[j, 0]), float(ppx[1] - pp[j, 1])]
                        if ppx is not None and np.isfinite(ppx).all()
                        else None
                    )
                else:
                    c["residual_camera_px"] = None
                    c["residual_projector_px"] = None
                corners.append(c)
        if p.decoded_fraction is not None:
            entry["decoded_fraction_median"] = float(np.median(p.decoded_fraction))
        if p.mismatch_fraction is not None:
            entry["mismatch_fraction"] = p.mismatch_fraction
        if p.gamma is not None:
            entry["gamma_estimate"] = p.gamma
        entry["corners"] = corners
        pose_reports.append(entry)

    # ----------------------------------------------------------------- diagnostics and warnings
    for p in poses:
        if p.reason is None:
            continue
        if p.cause == "board_not_found":
            _warn(
                warnings,
                "board_not_found",
                f"pose {p.name}: the board was not found in its board image; the pose is left out.",
                "Check the board spec (COLSxROWS counts inner corners, points per row first), that the whole "
                "board is in the camera's view, sharp and evenly lit in the white frame.",
                [p.name],
            )
        elif p.cause == "poorly_decoded":
            _warn(
                warnings,
                "poorly_decoded",
                f"pose {p.name}: too little of the board decoded ({p.reason}); the pose is left out.",
                "Keep the whole board inside the projector's light, avoid shadows and glare, and raise the exposure "
                "or the projector brightness so the black squares are still decoded.",
                [p.name],
            )
        elif p.cause == "outlier_corners":
            _warn(
                warnings,
                "outlier_corners",
                f"pose {p.name}: {p.reason}; the pose is left out.",
                "Look at the pose's board image: keep the whole board, with a margin, inside the camera's view and "
                "the projector's light, without glare, and keep it still during the sequence.",
                [p.name],
            )
        elif p.cause == "corner_order_flipped":
            _warn(
                warnings,
                "corner_order_flipped",
                f"pose {p.name}: {p.reason}; the pose is left out.",
                "Give the board's points in the same order for the camera and the projector (row by row, points "
                "per row first); in a correspondence file check that no pose has its projector list reversed.",
                [p.name],
            )
    if len(act) < RECOMMENDED_POSES:
        _warn(
            warnings,
            "too_few_poses",
            f"only {len(act)} poses were used; the intrinsics, above all the projector's, are poorly constrained.",
            f"Capture at least {RECOMMENDED_POSES} (better 8 to 12) poses, tilting the board in different directions.",
        )
    normals = {name: Rb[:, 2] for name, Rb in board_R.items()}
    similar: list[list[str]] = []
    used_names = [p.name for p in act]
    max_pair = 0.0
    for a in range(len(used_names)):
        for b in range(a + 1, len(used_names)):
            na, nb = used_names[a], used_names[b]
            ang = rotation_angle_deg(board_R[na], board_R[nb])
            max_pair = max(max_pair, math.degrees(math.acos(float(np.clip(abs(normals[na] @ normals[nb]), -1, 1)))))
            shift = float(np.linalg.norm(board_t[na] - board_t[nb])) / max(float(np.linalg.norm(board_t[na])), 1e-9)
            if ang < SIMILAR_ANGLE_DEG and shift < SIMILAR_SHIFT:
                similar.append([na, nb])
    for pair in similar:
        _warn(
            warnings,
            "similar_poses",
            f"poses {pair[0]} and {pair[1]} are near-identical (board orientations within {SIMILAR_ANGLE_DEG} degrees "
            f"and positions within {SIMILAR_SHIFT:.0%}); the second adds almost nothing.",
            "Replace one of them by a pose tilted by 20 to 40 degrees in another direction.",
            pair,
        )
    tilts = [float(e["tilt_deg"]) for e in pose_reports if e["used"]]
    if len(act) >= 2 and max_pair < MIN_TILT_RANGE_DEG:
        _warn(
            warnings,
            "similar_poses",
            f"the board's orientations span only {max_pair:.1f} degrees; "
            "focal length and distance cannot be told apart.",
            "Tilt the board by 20 to 40 degrees about both its axes across the poses.",
        )
    finite_loo = {name: v for name, v in loo_by_name.items() if v is not None and math.isfinite(v)}
    for name, value in finite_loo.items():
        others = [v for n, v in finite_loo.items() if n != name]
        typical = float(np.median(others)) if others else math.nan
        if others and value > max(INCONSISTENT_POSE_RATIO * typical, INCONSISTENT_POSE_PX):
            _warn(
                warnings,
                "inconsistent_pose",
                f"pose {name} is not predicted by the other poses: calibrated without it, the rig puts its projector "
                f"corners {value:.2f} px (RMS) from where they were decoded, against {typical:.2f} px for the "
                "other poses left out in turn.",
                "Retake this pose or leave it out: the board or the rig may have moved during its sequence, or "
                "its corners are wrong (blur, reflections).",
                [name],
            )
    cam_points = [p.camera_px[used_mask[p.name]] for p in act]  # type: ignore[index]
    proj_points = [p.projector_px[used_mask[p.name]] for p in act]  # type: ignore[index]
    cam_cov = _coverage(cam_points, cam_w, cam_h)
    proj_cov = _coverage(proj_points, proj_w, proj_h)
    edge_gaps = {
        "camera": _edge_gaps(cam_points, cam_w, cam_h),
        "projector": _edge_gaps(proj_points, proj_w, proj_h),
    }
    for cov, what in ((cam_cov, "camera"), (proj_cov, "projector")):
        far = {edge: g for edge, g in edge_gaps[what].items() if g > MAX_EDGE_GAP}
        if cov >= MIN_COVERAGE and not far:
            continue
        reasons = []
        if cov < MIN_COVERAGE:
            reasons.append(f"cover only {cov:.0%} of it (cells of an 8x8 grid)")
        if far:
            sides = [
                f"{g:.0%} of its {'width' if edge in ('left', 'right') else 'height'} to its {edge} edge"
                for edge, g in far.items()
            ]
            listed = sides[0] if len(sides) == 1 else ", ".join(sides[:-1]) + " and " + sides[-1]
            reasons.append(f"come no nearer than {listed}")
        _warn(
            warnings,
            "coverage",
            f"in the {what} image the corners {' and '.join(reasons)}; the {what}'s distortion is extrapolated there.",
            f"Add poses that bring the board's corners within {MAX_EDGE_GAP:.0%} of every edge of the {what} image "
            "(as far as the camera sees and the projector lights), the board tilted by 20 to 40 degrees and turned "
            "15 to 30 degrees in its plane.",
        )
    distances = [float(np.linalg.norm(t)) for t in board_t.values()]
    median_distance = float(np.median(distances))
    baseline = float(np.linalg.norm(T))
    lo, hi = PLAUSIBLE_DISTANCE_MM
    if not lo <= median_distance <= hi:
        _warn(
            warnings,
            "board_unit",
            f"the board comes out {median_distance:.4g} mm from the camera and the baseline {baseline:.4g} mm: "
            "implausible for a bench rig, so the board's square size is probably in the wrong unit.",
            f"Give the square size in millimetres (now {board.size_mm:g}; a square of 2.5 cm is 25, of 1 inch 25.4).",
        )
    mismatched = [p.name for p in poses if p.mismatch_fraction is not None and p.mismatch_fraction > MISMATCH_FRACTION]
    pp = Kp[:2, 2]
    pp_outside = not (-0.25 * proj_w <= pp[0] <= 1.25 * proj_w and -0.75 * proj_h <= pp[1] <= 1.75 * proj_h)
    if mismatched or pp_outside:
        fractions = ", ".join(
            f"{p.name} {p.mismatch_fraction:.0%}" for p in poses if p.name in mismatched and p.mismatch_fraction
        )
        detail = (
            f"decoded pixels refused as outside the projector or gray/phase inconsistent: {fractions}; "
            if fractions
            else ""
        )
        _warn(
            warnings,
            "projector_mismatch",
            f"{detail}projector principal point ({pp[0]:.0f}, {pp[1]:.0f}) for a declared {proj_w}x{proj_h} projector. "
            "The codec's projector size or fringe period does not match the patterns that were projected.",
            "Write the projector's real resolution and the periods and words of the projected patterns in the codec "
            "(regenerate the patterns from the codec to be sure), and project them at the native resolution.",
            mismatched or None,
        )
    gammas = [p.gamma for p in act if p.gamma is not None and math.isfinite(p.gamma)]
    gamma_estimate = float(np.median(gammas)) if gammas else None
    if gamma_estimate is not None and abs(gamma_estimate - 1.0) > GAMMA_TOLERANCE and not codec_gamma_precompensated:
        _warn(
            warnings,
            "gamma",
            f"the projector-camera response is not linear (gamma about {gamma_estimate:.2f} from the fringes' mean "
            "against the white and black frames): sine fringes are distorted and phases carry a periodic error.",
            "Set the projector to a linear (gamma 1) mode, or pre-compensate the patterns for this gamma, or use "
            "gray codes with inverse images or more phase steps.",
        )
    lo_g, hi_g = PROJECTOR_GAMMA_RANGE
    if gamma_estimate is not None and not codec_gamma_precompensated and lo_g <= gamma_estimate <= hi_g:
        # the measured response goes into the rig file (projector.gamma) for pre-compensation later
        rig = replace(rig, projector=replace(rig.projector, gamma=round(gamma_estimate, 4)))
    cam_rms, proj_rms = float(cam_cal[0]), float(proj_cal[0])
    if proj_rms > HIGH_RMS_PX or cam_rms > HIGH_RMS_PX:
        causes = sorted({w["cause"] for w in warnings})
        _warn(
            warnings,
            "high_rms",
            f"reprojection error is high (camera {cam_rms:.2f} px, projector {proj_rms:.2f} px)"
            + (f"; see the other warnings ({', '.join(causes)})" if causes else ""),
            "Look at the per-pose RMS and leave out the worst poses; check the board size, the codec and focus.",
        )

    n_dist_c, n_dist_p = len(dc), len(dp)
    report: dict[str, Any] = {
        "format": "gcps-procam-report/1",
        "board": board.spec(),
        "camera_size": [cam_w, cam_h],
        "projector_size": [proj_w, proj_h],
        "camera_rms_px": cam_rms,
        "projector_rms_px": proj_rms,
        "stereo_rms_px": stereo_rms,
        "poses_used": len(act),
        "poses_total": len(poses),
        "camera": {"K": Kc.tolist(), "dist": [float(x) for x in dc], "std": _std_dict(cam_std, n_dist_c)},
        "projector": {"K": Kp.tolist(), "dist": [float(x) for x in dp], "std": _std_dict(proj_std, n_dist_p)},
        "intrinsics_refined_jointly": joint,
        "leave_one_out": {
            "projector_rms_px": {name: v for name, v in loo_by_name.items()},
            "median_px": float(np.median(list(finite_loo.values()))) if finite_loo else None,
        },
        "R": R.tolist(),
        "T": [float(x) for x in T],
        "baseline_mm": baseline,
        "coverage": {"camera": cam_cov, "projector": proj_cov, "grid": COVERAGE_CELLS, "edge_gaps": edge_gaps},
        "pose_diversity": {
            "tilt_min_deg": min(tilts) if tilts else None,
            "tilt_max_deg": max(tilts) if tilts else None,
            "max_angle_between_boards_deg": max_pair,
            "near_identical_pairs": similar,
        },
        "median_board_distance_mm": median_distance,
        "gamma_estimate": gamma_estimate,
        "warnings": warnings,
        "poses": pose_reports,
    }
    return ProcamCalibration(rig=rig, report=report)
