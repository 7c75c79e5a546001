"""Two-camera (stereo) calibration from board poses: both cameras as OpenCV pinholes, camera 1's pose,
and a report that explains the result (docs/stereo-calibration.md).

Per pose ``i`` the board's points ``X_k`` (mm, board frame ``Z = 0``) are seen at camera-0 pixels
``a_ik`` and camera-1 pixels ``b_ik`` (:func:`~metrology.core.procam.board.detect_board` in each
camera's board image). This is the projector-camera calibration of :mod:`metrology.core.procam`
with camera 1 in the projector's place, and it runs the same steps on the same code:

1. each camera alone: ``cv2.calibrateCameraExtended(X, a)`` and ``(X, b)`` -> ``K``, ``dist``
   (5 coefficients), after leaving out mirrored or flipped corner orders and outlier corners
   (:func:`~metrology.core.procam.calibrate.chosen_poses`);
2. stereo: ``cv2.stereoCalibrateExtended`` -> ``R``, ``T`` with ``X_c1 = R X_c0 + T`` (mm, the stereo
   rig file's convention), refining both cameras' intrinsics with the pose by default (``joint``);
3. leave-one-pose-out: each pose's camera-1 corners predicted by a calibration of the other poses
   from its camera-0 corners alone (``solvePnP``), pixels RMS;
4. coverage of both images, pose diversity, the intrinsics' uncertainty, warnings with actions.

Every residual is ``observed - projected`` (pixels) through the stereo solution: camera 0 sees board
pose ``(R_i, t_i)``, camera 1 ``(R R_i, R t_i + T)``. RMS values are OpenCV's:
``sqrt(sum |r|^2 / n_points)`` per camera, over both cameras for the stereo fit.

The report (``gcps-stereo-calibration-report/1``) has the keys of the projector-camera report
(``gcps-procam-report/1``, docs/procam-calibration.md) with ``camera`` read ``camera0`` and
``projector`` read ``camera1`` (``camera0_rms_px``, ``camera1_rms_px``, ``coverage.camera1``,
``residual_camera1_px``, ``leave_one_out.camera1_rms_px``...), without the projector's gamma.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.stereo import StereoRig
from metrology.core.io.cameras import camera_folders
from metrology.core.procam.advice import (
    INCONSISTENT_POSE_PX,
    INCONSISTENT_POSE_RATIO,
    MAX_EDGE_GAP,
    MIN_COVERAGE,
    RECOMMENDED_POSES,
    CalibrationWarning,
    board_unit_warnings,
    focal_distance_coupled_warnings,
    high_rms_warnings,
    left_out_warnings,
    similar_poses_warnings,
)
from metrology.core.procam.board import BoardSpec, detect_board
from metrology.core.procam.calibrate import calibrate_procam, chosen_poses
from metrology.core.procam.diagnostics import COVERAGE_CELLS, Coverage, image_coverage, pose_diversity
from metrology.core.procam.fit import StereoFit, leave_one_out_fits, stereo_fit
from metrology.core.procam.poses import PoseObservation, ProcamCalibrationError, fit_points, select_usable_poses
from metrology.core.procam.report import procam_report
from metrology.core.procam.uncertainty import intrinsics_uncertainty

FloatArray = npt.NDArray[np.float64]

REPORT_FORMAT = "gcps-stereo-calibration-report/1"
CAMERAS = camera_folders(2)
"""The cameras' names in captures (their sub-folders, :mod:`metrology.core.io.cameras`) and messages."""


class StereoCalibrationError(ValueError):
    """The poses cannot give a stereo calibration (the message names the pose and the camera)."""


@dataclass(frozen=True)
class StereoBoardPose:
    """One board pose seen by both cameras.

    Attributes
    ----------
    name : str
    camera0_px, camera1_px : (N, 2) float64
        The board's points in camera 0 and camera 1, pixels (centres at integers), in the board's
        order (:meth:`~metrology.core.procam.board.BoardSpec.object_points`).
    """

    name: str
    camera0_px: FloatArray
    camera1_px: FloatArray


