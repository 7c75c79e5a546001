"""What the projector-camera calibration page shows, read from the stored report (gcps-procam-report/1).

Nothing is computed again: the numbers are the report's (docs/procam-calibration.md), arranged
for the template: the devices' intrinsics and distortion with their standard deviations (beside
them the leave-one-pose-out spread and the correlation with the boards' distance, from the
report's ``uncertainty``), what the poses cannot determine, the stereo pose (baseline, rotation
angle), coverage, the warnings and the per-pose table.
"""

from __future__ import annotations

from typing import Any

from metrology.core.procam.diagnostics import rotation_angle_deg as core_rotation_angle_deg
from metrology.dashboard.selectors import finite_or_none

DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3")


def rig_change(rig_before: dict[str, Any], rig_file: dict[str, Any] | None) -> dict[str, Any]:
    """What applying the calibration does to the rig, in the models' own words: ``converts`` (the
    rig's model changes), ``before`` and ``after`` (the models' labels)."""
    from metrology.core.geometry import MODELS, model_name

    was = rig_before.get("model") or model_name(rig_before.get("rig_file") or {})
    names = [was, model_name(rig_file) if rig_file else was]  # no file yet: the calibration has not finished
    before, after = (MODELS[name].label if name in MODELS else name for name in names)
    return {"converts": names[0] != names[1], "before": before, "after": after}


def _uncertainty_columns(entry: dict[str, Any] | None) -> dict[str, Any]:
    """A row's columns from the report's ``uncertainty.DEVICE.intrinsics.NAME`` entry: ``spread``
    (leave-one-pose-out), ``spread_ratio``, ``agrees`` (None when not compared) and
    ``distance_corr``; all None without the entry (reports made before it)."""
    entry = entry or {}
    agrees = entry.get("agrees")
    return {
        "spread": finite_or_none(entry.get("leave_one_out_std")),
        "spread_ratio": finite_or_none(entry.get("spread_ratio")),
        "agrees": agrees if isinstance(agrees, bool) else None,
        "distance_corr": finite_or_none(entry.get("distance_correlation")),
    }


