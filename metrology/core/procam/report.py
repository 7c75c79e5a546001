"""The calibration report (``gcps-procam-report/1``, docs/procam-calibration.md): a JSON-ready dict
of the fits, each pose and corner with its residuals, the diagnostics and the warnings.

- :func:`corner_reports`: one pose's corners (points, used, outlier, residuals);
- :func:`pose_report`: one pose's entry (used or why not, RMS, tilt, distance, corners);
- :func:`procam_report`: the whole report.

A residual is ``observed - projected`` through the stereo fit (:meth:`StereoFit.reproject`);
pixels in the camera, projector units in the projector. Non-finite floats stay as they are (the
JSON writers turn them into null).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.procam.advice import CalibrationWarning
from metrology.core.procam.board import BoardSpec
from metrology.core.procam.diagnostics import COVERAGE_CELLS, Coverage, PoseDiversity, tilt_deg
from metrology.core.procam.fit import DeviceFits, Intrinsics, StereoFit
from metrology.core.procam.poses import BoolArray, PoseObservation, PoseSelection
from metrology.core.procam.uncertainty import Uncertainty, uncertainty_report

FloatArray = npt.NDArray[np.float64]

REPORT_FORMAT = "gcps-procam-report/1"


def _point(xy: FloatArray) -> list[float]:
    return [float(xy[0]), float(xy[1])]


def corner_reports(
    pose: PoseObservation, mask: BoolArray | None, projected: tuple[FloatArray, FloatArray] | None
) -> list[dict[str, Any]]:
    """One entry per board point of a pose whose board was found (else an empty list).

    Parameters
    ----------
    pose : PoseObservation
    mask : (N,) bool or None
        The pose's used corners (None: none used).
    projected : ((N, 2), (N, 2)) float64 or None
        The board points through the stereo fit into the camera and the projector
        (:meth:`StereoFit.reproject`); None for a pose left out (no residuals).

    Returns
    -------
    list of dict
        ``camera_px``, ``projector_px`` (None where not mapped), ``used``, ``outlier`` (only when
        true), ``decoded_fraction``, ``homography_rms`` (when known), ``residual_camera_px``,
        ``residual_projector_px`` (None without ``projected`` or a projector point).
    """
    if pose.camera_px is None:
        return []
    corners = []
    for j in range(pose.camera_px.shape[0]):
        cpx = pose.camera_px[j]
        ppx = pose.projector_px[j] if pose.projector_px is not None else None
        mapped = ppx is not None and bool(np.isfinite(ppx).all())
        c: dict[str, Any] = {
            "camera_px": _point(cpx),
            "projector_px": _point(ppx) if ppx is not None and mapped else None,
            "used": bool(pose.reason is None and mask is not None and mask[j]),
        }
        if pose.outliers is not None and pose.outliers[j]:
            c["outlier"] = True
        if pose.decoded_fraction is not None:
            c["decoded_fraction"] = float(pose.decoded_fraction[j])
        if pose.fit_rms is not None and np.isfinite(pose.fit_rms[j]):
            c["homography_rms"] = float(pose.fit_rms[j])
        if projected is not None:
            pc, pp = projected
            c["residual_camera_px"] = _point(cpx - pc[j])
            c["residual_projector_px"] = _point(ppx - pp[j]) if ppx is not None and mapped else None
        else:
            c["residual_camera_px"] = None
            c["residual_projector_px"] = None
        corners.append(c)
    return corners


def pose_report(
    pose: PoseObservation,
    mask: BoolArray | None,
    stereo: StereoFit,
    leave_one_out_px: Mapping[str, float],
) -> dict[str, Any]:
    """One pose's report entry.

    ``name``, ``used``, ``reason``, ``cause``, ``rms_px`` (the pose's stereo RMS over both
    devices, ``sqrt((e_c^2 + e_p^2) / 2)``; None when left out) and for a used pose
    ``camera_rms_px``, ``projector_rms_px``, ``tilt_deg``, ``leave_one_out_projector_rms_px``,
    ``distance_mm``; then ``decoded_fraction_median``, ``mismatch_fraction``,
    ``gamma_estimate`` when known, and ``corners`` (:func:`corner_reports`).
    """
    entry: dict[str, Any] = {"name": pose.name, "used": pose.reason is None, "reason": pose.reason, "cause": pose.cause}
    projected = None
    if pose.reason is None:
        assert pose.object_mm is not None
        k = stereo.names.index(pose.name)
        Ri, ti = stereo.board_pose(pose.name)
        projected = stereo.reproject(pose.name, pose.object_mm)
        e_c, e_p = float(stereo.pose_rms[k, 0]), float(stereo.pose_rms[k, 1])
        entry.update(
            {
                "rms_px": math.sqrt((e_c**2 + e_p**2) / 2),
                "camera_rms_px": e_c,
                "projector_rms_px": e_p,
                "tilt_deg": tilt_deg(Ri),
                "leave_one_out_projector_rms_px": leave_one_out_px.get(pose.name),
                "distance_mm": float(np.linalg.norm(ti)),
            }
        )
    else:
        entry["rms_px"] = None
    corners = corner_reports(pose, mask, projected)
    if pose.decoded_fraction is not None:
        entry["decoded_fraction_median"] = float(np.median(pose.decoded_fraction))
    if pose.mismatch_fraction is not None:
        entry["mismatch_fraction"] = pose.mismatch_fraction
    if pose.gamma is not None:
        entry["gamma_estimate"] = pose.gamma
    entry["corners"] = corners
    return entry


def _std_dict(std: FloatArray, n_dist: int) -> dict[str, Any]:
    s = np.asarray(std, dtype=np.float64).ravel()
    return {
        "fx": float(s[0]),
        "fy": float(s[1]),
        "cx": float(s[2]),
        "cy": float(s[3]),
        "dist": [float(x) for x in s[4 : 4 + n_dist]],
    }


def _device(device: Intrinsics) -> dict[str, Any]:
    K, dist = device.K, device.dist
    return {"K": K.tolist(), "dist": [float(x) for x in dist], "std": _std_dict(device.std, len(dist))}


def procam_report(
    *,
    board: BoardSpec,
    camera_size: tuple[int, int],
    projector_size: tuple[int, int],
    selection: PoseSelection,
    devices: DeviceFits,
    stereo: StereoFit,
    leave_one_out_px: Mapping[str, float],
    coverage: Coverage,
    diversity: PoseDiversity,
    gamma_estimate: float | None,
    warnings: Sequence[CalibrationWarning],
    uncertainty: Uncertainty | None = None,
) -> dict[str, Any]:
    """The report's dict, keys in the documented order (docs/procam-calibration.md).

    ``camera_rms_px`` and ``projector_rms_px`` are the devices' own fits' (``devices``), the
    intrinsics, their standard deviations, ``R``, ``T`` and the per-pose entries the stereo
    fit's; ``leave_one_out.median_px`` is the median of the finite values (None without);
    ``uncertainty`` (:func:`~metrology.core.procam.uncertainty.uncertainty_report`, before
    ``warnings``) when given.
    """
    finite_loo = [v for v in leave_one_out_px.values() if v is not None and math.isfinite(v)]
    tilts = diversity.tilts_deg
    report: dict[str, Any] = {
        "format": REPORT_FORMAT,
        "board": board.spec(),
        "camera_size": list(camera_size),
        "projector_size": list(projector_size),
        "camera_rms_px": devices.camera.rms,
        "projector_rms_px": devices.projector.rms,
        "stereo_rms_px": stereo.rms,
        "poses_used": len(selection.used),
        "poses_total": len(selection.poses),
        "camera": _device(stereo.camera),
        "projector": _device(stereo.projector),
        "intrinsics_refined_jointly": stereo.joint,
        "leave_one_out": {
            "projector_rms_px": dict(leave_one_out_px),
            "median_px": float(np.median(finite_loo)) if finite_loo else None,
        },
        "R": stereo.R.tolist(),
        "T": [float(x) for x in stereo.T],
        "baseline_mm": float(np.linalg.norm(stereo.T)),
        "coverage": {
            "camera": coverage.camera,
            "projector": coverage.projector,
            "grid": COVERAGE_CELLS,
            "edge_gaps": {device: dict(gaps) for device, gaps in coverage.edge_gaps.items()},
        },
        "pose_diversity": {
            "tilt_min_deg": min(tilts) if tilts else None,
            "tilt_max_deg": max(tilts) if tilts else None,
            "max_angle_between_boards_deg": diversity.max_angle_deg,
            "near_identical_pairs": [list(pair) for pair in diversity.similar_pairs],
        },
        "median_board_distance_mm": diversity.median_distance_mm,
        "gamma_estimate": gamma_estimate,
    }
    if uncertainty is not None:
        report["uncertainty"] = uncertainty_report(uncertainty)
    report["warnings"] = [w.to_dict() for w in warnings]
    report["poses"] = [pose_report(p, selection.masks.get(p.name), stereo, leave_one_out_px) for p in selection.poses]
    return report
