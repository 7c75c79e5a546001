"""The OpenCV fits of a calibration: each device alone, the stereo fit, its standard deviations and
the leave-one-pose-out refits (the equations are in :mod:`metrology.core.procam.calibrate`).

- :func:`fit_devices`: ``cv2.calibrateCameraExtended`` for the camera and for the projector
  (:class:`DeviceFits`);
- :func:`stereo_fit`: ``cv2.stereoCalibrateExtended`` from those, refining both devices'
  intrinsics with the pose or holding them (:class:`StereoFit`), and its rig (:meth:`StereoFit.rig`);
- :func:`final_covariance`: the covariance of every parameter of the fit that gave the
  intrinsics, board poses included (:mod:`~metrology.core.procam.bundle`), and
  :func:`intrinsic_std`: a device's standard deviations from it;
- :func:`leave_one_out_fits`: each pose's projector corners predicted by a calibration of the
  others, and those calibrations' intrinsics;
- :func:`project_board` (from :mod:`~metrology.core.procam.bundle`): board points through a pose
  and a device, ``cv2.projectPoints``.

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
from metrology.core.procam.bundle import (
    INTRINSIC_NAMES,
    ParameterCovariance,
    device_covariance,
    independent,
    joint_covariance,
    project_board,
)
from metrology.core.procam.poses import FitPoints, Float32Array

__all__ = [
    "CRITERIA",
    "DeviceFit",
    "DeviceFits",
    "Intrinsics",
    "LeftOutFit",
    "StereoFit",
    "device_flags",
    "final_covariance",
    "fit_devices",
    "intrinsic_std",
    "leave_one_out_fits",
    "project_board",
    "stereo_fit",
    "stereo_flags",
]

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
    covariance : ParameterCovariance or None
        Every parameter of the fit that gave the intrinsics (:func:`final_covariance`): the joint
        fit's, or both devices' own fits' when the intrinsics were held.
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
    covariance: ParameterCovariance | None = None

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
    adjustment), standard deviations from its covariance (:func:`final_covariance`); else hold them
    at ``devices`` (``CALIB_FIX_INTRINSIC``), standard deviations those of ``devices``
    (``calibrateCameraExtended``'s) and the covariance that of ``devices``' fits.
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
    covariance = final_covariance(points, (Kc, dc), (Kp, dp), R, T, rvecs, tvecs, None if joint else devices, fix_k3)
    if joint:
        cam_std, proj_std = intrinsic_std(covariance, "camera"), intrinsic_std(covariance, "projector")
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
        covariance=covariance,
    )


def intrinsic_std(covariance: ParameterCovariance, device: str) -> FloatArray:
    """A device's standard deviations from a covariance (:mod:`~metrology.core.procam.bundle`'s
    names), (9,) float64 in ``calibrateCameraExtended``'s order ``(fx, fy, cx, cy, k1, k2, p1, p2,
    k3)``; 0 for a coefficient the fit held (k3 with ``fix_k3``)."""
    std = covariance.std()
    out = np.zeros(len(INTRINSIC_NAMES))
    for k, name in enumerate(INTRINSIC_NAMES):
        if f"{device}.{name}" in covariance.names:
            out[k] = std[covariance.index(f"{device}.{name}")]
    return out


def final_covariance(
    points: FitPoints,
    camera: tuple[FloatArray, FloatArray],
    projector: tuple[FloatArray, FloatArray],
    R: FloatArray,
    T: FloatArray,
    rvecs: tuple[FloatArray, ...],
    tvecs: tuple[FloatArray, ...],
    devices: DeviceFits | None,
    fix_k3: bool,
) -> ParameterCovariance:
    """The covariance of every parameter of the fit that gave the intrinsics: the joint stereo fit
    (:func:`~metrology.core.procam.bundle.joint_covariance`; ``devices`` None) or, when the
    intrinsics are held at both devices' own fits (``devices``), those two fits'
    (:func:`~metrology.core.procam.bundle.device_covariance`, block diagonal)."""
    obj = [np.asarray(o, np.float64).reshape(-1, 3) for o in points.object_mm]
    if devices is None:
        return joint_covariance(
            obj, points.camera_px, points.projector_px, points.names, camera, projector, R, T, rvecs, tvecs, fix_k3
        )
    own = [
        device_covariance(
            name,
            obj,
            image,
            points.names,
            (fit.intrinsics.K, fit.intrinsics.dist),
            fit.rvecs,
            fit.tvecs,
            fix_k3,
        )
        for name, image, fit in (
            ("camera", points.camera_px, devices.camera),
            ("projector", points.projector_px, devices.projector),
        )
    ]
    return independent(own[0], own[1])


MIN_LEAVE_ONE_OUT_POSES = 3
"""Leave-one-out needs this many poses (two left to calibrate on)."""


@dataclass(frozen=True)
class LeftOutFit:
    """Pose ``name`` left out: the calibration of the other poses and its prediction of the pose.

    Attributes
    ----------
    name : str
    projector_rms_px : float
        ``sqrt(mean |p_observed - p_predicted|^2)`` over the pose's projector corners (NaN when a
        fit failed).
    camera, projector : (9,) float64
        The other poses' intrinsics ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` (NaN when a fit failed).
    """

    name: str
    projector_rms_px: float
    camera: FloatArray
    projector: FloatArray


def _intrinsic_values(K: FloatArray, dist: FloatArray) -> FloatArray:
    d = np.zeros(5)
    given = np.asarray(dist, np.float64).ravel()[:5]
    d[: given.size] = given
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d], dtype=np.float64)


def _failed(name: str) -> LeftOutFit:
    nan = np.full(len(INTRINSIC_NAMES), np.nan)
    return LeftOutFit(name, math.nan, nan, nan.copy())


def leave_one_out_fits(
    points: FitPoints,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    *,
    joint: bool,
    fix_k3: bool,
) -> tuple[LeftOutFit, ...]:
    """Each pose left out in turn: the others calibrated as the full fit is, and the pose's
    projector corners predicted (:class:`LeftOutFit`, in pose order).

    For pose ``k``: calibrate both devices and the stereo pose on the others (as the full fit
    does), find pose ``k``'s board from its camera corners alone (``cv2.solvePnP`` with the
    camera's intrinsics), carry it into the projector (``R R_k``, ``R t_k + T``), project, and
    compare with the decoded corners. Empty for fewer than :data:`MIN_LEAVE_ONE_OUT_POSES` poses.
    It measures what a calibration is for, predicting poses it has not seen, which the
    reprojection RMS of the poses it was fitted to does not; the spread of the intrinsics over
    the refits is the jackknife's measure of their uncertainty
    (:mod:`~metrology.core.procam.uncertainty`).
    """
    obj, cam, prj = points.object_mm, points.camera_px, points.projector_px
    if len(obj) < MIN_LEAVE_ONE_OUT_POSES:
        return ()
    flags, s_flags = device_flags(fix_k3), stereo_flags(joint, fix_k3)
    out: list[LeftOutFit] = []
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
            out.append(_failed(name))
            continue
        if not ok:
            out.append(_failed(name))
            continue
        Rb = np.asarray(cv2.Rodrigues(rvec)[0], np.float64)
        rp = np.asarray(cv2.Rodrigues(R @ Rb)[0], np.float64).ravel()
        predicted = project_board(obj[k].reshape(-1, 3).astype(np.float64), rp, (R @ tvec).ravel() + T.ravel(), Kp, dp)
        err = predicted - prj[k].reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
        out.append(LeftOutFit(name, rms, _intrinsic_values(Kc, dc), _intrinsic_values(Kp, dp)))
    return tuple(out)