def device_rows(device: dict[str, Any], uncertainty: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """One row per intrinsic value of a device's report entry: ``name``, ``value``, ``std`` (one sigma;
    None when the report has none), ``unit`` ("px", or "" for distortion coefficients), and the
    columns of :func:`_uncertainty_columns` from the device's ``uncertainty`` entry."""
    K = device.get("K") or [[None] * 3] * 3
    std = device.get("std") or {}
    rows = [
        {"name": "fx", "value": finite_or_none(K[0][0]), "std": finite_or_none(std.get("fx")), "unit": "px"},
        {"name": "fy", "value": finite_or_none(K[1][1]), "std": finite_or_none(std.get("fy")), "unit": "px"},
        {"name": "cx", "value": finite_or_none(K[0][2]), "std": finite_or_none(std.get("cx")), "unit": "px"},
        {"name": "cy", "value": finite_or_none(K[1][2]), "std": finite_or_none(std.get("cy")), "unit": "px"},
    ]
    dist_std = list(std.get("dist") or [])
    for index, value in enumerate(device.get("dist") or []):
        name = DISTORTION_NAMES[index] if index < len(DISTORTION_NAMES) else f"d{index}"
        sigma = finite_or_none(dist_std[index]) if index < len(dist_std) else None
        rows.append({"name": name, "value": finite_or_none(value), "std": sigma, "unit": ""})
    intrinsics = (uncertainty or {}).get("intrinsics") or {}
    return [{**row, **_uncertainty_columns(intrinsics.get(row["name"]))} for row in rows]


def determinacy(report: dict[str, Any]) -> dict[str, Any]:
    """What the poses cannot determine, from the report's ``uncertainty`` (empty dict without it):
    ``limit`` (the correlation beyond which focal length and distance are not separable),
    ``factor`` (the spread/std agreement factor), ``fit``, ``left_out`` (left-out fits), and per
    device (``devices``: label, ``focal`` name, ``corr`` with the mean distance, ``coupled``,
    ``distance_mm`` and ``distance_std_mm``), ``disagreements`` (``device.name`` list) and
    ``parameters`` (the full covariance's size)."""
    u = report.get("uncertainty")
    if not isinstance(u, dict):
        return {}
    coupled = set(u.get("coupled") or [])
    devices = []
    for key, label in (("camera", "Camera"), ("projector", "Projector")):
        entry = u.get(key) or {}
        devices.append(
            {
                "label": label,
                "focal": entry.get("focal_parameter") or "fx",
                "corr": finite_or_none(entry.get("focal_distance_correlation")),
                "coupled": key in coupled,
                "distance_mm": finite_or_none(entry.get("mean_distance_mm")),
                "distance_std_mm": finite_or_none(entry.get("mean_distance_std_mm")),
            }
        )
    return {
        "limit": finite_or_none(u.get("correlation_limit")),
        "factor": finite_or_none(u.get("spread_factor")),
        "fit": u.get("fit"),
        "left_out": u.get("leave_one_out_fits"),
        "devices": devices,
        "disagreements": list(u.get("disagreements") or []),
        "parameters": len((u.get("covariance") or {}).get("parameters") or []),
    }


def rotation_angle_deg(R: Any) -> float | None:
    """The angle of the report's rotation ``R`` (3x3 nested lists), degrees; None when it is not one."""
    try:
        return core_rotation_angle_deg(R)
    except (TypeError, ValueError):
        return None


def procam_summary(report: dict[str, Any]) -> dict[str, Any]:
    """The page's view of a done calibration's report (empty dict for an empty report)."""
    if not report:
        return {}
    diversity = report.get("pose_diversity") or {}
    poses = []
    for index, pose in enumerate(report.get("poses") or []):
        poses.append(
            {
                "index": index,
                "name": pose.get("name"),
                "used": bool(pose.get("used")),
                "reason": pose.get("reason"),
                "cause": pose.get("cause"),
                "rms_px": finite_or_none(pose.get("rms_px")),
                "camera_rms_px": finite_or_none(pose.get("camera_rms_px")),
                "projector_rms_px": finite_or_none(pose.get("projector_rms_px")),
                "decoded_fraction": finite_or_none(pose.get("decoded_fraction_median")),
                "tilt_deg": finite_or_none(pose.get("tilt_deg")),
                "leave_one_out_px": finite_or_none(pose.get("leave_one_out_projector_rms_px")),
                "distance_mm": finite_or_none(pose.get("distance_mm")),
                "corners_used": sum(1 for c in pose.get("corners") or [] if c.get("used")),
                "corners": len(pose.get("corners") or []),
            }
        )
    coverage = report.get("coverage") or {}
    return {
        "board": report.get("board"),
        "camera_size": report.get("camera_size"),
        "projector_size": report.get("projector_size"),
        "rms": {
            "camera": finite_or_none(report.get("camera_rms_px")),
            "projector": finite_or_none(report.get("projector_rms_px")),
            "pair": finite_or_none(report.get("stereo_rms_px")),
        },
        "poses_used": report.get("poses_used"),
        "leave_one_out_median_px": finite_or_none((report.get("leave_one_out") or {}).get("median_px")),
        "joint": report.get("intrinsics_refined_jointly"),
        "poses_total": report.get("poses_total"),
        "devices": [
            ("Camera", device_rows(report.get("camera") or {}, (report.get("uncertainty") or {}).get("camera"))),
            (
                "Projector",
                device_rows(report.get("projector") or {}, (report.get("uncertainty") or {}).get("projector")),
            ),
        ],
        "determinacy": determinacy(report),
        "baseline_mm": finite_or_none(report.get("baseline_mm")),
        "rotation_deg": rotation_angle_deg(report.get("R")),
        "T": report.get("T"),
        "coverage": {
            "camera": finite_or_none(coverage.get("camera")),
            "projector": finite_or_none(coverage.get("projector")),
        },
        "grid": coverage.get("grid", 8),
        "tilt_min_deg": finite_or_none(diversity.get("tilt_min_deg")),
        "tilt_max_deg": finite_or_none(diversity.get("tilt_max_deg")),
        "max_angle_deg": finite_or_none(diversity.get("max_angle_between_boards_deg")),
        "median_distance_mm": finite_or_none(report.get("median_board_distance_mm")),
        "gamma": finite_or_none(report.get("gamma_estimate")),
        "warnings": list(report.get("warnings") or []),
        "poses": poses,
    }
