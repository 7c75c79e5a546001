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

:func:`calibrate_procam` composes steps that each take values and return new ones (the poses
given are never changed):

- :func:`~metrology.core.procam.poses.select_usable_poses`: board points, usable corners, the
  poses left out at once (board not found, poorly decoded);
- :func:`~metrology.core.procam.rejection.mirrored_poses`, then 1. and 2.
  (:func:`~metrology.core.procam.fit.fit_devices`), :func:`~metrology.core.procam.rejection.flipped_poses`
  and :func:`~metrology.core.procam.rejection.outlier_corners`, each change fitted again;
- 3. (:func:`~metrology.core.procam.fit.stereo_fit`, with the covariance of every parameter of
  the fit that gave the intrinsics) and :func:`~metrology.core.procam.fit.leave_one_out_fits`;
- :func:`~metrology.core.procam.uncertainty.intrinsics_uncertainty`: each intrinsic's std, its
  correlation with the boards' distances and the spread of the left-out fits;
- the diagnostics (:mod:`~metrology.core.procam.diagnostics`), one function per warning cause
  (:mod:`~metrology.core.procam.advice`) and the report (:mod:`~metrology.core.procam.report`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from metrology.core.geometry.pinhole import PROJECTOR_GAMMA_RANGE, PinholeRig
from metrology.core.procam.advice import (
    CalibrationWarning,
    board_unit_warnings,
    coverage_warnings,
    focal_distance_coupled_warnings,
    gamma_warnings,
    high_rms_warnings,
    inconsistent_pose_warnings,
    left_out_warnings,
    projector_mismatch_warnings,
    similar_poses_warnings,
    too_few_poses_warnings,
)
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.diagnostics import gamma_estimate, image_coverage, pose_diversity, rotation_angle_deg
from metrology.core.procam.fit import DeviceFits, fit_devices, leave_one_out_fits, stereo_fit
from metrology.core.procam.poses import (
    MIN_DECODED_FRACTION,
    PoseObservation,
    PoseSelection,
    ProcamCalibrationError,
    fit_points,
    select_usable_poses,
)
from metrology.core.procam.rejection import (
    OUTLIER_FLOOR_PX,
    flipped_poses,
    mirrored_poses,
    outlier_corners,
    reject_outlier_corners,
)
from metrology.core.procam.report import procam_report
from metrology.core.procam.uncertainty import intrinsics_uncertainty

__all__ = [
    "MIN_DECODED_FRACTION",
    "OUTLIER_FLOOR_PX",
    "PoseObservation",
    "ProcamCalibration",
    "ProcamCalibrationError",
    "calibrate_procam",
    "rotation_angle_deg",
]


@dataclass(frozen=True)
class ProcamCalibration:
    """The calibrated rig, the report (a JSON-ready dict, docs/procam-calibration.md) and the poses.

    ``poses`` are the given poses as the calibration judged them, in their order: ``object_mm``
    filled in, ``reason`` and ``cause`` set for the poses left out, ``outliers`` for poses with
    outlier corners (the given poses are not changed).
    """

    rig: PinholeRig
    report: dict[str, Any] = field(default_factory=dict)
    poses: tuple[PoseObservation, ...] = ()


def chosen_poses(
    selection: PoseSelection,
    board: BoardSpec,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    fix_k3: bool,
) -> tuple[PoseSelection, DeviceFits]:
    """Leave out the mirrored and flipped poses and the outlier corners; return the selection and
    both devices' own fits of it (fitted again after each step that changed it)."""

    def fit(chosen: PoseSelection) -> DeviceFits:
        return fit_devices(fit_points(chosen), camera_size, projector_size, fix_k3)

    selection = selection.leave_out(mirrored_poses(selection, board.cols), "corner_order_flipped")
    fits = fit(selection)
    flipped = flipped_poses(selection, fits)
    if flipped:
        selection = selection.leave_out(flipped, "corner_order_flipped")
        fits = fit(selection)
    # corners that disagree with their device's fit by far more than the noise (a corner located on
    # a shadowed or cut-off part of the board, a glint): left out, and the devices fitted again
    flagged = outlier_corners(selection, fits)
    if flagged:
        selection = reject_outlier_corners(selection, flagged)
        fits = fit(selection)
    return selection, fits


def _with_measured_gamma(rig: PinholeRig, gamma: float | None, precompensated: bool) -> PinholeRig:
    """The rig with ``projector.gamma`` the measured response (rounded to 4 decimals) when it is
    within the rig file's range and the patterns were not pre-compensated; else ``rig``."""
    lo, hi = PROJECTOR_GAMMA_RANGE
    if gamma is None or precompensated or not lo <= gamma <= hi:
        return rig
    return replace(rig, projector=replace(rig.projector, gamma=round(gamma, 4)))


def calibrate_procam(
    poses: Sequence[PoseObservation],
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
    poses : sequence of PoseObservation
        Poses whose ``reason`` is set are reported and left out; others are checked (decoded
        fraction around each corner, corner order, outlier corners) and used. Not changed.
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
        ``rig`` (the pinhole rig, mm), ``report`` (see docs/procam-calibration.md) and ``poses``
        (the poses as judged).

    Raises
    ------
    ProcamCalibrationError
        No poses, two of one name, or fewer than two usable poses (the message lists every pose's reason).
    """
    cam_size = (int(camera_size[0]), int(camera_size[1]))
    proj_size = (round(projector_size[0]), round(projector_size[1]))
    selection = select_usable_poses(poses, board, min_decoded_fraction)
    selection, devices = chosen_poses(selection, board, cam_size, proj_size, fix_k3)
    points = fit_points(selection)
    stereo = stereo_fit(points, devices, cam_size, joint=joint, fix_k3=fix_k3)
    refits = leave_one_out_fits(points, cam_size, proj_size, joint=joint, fix_k3=fix_k3)
    left_out = {fit.name: fit.projector_rms_px for fit in refits}
    uncertainty = intrinsics_uncertainty(stereo, refits)
    coverage = image_coverage(selection, cam_size, proj_size)
    diversity = pose_diversity(stereo)
    gamma = gamma_estimate(selection)
    n_used = len(selection.used)
    found: list[CalibrationWarning] = [
        *left_out_warnings(selection.poses),
        *too_few_poses_warnings(n_used),
        *similar_poses_warnings(diversity, n_used),
        *focal_distance_coupled_warnings(uncertainty),
        *inconsistent_pose_warnings(left_out),
        *coverage_warnings(coverage),
        *board_unit_warnings(diversity.median_distance_mm, float(np.linalg.norm(stereo.T)), board),
        *projector_mismatch_warnings(selection.poses, stereo.projector.K, proj_size),
        *gamma_warnings(gamma, codec_gamma_precompensated),
    ]
    warnings = [*found, *high_rms_warnings(devices.camera.rms, devices.projector.rms, found)]
    report = procam_report(
        board=board,
        camera_size=cam_size,
        projector_size=proj_size,
        selection=selection,
        devices=devices,
        stereo=stereo,
        leave_one_out_px=left_out,
        coverage=coverage,
        diversity=diversity,
        gamma_estimate=gamma,
        warnings=warnings,
        uncertainty=uncertainty,
    )
    rig = _with_measured_gamma(stereo.rig(cam_size, proj_size), gamma, codec_gamma_precompensated)
    return ProcamCalibration(rig=rig, report=report, poses=selection.poses)