def observe_stereo_pose(name: str, image0: npt.ArrayLike, image1: npt.ArrayLike, board: BoardSpec) -> StereoBoardPose:
    """The board's points in both cameras' images ``(H, W)`` (any dtype) of pose ``name``.

    Raises
    ------
    StereoCalibrationError
        ``pose NAME: board SPEC not found in cam1's image`` when a camera's image has no board.
    """
    points = []
    for camera, image in zip(CAMERAS, (image0, image1), strict=True):
        found = detect_board(image, board)
        if found is None:
            raise StereoCalibrationError(
                f"pose {name}: board {board.spec()} not found in {camera}'s image "
                "(whole board in view, in focus, evenly lit, and the board spec's COLSxROWS counting inner corners?)"
            )
        points.append(found)
    return StereoBoardPose(name=name, camera0_px=points[0], camera1_px=points[1])


@dataclass(frozen=True)
class StereoCalibration:
    """The calibration: the stereo rig (cameras 0 and 1 with camera 1's ``R``, ``T``, the projector's
    size; docs/stereo-calibration.md), the report (JSON-ready but for non-finite floats) and the fit."""

    rig: StereoRig
    report: dict[str, Any] = field(default_factory=dict)
    stereo: StereoFit | None = None


_CAMERA_TOKEN = re.compile(r"(?<![A-Za-z0-9])(camera|projector)(?![A-Za-z0-9])")


def _renamed_key(key: str) -> str:
    """``camera`` -> ``camera0``, ``projector`` -> ``camera1`` as whole tokens of a key or name
    (``residual_projector_px`` -> ``residual_camera1_px``, ``camera.fx`` -> ``camera0.fx``)."""
    return _CAMERA_TOKEN.sub(lambda m: "camera0" if m.group(1) == "camera" else "camera1", key)


def _renamed(value: Any, values_too: bool = False) -> Any:
    """``value`` with every mapping key renamed (:func:`_renamed_key`), and string values when ``values_too``."""
    if isinstance(value, Mapping):
        return {_renamed_key(str(k)): _renamed(v, values_too) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_renamed(v, values_too) for v in value]
    if values_too and isinstance(value, str):
        return _renamed_key(value)
    return value


_PROSE = re.compile(r"\b(?:[Tt]he )?(camera|projector)\b")


def _two_cameras_prose(text: str) -> str:
    """A procam warning's text for two cameras: "the camera" -> "camera 0", "the projector" -> "camera 1"."""
    return _PROSE.sub(lambda m: "camera 0" if m.group(1) == "camera" else "camera 1", text)


def _for_two_cameras(warning: CalibrationWarning) -> CalibrationWarning:
    return CalibrationWarning(
        warning.cause,
        _two_cameras_prose(warning.message),
        _two_cameras_prose(warning.action),
        warning.poses,
        warning.pairs,
    )


def too_few_poses_warnings(n_used: int) -> list[CalibrationWarning]:
    """Fewer than :data:`~metrology.core.procam.advice.RECOMMENDED_POSES` poses used (cause ``too_few_poses``)."""
    if n_used >= RECOMMENDED_POSES:
        return []
    return [
        CalibrationWarning(
            "too_few_poses",
            f"only {n_used} poses were used; both cameras' intrinsics and their pose are poorly constrained.",
            f"Capture at least {RECOMMENDED_POSES} (better 8 to 12) poses seen by both cameras, tilting the board "
            "in different directions.",
        )
    ]


def inconsistent_pose_warnings(leave_one_out_px: Mapping[str, float]) -> list[CalibrationWarning]:
    """Poses the others do not predict (cause ``inconsistent_pose``): left out, a pose's camera-1
    corners are predicted worse (RMS, pixels) than ``INCONSISTENT_POSE_RATIO`` times the median of the
    other poses' and than ``INCONSISTENT_POSE_PX``."""
    finite = {name: v for name, v in leave_one_out_px.items() if v is not None and np.isfinite(v)}
    found = []
    for name, value in finite.items():
        others = [v for n, v in finite.items() if n != name]
        typical = float(np.median(others)) if others else float("nan")
        if others and value > max(INCONSISTENT_POSE_RATIO * typical, INCONSISTENT_POSE_PX):
            found.append(f"{name} {value:.2f} px against {typical:.2f} px")
    if not found:
        return []
    return [
        CalibrationWarning(
            "inconsistent_pose",
            "not predicted by the other poses (calibrated without the pose, the rig puts its camera-1 corners this "
            f"far, RMS, from where they were found, against the median of the others): {', '.join(found)}.",
            "Retake these poses or leave them out: the board or a camera may have moved between the two images "
            "(trigger both cameras together), or the corners are wrong (blur, reflections).",
            tuple(text.split(" ")[0] for text in found),
        )
    ]


