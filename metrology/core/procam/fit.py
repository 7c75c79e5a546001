"""The OpenCV fits of a calibration: each device alone, the stereo fit, its standard deviations and
the leave-one-pose-out refits (the equations are in :mod:`metrology.core.procam.calibrate`).

- :func:`fit_devices`: ``cv2.calibrateCameraExtended`` for the camera and for the projector
  (:class:`DeviceFits`);
- :func:`stereo_fit`: ``cv2.stereoCalibrateExtended`` from those, refining both devices'
  intrinsics with the pose or holding them (:class:`StereoFit`), and its rig (:meth:`StereoFit.rig`);
- :func:`leave_one_out`: each pose's projector corners predicted by a calibration of the others;
- :func:`project_board`: board points through a pose and a device, ``cv2.projectPoints``.

Every fit runs to convergence (:data:`CRITERIA`) with the same flags (:func:`device_flags`,
:func:`stereo_flags`). Poses are in :class:`~metrology.core.procam.poses.FitPoints` order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig
from metrology.core.procam.poses import FitPoints, Float32Array

FloatArray = npt.NDArray[np.float64]

CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
"""Termination of every OpenCV fit here: 200 iterations or a step below 1e-12 (run to convergence)."""


def device_flags(fix_k3: bool) -> int:
    """``calibrateCamera``'s flags: k3 held at 0 or not."""
    return cv2.CALIB_FIX_K3 if fix_k3 else 0


def stereo_flags(joint: bool, fix_k3: bool) -> int:
    """``stereoCalibrate``'s flags: refine both devices' intrinsics from the given start (``joint``),
    or hold them fixed."""
    return (cv2.CALIB_USE_INTRINSIC_GUESS | device_flags(fix_k3)) if joint else cv2.CALIB_FIX_INTRINSIC


def project_board(obj: FloatArray, rvec: FloatArray, tvec: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    """Board points ``obj`` (n, 3) mm through the pose ``rvec``, ``tvec`` (3,) (Rodrigues vector,
    mm) and the device ``K`` (3, 3), ``dist`` (5,): ``(n, 2)`` float64 pixels / projector units."""
    pts, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, dist)
    return np.asarray(pts, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class Intrinsics:
    """One device's pinhole intrinsics and distortion as fitted, with their standard deviations.

    Attributes
    ----------
    K : (3, 3) float64
        Pixels (projector units for the projector).
    dist : (5,) float64
        k1, k2, p1, p2, k3.
    std : (n >= 9,) float64
        Standard deviations in OpenCV's order (fx, fy, cx, cy, k1, k2, p1, p2, k3, ...).
    """

    K: FloatArray
    dist: FloatArray
    std: FloatArray


@dataclass(frozen=True)
class DeviceFit:
    """One device's ``calibrateCameraExtended`` fit.

    Attributes
    ----------
    rms : float
        RMS reprojection error, pixels (projector units for the projector).
    intrinsics : Intrinsics
    rvecs, tvecs : tuple of (3, 1) float64
        Each pose's board in the device's frame (Rodrigues vector; mm).
    """

    rms: float
    intrinsics: Intrinsics
    rvecs: tuple[FloatArray, ...]
    tvecs: tuple[FloatArray, ...]


@dataclass(frozen=True)
class DeviceFits:
    """Both devices' own fits of the same poses."""

    camera: DeviceFit
    projector: DeviceFit


def _fit_device(
    obj: tuple[Float32Array, ...], img: tuple[Float32Array, ...], size: tuple[int, int], flags: int
) -> DeviceFit:
    rms, K, dist, rvecs, tvecs, std_int, _std_ext, _per_view = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
        list(obj), list(img), size, None, None, flags=flags, criteria=CRITERIA
    )
    return DeviceFit(float(rms), Intrinsics(K, dist.ravel()[:5], std_int.ravel()), tuple(rvecs), tuple(tvecs))


def fit_devices(
    points: FitPoints, camera_size: tuple[int, int], projector_size: tuple[int, int], fix_k3: bool
) -> DeviceFits:
    """Calibrate the camera (board points against camera points) and the projector (against
    projector points) each on its own; sizes ``(width, height)`` pixels / projector units."""
    flags = device_flags(fix_k3)
    return DeviceFits(
        camera=_fit_device(points.object_mm, points.camera_px, camera_size, flags),
        projector=_fit_device(points.object_mm, points.projector_px, projector_size, flags),
    )


