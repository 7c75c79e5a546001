"""Projector-camera calibration accuracy: the virtual rig against its truth, and kamino410.

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/procam_accuracy.py [--skip-kamino]

Virtual rig: the eight planned poses of tests/core/procam/test_virtual_calibration.py (same
renders and seeds: a 9x6 chessboard of 20 mm squares, 800x600 camera and 1024x768 projector, both
distorted, realistic 8-bit noise), calibrated with the intrinsics refined jointly (the default)
and held at each device's own fit (``--fixed-intrinsics``). Printed per device: focal length
errors (%), principal point errors (px), the largest difference between the calibrated and true
distortion's point displacements over a 41x31 grid of the whole image (px); then the rotation
error (degrees), the baseline error (%), and the flatness (RMS about a fitted plane, mm) of a
plane measured with the calibrated rig against the true rig (the noise).

kamino410 procam-calibration (five real poses; skipped when the datasets folder, $GCPS_SHARED_DATASETS or
../shared/datasets, is absent):
camera and projector fx, stereo RMS, outlier corners and each pose's left-out prediction (its
projector corners predicted by a calibration of the other four), for both settings.
Runs in about a minute; prints one line per figure and a JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tests.core.procam.test_virtual_calibration as virtual_rig  # noqa: E402
from metrology.core.codecs import read_codec  # noqa: E402
from metrology.core.codecs.decode import decode_codec  # noqa: E402
from metrology.core.codecs.stack import read_codec_stack  # noqa: E402
from metrology.core.procam import calibrate_procam, parse_board  # noqa: E402
from metrology.core.procam.diagnostics import rotation_angle_deg  # noqa: E402
from metrology.core.procam.observe import observe_pose  # noqa: E402
from metrology.core.procam.virtual import BoardPose, render_board  # noqa: E402
from tests.datasets import dataset_path  # noqa: E402

KAMINO = dataset_path("kamino410-procam-calibration", "sample_data")


def virtual(results: dict[str, Any]) -> None:
    start = time.perf_counter()
    observations = [
        observe_pose(
            f"pose{i}",
            render_board(virtual_rig.RIG, virtual_rig.BOARD, p, virtual_rig.CODEC, virtual_rig.OPTIONS, seed=i),
            virtual_rig.CODEC,
            virtual_rig.BOARD,
        )
        for i, p in enumerate(virtual_rig.POSES)
    ]
    print(f"virtual rig: {len(observations)} poses rendered and observed in {time.perf_counter() - start:.1f} s")
    tilted = BoardPose.from_angles(12, -8, 0, (0, 0, 500))
    plane = BoardPose(R=tilted.R, t=tilted.t - tilted.R @ np.array([5000.0, 5000.0, 0.0]))  # no squares: a plane
    decoded = decode_codec(
        render_board(virtual_rig.RIG, virtual_rig.BOARD, plane, virtual_rig.CODEC, virtual_rig.OPTIONS, seed=50),
        virtual_rig.CODEC,
    )
    u, v = decoded.axes["u"].coordinate, decoded.axes["v"].coordinate
    noise = virtual_rig.plane_flatness_mm(virtual_rig.RIG, u, v)
    for joint in (True, False):
        label = "joint" if joint else "fixed-intrinsics"
        result = calibrate_procam(
            virtual_rig.fresh(observations), virtual_rig.BOARD, (800, 600), (1024, 768), fix_k3=True, joint=joint
        )
        rig, report = result.rig, result.report
        row: dict[str, Any] = {}
        for name, got, truth in (
            ("camera", rig.camera, virtual_rig.CAMERA),
            ("projector", rig.projector, virtual_rig.PROJECTOR),
        ):
            K, Kt = np.asarray(got.K), np.asarray(truth.K)
            row[name] = {
                "fx_pct": 100 * (K[0, 0] / Kt[0, 0] - 1),
                "fy_pct": 100 * (K[1, 1] / Kt[1, 1] - 1),
                "pp_px": [K[0, 2] - Kt[0, 2], K[1, 2] - Kt[1, 2]],
                "distortion_px": virtual_rig.distortion_error_px(got, truth),
            }
            print(
                f"  {label:16s} {name:9s} fx {row[name]['fx_pct']:+.4f} %  fy {row[name]['fy_pct']:+.4f} %  "
                f"pp ({row[name]['pp_px'][0]:+.3f}, {row[name]['pp_px'][1]:+.3f}) px  "
                f"distortion over the whole image {row[name]['distortion_px']:.4f} px"
            )
        row["rotation_deg"] = rotation_angle_deg(rig.R, virtual_rig.RIG.R)
        row["baseline_pct"] = 100 * (np.linalg.norm(rig.T) / np.linalg.norm(virtual_rig.RIG.T) - 1)
        row["flatness_mm"], row["noise_mm"] = virtual_rig.plane_flatness_mm(rig, u, v), noise
        row["warnings"] = [w["cause"] for w in report["warnings"]]
        print(
            f"  {label:16s} rotation {row['rotation_deg']:.4f} deg  baseline {row['baseline_pct']:+.4f} %  "
            f"plane flatness {row['flatness_mm']:.5f} mm "
            f"(true rig {noise:.5f}, ratio {row['flatness_mm'] / noise:.3f})  "
            f"warnings {row['warnings']}"
        )
        results[f"virtual_{label}"] = row


def kamino(results: dict[str, Any]) -> None:
    if not (KAMINO / "capture_0").is_dir():
        print(f"kamino410: dataset not found at {KAMINO} (docs/datasets.md says where to get it); skipped")
        return
    codec = read_codec(ROOT / "examples" / "kamino410-procam.codec.json")
    board = parse_board("chessboard:9x7:75")
    observations = [
        observe_pose(f"capture_{k}", read_codec_stack(KAMINO / f"capture_{k}", codec).images, codec, board)
        for k in range(5)
    ]
    for joint in (True, False):
        label = "joint" if joint else "fixed-intrinsics"
        report = calibrate_procam(virtual_rig.fresh(observations), board, (1280, 1024), (1024, 768), joint=joint).report
        loo = report["leave_one_out"]["projector_rms_px"]
        outliers = {p["name"]: sum(1 for c in p["corners"] if c.get("outlier")) for p in report["poses"]}
        row = {
            "camera_fx": report["camera"]["K"][0][0],
            "projector_fx": report["projector"]["K"][0][0],
            "projector_fx_std": report["projector"]["std"]["fx"],
            "stereo_rms_px": report["stereo_rms_px"],
            "outliers": outliers,
            "leave_one_out_px": loo,
            "leave_one_out_median_px": report["leave_one_out"]["median_px"],
        }
        print(
            f"  kamino410 {label:16s} camera fx {row['camera_fx']:.1f}  projector fx {row['projector_fx']:.1f} "
            f"(std {row['projector_fx_std']:.2f})  stereo RMS {row['stereo_rms_px']:.3f} px  outliers {outliers}  "
            f"left-out prediction {[round(x, 2) for x in loo.values()]} px, median {row['leave_one_out_median_px']:.3f}"
        )
        results[f"kamino_{label}"] = row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-kamino", action="store_true", help="only the virtual rig")
    args = parser.parse_args()
    results: dict[str, Any] = {}
    virtual(results)
    if not args.skip_kamino:
        kamino(results)
    print(json.dumps(results, default=float))


if __name__ == "__main__":
    main()