def coverage_warnings(coverage: Coverage) -> list[CalibrationWarning]:
    """Per camera, corners covering less than ``MIN_COVERAGE`` of its image or stopping more than
    ``MAX_EDGE_GAP`` short of one of its edges (cause ``coverage``; camera 0's entry first)."""
    entries = []
    for cov, key, what in ((coverage.camera, "camera", "camera 0"), (coverage.projector, "projector", "camera 1")):
        gaps = {edge: g for edge, g in coverage.edge_gaps[key].items() if g > MAX_EDGE_GAP}
        if cov >= MIN_COVERAGE and not gaps:
            continue
        reasons = []
        if cov < MIN_COVERAGE:
            reasons.append(f"cover only {cov:.0%} of it (cells of an {COVERAGE_CELLS}x{COVERAGE_CELLS} grid)")
        if gaps:
            reasons.append(
                "come no nearer than " + ", ".join(f"{g:.0%} to its {edge} edge" for edge, g in gaps.items())
            )
        entries.append(
            CalibrationWarning(
                "coverage",
                f"in {what}'s image the corners {' and '.join(reasons)}; its distortion is extrapolated there.",
                f"Add poses that bring the board's corners within {MAX_EDGE_GAP:.0%} of every edge of {what}'s image "
                "(while the other camera still sees the whole board), tilted by 20 to 40 degrees.",
            )
        )
    return entries


def stereo_rig_dict(
    stereo: StereoFit, camera0_size: tuple[int, int], camera1_size: tuple[int, int], projector_size: tuple[float, float]
) -> dict[str, Any]:
    """The stereo rig file's object of a fit (sizes ``(width, height)``; the projector's in its units)."""

    def camera(K: FloatArray, dist: FloatArray, size: tuple[int, int]) -> dict[str, Any]:
        return {
            "width_px": int(size[0]),
            "height_px": int(size[1]),
            "K": [[float(x) for x in row] for row in K],
            "dist": [float(x) for x in dist],
        }

    second = camera(stereo.projector.K, stereo.projector.dist, camera1_size)
    second["R"] = [[float(x) for x in row] for row in stereo.R]
    second["T"] = [float(x) for x in stereo.T]
    return {
        "model": StereoRig.model,
        "cameras": [camera(stereo.camera.K, stereo.camera.dist, camera0_size), second],
        "projector": {"width": projector_size[0], "height": projector_size[1]},
    }