@dataclass(frozen=True)
class StereoFit:
    """The stereo fit: both devices, their pose ``X_p = R X_c + T`` and each board pose.

    Attributes
    ----------
    rms : float
        ``stereoCalibrate``'s RMS over both devices, pixels.
    names : tuple of str
        The poses fitted, in order.
    camera, projector : Intrinsics
        Both devices, refined by the fit (``joint``) or :class:`DeviceFits`' held.
    R : (3, 3) float64
    T : (3,) float64, mm
    rvecs, tvecs : tuple of (3, 1) float64
        Each pose's board in the camera's frame (Rodrigues vector; mm).
    pose_rms : (n_poses, 2) float64
        Each pose's camera and projector RMS, pixels.
    joint : bool
        The intrinsics were refined with the pose (else held at :class:`DeviceFits`').
    """

    rms: float
    names: tuple[str, ...]
    camera: Intrinsics
    projector: Intrinsics
    R: FloatArray
    T: FloatArray
    rvecs: tuple[FloatArray, ...]
    tvecs: tuple[FloatArray, ...]
    pose_rms: FloatArray
    joint: bool

    def board_pose(self, name: str) -> tuple[FloatArray, FloatArray]:
        """Pose ``name``'s board in the camera's frame: ``R_i`` (3, 3), ``t_i`` (3,) mm (``X_c = R_i X_b + t_i``)."""
        k = self.names.index(name)
        rvec = np.asarray(self.rvecs[k]).ravel()
        return np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64), np.asarray(self.tvecs[k]).ravel()

    def reproject(self, name: str, obj: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Board points ``obj`` (n, 3) mm of pose ``name`` through the fit: into the camera at the
        board pose ``(R_i, t_i)`` and into the projector at ``(R R_i, R t_i + T)``; ``(n, 2)``
        float64 each, pixels / projector units."""
        k = self.names.index(name)
        rvec, tvec = np.asarray(self.rvecs[k]).ravel(), np.asarray(self.tvecs[k]).ravel()
        Ri = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
        rvec_p = np.asarray(cv2.Rodrigues(self.R @ Ri)[0], dtype=np.float64).ravel()
        camera = project_board(obj, rvec, tvec, self.camera.K, self.camera.dist)
        projector = project_board(obj, rvec_p, self.R @ tvec + self.T, self.projector.K, self.projector.dist)
        return camera, projector

    def rig(self, camera_size: tuple[int, int], projector_size: tuple[int, int]) -> PinholeRig:
        """The pinhole rig of the fit (sizes ``(width, height)``, pixels / projector units)."""
        return PinholeRig(
            camera=PinholeCamera(
                width_px=camera_size[0],
                height_px=camera_size[1],
                K=tuple(tuple(float(x) for x in row) for row in self.camera.K),  # type: ignore[arg-type]
                dist=tuple(float(x) for x in self.camera.dist),
            ),
            projector=PinholeProjector(
                width=projector_size[0],
                height=projector_size[1],
                K=tuple(tuple(float(x) for x in row) for row in self.projector.K),  # type: ignore[arg-type]
                dist=tuple(float(x) for x in self.projector.dist),
            ),
            R=tuple(tuple(float(x) for x in row) for row in self.R),  # type: ignore[arg-type]
            T=(float(self.T[0]), float(self.T[1]), float(self.T[2])),
        )


def stereo_fit(
    points: FitPoints, devices: DeviceFits, camera_size: tuple[int, int], *, joint: bool, fix_k3: bool
) -> StereoFit:
    """``cv2.stereoCalibrateExtended`` started from both devices' own fits.

    ``joint``: refine both devices' intrinsics and distortion with the pose (one bundle
    adjustment), standard deviations from :func:`_joint_std`; else hold them at ``devices``
    (``CALIB_FIX_INTRINSIC``), standard deviations those of ``devices``.
    """
    cam, prj = devices.camera.intrinsics, devices.projector.intrinsics
    stereo = cv2.stereoCalibrateExtended(  # type: ignore[call-overload]
        list(points.object_mm),
        list(points.camera_px),
        list(points.projector_px),
        cam.K.copy(),
        cam.dist.copy(),
        prj.K.copy(),
        prj.dist.copy(),
        camera_size,
        None,
        None,
        flags=stereo_flags(joint, fix_k3),
        criteria=CRITERIA,
    )
    Kc, dc, Kp, dp = cam.K, cam.dist, prj.K, prj.dist
    if joint:
        Kc, dc = np.asarray(stereo[1], np.float64), np.asarray(stereo[2], np.float64).ravel()[:5]
        Kp, dp = np.asarray(stereo[3], np.float64), np.asarray(stereo[4], np.float64).ravel()[:5]
    R = np.asarray(stereo[5], dtype=np.float64)
    T = np.asarray(stereo[6], dtype=np.float64).ravel()
    rvecs, tvecs = tuple(stereo[9]), tuple(stereo[10])
    if joint:
        cam_std, proj_std = _joint_std(points, Kc, dc, Kp, dp, R, T, rvecs, tvecs, fix_k3)
    else:
        cam_std, proj_std = cam.std, prj.std
    return StereoFit(
        rms=float(stereo[0]),
        names=points.names,
        camera=Intrinsics(Kc, dc, cam_std),
        projector=Intrinsics(Kp, dp, proj_std),
        R=R,
        T=T,
        rvecs=rvecs,
        tvecs=tvecs,
        pose_rms=np.asarray(stereo[11]).reshape(-1, 2),
        joint=joint,
    )


def _joint_std(
    points: FitPoints,
    Kc: FloatArray,
    dc: FloatArray,
    Kp: FloatArray,
    dp: FloatArray,
    R: FloatArray,
    T: FloatArray,
    rvecs: tuple[FloatArray, ...],
    tvecs: tuple[FloatArray, ...],
    fix_k3: bool,
) -> tuple[FloatArray, FloatArray]:
    """Standard deviations of both devices' intrinsics after the joint stereo fit.

    Parameters ``theta`` = camera ``(fx, fy, cx, cy, k1, k2, p1, p2[, k3])``, the projector's
    likewise, the stereo ``rvec(R)``, ``T`` and each pose's camera-frame ``rvec_i``, ``t_i``; the
    residuals are every used corner's camera and projector reprojection errors (pixels; the
    projector sees pose ``(R R_i, R t_i + T)``). ``cov = s^2 (J^T J)^-1``, ``s^2 = sum r^2 / (m - n)``,
    ``J`` by central differences (steps ``1e-6 max(1, |theta|)``). Returns two ``(9,)`` float64
    arrays in ``calibrateCameraExtended``'s order ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` (k3's
    entry 0 when it is held at 0); NaN when ``J^T J`` is singular.
    """
    obj = [o.reshape(-1, 3).astype(np.float64) for o in points.object_mm]
    cam = [c.reshape(-1, 2).astype(np.float64) for c in points.camera_px]
    prj = [q.reshape(-1, 2).astype(np.float64) for q in points.projector_px]
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
            out.append(project_board(o, rv, tv, Kc_, dc_).reshape(-1))
            rp = np.asarray(cv2.Rodrigues(Rs @ Ri)[0], np.float64).ravel()
            out.append(project_board(o, rp, Rs @ tv + Ts, Kp_, dp_).reshape(-1))
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


MIN_LEAVE_ONE_OUT_POSES = 3
"""Leave-one-out needs this many poses (two left to calibrate on)."""


def leave_one_out(
    points: FitPoints,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    *,
    joint: bool,
    fix_k3: bool,
) -> dict[str, float]:
    """Each pose's projector corners predicted by a calibration of the other poses, RMS pixels, by name.

    For pose ``k``: calibrate both devices and the stereo pose on the others (as the full fit
    does), find pose ``k``'s board from its camera corners alone (``cv2.solvePnP`` with the
    camera's intrinsics), carry it into the projector (``R R_k``, ``R t_k + T``), project, and
    return ``sqrt(mean |p_observed - p_predicted|^2)``. Empty for fewer than
    :data:`MIN_LEAVE_ONE_OUT_POSES` poses; NaN where a fit fails. It measures what a calibration
    is for, predicting poses it has not seen, which the reprojection RMS of the poses it was
    fitted to does not.
    """
    obj, cam, prj = points.object_mm, points.camera_px, points.projector_px
    if len(obj) < MIN_LEAVE_ONE_OUT_POSES:
        return {}
    flags, s_flags = device_flags(fix_k3), stereo_flags(joint, fix_k3)
    out: dict[str, float] = {}
    for k, name in enumerate(points.names):
        o = [obj[i] for i in range(len(obj)) if i != k]
        c = [cam[i] for i in range(len(obj)) if i != k]
        q = [prj[i] for i in range(len(obj)) if i != k]
        try:
            _, Kc0, dc0, _, _ = cv2.calibrateCamera(o, c, camera_size, None, None, flags=flags, criteria=CRITERIA)
            _, Kp0, dp0, _, _ = cv2.calibrateCamera(o, q, projector_size, None, None, flags=flags, criteria=CRITERIA)
            st = cv2.stereoCalibrate(o, c, q, Kc0, dc0, Kp0, dp0, camera_size, flags=s_flags, criteria=CRITERIA)
            Kc, dc = np.asarray(st[1], np.float64), np.asarray(st[2], np.float64).ravel()
            Kp, dp = np.asarray(st[3], np.float64), np.asarray(st[4], np.float64).ravel()
            R, T = np.asarray(st[5], np.float64), np.asarray(st[6], np.float64)
            ok, rvec, tvec = cv2.solvePnP(obj[k], cam[k], Kc, dc)
        except cv2.error:
            out[name] = math.nan
            continue
        if not ok:
            out[name] = math.nan
            continue
        Rb = np.asarray(cv2.Rodrigues(rvec)[0], np.float64)
        rp = np.asarray(cv2.Rodrigues(R @ Rb)[0], np.float64).ravel()
        predicted = project_board(obj[k].reshape(-1, 3).astype(np.float64), rp, (R @ tvec).ravel() + T.ravel(), Kp, dp)
        err = predicted - prj[k].reshape(-1, 2)
        out[name] = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    return out