def calibrate_stereo(
    poses: Sequence[StereoBoardPose],
    board: BoardSpec,
    camera0_size: tuple[int, int],
    camera1_size: tuple[int, int],
    projector_size: tuple[float, float],
    *,
    fix_k3: bool = False,
    joint: bool = True,
    projector_poses: Sequence[PoseObservation] | None = None,
) -> StereoCalibration:
    """Calibrate two cameras and camera 1's pose from board poses; explain the result. With
    ``projector_poses``, calibrate the projector too.

    Parameters
    ----------
    poses : sequence of StereoBoardPose
        At least two, names unique.
    board : BoardSpec
    camera0_size, camera1_size : (width, height) pixels
    projector_size : (width, height) projector units (written to the rig file; not calibrated)
    fix_k3 : bool
        Hold the radial coefficient k3 at 0 for both cameras.
    joint : bool
        Refine both cameras' intrinsics together with the pose (default); False holds each
        camera's own calibration in the stereo fit.
    projector_poses : sequence of PoseObservation, optional
        Camera 0's board corners mapped into the projector (:func:`~metrology.core.procam.observe.observe_pose`
        of camera 0's codec stacks): the projector is then calibrated against camera 0 by
        :func:`~metrology.core.procam.calibrate.calibrate_procam` (its own fit of camera 0), and
        the rig's ``projector`` gets its ``K``, ``dist``, ``R``, ``T`` (``X_p = R X_c0 + T``); that
        calibration's report is the report's ``projector_calibration``
        (``gcps-procam-report/1``), its warnings are also the report's, prefixed
        ``projector calibration:``.

    Raises
    ------
    StereoCalibrationError
        No poses, names repeated, points of the wrong shape, or fewer than two usable poses.
    """
    if len(poses) < 2:
        raise StereoCalibrationError(f"need at least 2 board poses seen by both cameras, got {len(poses)}")
    size0 = (int(camera0_size[0]), int(camera0_size[1]))
    size1 = (int(camera1_size[0]), int(camera1_size[1]))
    observations = []
    for pose in poses:
        for camera, pts in zip(CAMERAS, (pose.camera0_px, pose.camera1_px), strict=True):
            if np.asarray(pts).shape != (board.count, 2):
                raise StereoCalibrationError(
                    f"pose {pose.name}: {camera} has points of shape {np.asarray(pts).shape}, "
                    f"expected ({board.count}, 2)"
                )
        observations.append(
            PoseObservation(
                name=pose.name,
                camera_px=np.asarray(pose.camera0_px, np.float64),
                projector_px=np.asarray(pose.camera1_px, np.float64),
            )
        )
    try:
        selection = select_usable_poses(observations, board)
        selection, devices = chosen_poses(selection, board, size0, size1, fix_k3)
        points = fit_points(selection)
    except ProcamCalibrationError as exc:
        raise StereoCalibrationError(str(exc)) from None
    stereo = stereo_fit(points, devices, size0, joint=joint, fix_k3=fix_k3)
    refits = leave_one_out_fits(points, size0, size1, joint=joint, fix_k3=fix_k3)
    left_out = {fit.name: fit.projector_rms_px for fit in refits}
    uncertainty = intrinsics_uncertainty(stereo, refits)
    coverage = image_coverage(selection, size0, size1)
    diversity = pose_diversity(stereo)
    n_used = len(selection.used)
    reused = [
        *left_out_warnings(selection.poses),
        *similar_poses_warnings(diversity, n_used),
        *focal_distance_coupled_warnings(uncertainty),
        *board_unit_warnings(diversity.median_distance_mm, float(np.linalg.norm(stereo.T)), board),
    ]
    found = [
        *too_few_poses_warnings(n_used),
        *[_for_two_cameras(w) for w in reused],
        *inconsistent_pose_warnings(left_out),
        *coverage_warnings(coverage),
    ]
    high = [_for_two_cameras(w) for w in high_rms_warnings(devices.camera.rms, devices.projector.rms, found)]
    procam = procam_report(
        board=board,
        camera_size=size0,
        projector_size=size1,
        selection=selection,
        devices=devices,
        stereo=stereo,
        leave_one_out_px=left_out,
        coverage=coverage,
        diversity=diversity,
        gamma_estimate=None,
        warnings=[],
        uncertainty=uncertainty,
    )
    procam.pop("gamma_estimate", None)
    uncertainty_entry = procam.pop("uncertainty")
    procam.pop("warnings")
    poses_entry = procam.pop("poses")
    report: dict[str, Any] = _renamed(procam)
    report["format"] = REPORT_FORMAT
    report["convention"] = "X_c1 = R X_c0 + T (mm); residuals observed - projected, pixels"
    report["uncertainty"] = _renamed(uncertainty_entry, values_too=True)
    report["warnings"] = [w.to_dict() for w in [*found, *high]]
    report["poses"] = _renamed(poses_entry)
    rig_dict = stereo_rig_dict(stereo, size0, size1, projector_size)
    if projector_poses is not None:
        projector_fit = calibrate_procam(
            projector_poses,
            board,
            size0,
            (round(projector_size[0]), round(projector_size[1])),
            fix_k3=fix_k3,
            joint=joint,
        )
        projector = projector_fit.rig.projector
        rig_dict["projector"].update(
            {
                "K": [list(row) for row in projector.K],
                "dist": list(projector.dist),
                "R": [list(row) for row in projector_fit.rig.R],
                "T": list(projector_fit.rig.T),
            }
        )
        report["projector_calibration"] = projector_fit.report
        report["warnings"] += [
            {**w, "message": f"projector calibration: {w['message']}"} for w in projector_fit.report["warnings"]
        ]
    rig = StereoRig.from_dict(rig_dict)
    return StereoCalibration(rig=rig, report=report, stereo=stereo)
