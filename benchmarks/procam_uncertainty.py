"""What the poses cannot determine: the focal length's correlation with the boards' distance for
several sets of poses, and the report's standard deviations against Monte Carlo draws and the
leave-one-pose-out spread (docs/procam-calibration.md, "What the poses cannot determine").

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/procam_uncertainty.py [--draws 40]

Poses of the procam tests' distorted rig (tests/core/procam/virtual_rig.py: 9x6 board of 20 mm
squares, 800x600 camera, 1024x768 projector), seen through exact projections plus Gaussian noise
(no rendering). Part 1: each pose set with 0.05 px noise, the joint fit and the intrinsics held,
prints per device the correlation of the focal length (fx or fy, the larger) with the boards'
mean distance, fx's std and its leave-one-pose-out spread, and the warnings. Part 2: ``--draws``
draws of 0.1 px noise on the six poses of tests/core/procam/noisy_corners.py (joint fit): per
intrinsic the median reported std over the draws' spread, the ratio spread/std (median, range),
and the camera's correlation of fx and fy with the mean distance against the draws'. Prints one
line per figure and a JSON line.
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

from metrology.core.procam.calibrate import calibrate_procam  # noqa: E402
from metrology.core.procam.virtual import BoardPose  # noqa: E402
from tests.core.procam.noisy_corners import FACING, board_poses, noisy, observations  # noqa: E402
from tests.core.procam.noisy_corners import POSES as SIX  # noqa: E402
from tests.core.procam.virtual_rig import BOARD, CENTRAL, POSES  # noqa: E402

SHIFTS = [(0, 0), (-60, 40), (60, -40), (50, 50), (-50, -50), (0, 60), (70, 0), (-70, 10)]


def near_facing(max_tilt_deg: float, distances: list[float], seed: int = 0) -> list[BoardPose]:
    """8 boards tilted uniformly within ``max_tilt_deg`` about both axes, turned up to 20 degrees,
    at the given distances (mm) in turn."""
    rng = np.random.default_rng(seed)
    out = []
    for i, (sx, sy) in enumerate(SHIFTS):
        tx, ty = rng.uniform(-max_tilt_deg, max_tilt_deg, 2)
        spin = rng.uniform(-20, 20)
        out.append(BoardPose.from_angles(tx, ty, spin, (sx, sy, distances[i % len(distances)])).centred(BOARD))
    return out


def pose_sets() -> dict[str, list[BoardPose]]:
    return {
        "planned (tilted 20-30 deg, to the edges)": list(POSES),
        "central (tilted up to 25 deg)": list(CENTRAL),
        "noisy_corners' six (tilted up to 25 deg)": board_poses(SIX),
        "tilted within 10 deg, one distance": near_facing(10, [500]),
        "tilted within 5 deg, one distance": near_facing(5, [500]),
        "tilted within 1.5 deg, one distance": near_facing(1.5, [500]),
        "tilted within 1.5 deg, 400/500/600 mm": near_facing(1.5, [400, 500, 600]),
        "FACING (five, within 1.4 deg, 500 mm)": board_poses(FACING),
    }


def part1() -> list[dict[str, Any]]:
    rows = []
    for label, poses in pose_sets().items():
        for joint in (True, False):
            obs = noisy(poses, np.random.default_rng(0), 0.05)
            start = time.perf_counter()
            report = calibrate_procam(obs, BOARD, (800, 600), (1024, 768), fix_k3=True, joint=joint).report
            u = report["uncertainty"]
            row: dict[str, Any] = {"poses": label, "joint": joint, "seconds": round(time.perf_counter() - start, 2)}
            for device in ("camera", "projector"):
                fx = u[device]["intrinsics"]["fx"]
                row[device] = {
                    "corr": u[device]["focal_distance_correlation"],
                    "fx_std": fx["std"],
                    "fx_spread": fx["leave_one_out_std"],
                }
            row["warnings"] = [w["cause"] for w in report["warnings"]]
            rows.append(row)
            c, p = row["camera"], row["projector"]
            print(
                f"{label:42s} {'joint' if joint else 'held '} corr camera {c['corr']:.5f} projector {p['corr']:.5f}"
                f" | camera fx std {c['fx_std']:.3g} spread {c['fx_spread']:.3g} px | {row['warnings']}",
                flush=True,
            )
    return rows


def part2(draws: int) -> dict[str, Any]:
    rng = np.random.default_rng(11)
    table: dict[str, list[tuple[float, float, float | None, float]]] = {}
    distance = []
    for _ in range(draws):
        obs = observations(rng)
        report = calibrate_procam(obs, BOARD, (800, 600), (1024, 768), fix_k3=True).report
        u = report["uncertainty"]
        distance.append(u["camera"]["mean_distance_mm"])
        for device in ("camera", "projector"):
            for name, e in u[device]["intrinsics"].items():
                table.setdefault(f"{device}.{name}", []).append(
                    (e["value"], e["std"], e["leave_one_out_std"], e["distance_correlation"])
                )
    out: dict[str, Any] = {}
    all_ratios = []
    for key, rows in table.items():
        values = np.array([r[0] for r in rows])
        std = np.array([r[1] for r in rows])
        ratio = np.array([(r[2] or np.nan) / r[1] for r in rows])
        all_ratios.extend(ratio[np.isfinite(ratio)])
        spread = float(np.std(values, ddof=1))
        entry = {
            "std_over_draws": float(np.median(std)) / spread,
            "spread_ratio_median": float(np.nanmedian(ratio)),
            "spread_ratio_range": [float(np.nanmin(ratio)), float(np.nanmax(ratio))],
        }
        if key in ("camera.fx", "camera.fy"):
            entry["corr"] = float(np.median([r[3] for r in rows]))
            entry["corr_draws"] = float(np.corrcoef(values, distance)[0, 1])
        out[key] = entry
        lo, hi = entry["spread_ratio_range"]
        line = (
            f"{key:14s} std / draws' spread {entry['std_over_draws']:.2f}; "
            f"left-out spread / std median {entry['spread_ratio_median']:.2f} ({lo:.2f}-{hi:.2f})"
        )
        if "corr" in entry:
            line += f"; corr with mean distance {entry['corr']:.4f}, draws {entry['corr_draws']:.4f}"
        print(line, flush=True)
    r = np.array(all_ratios)
    q = np.quantile(r, [0.005, 0.995])
    for factor in (2.0, 3.0, 4.0):
        share = float(np.mean((r < 1 / factor) | (r > factor)))
        print(f"spread/std outside 1/{factor:g}..{factor:g}: {share:.2%} of {r.size}", flush=True)
    print(f"spread/std 99 % within {q[0]:.2f}..{q[1]:.2f}", flush=True)
    out["ratios_99"] = [float(q[0]), float(q[1])]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=40)
    args = parser.parse_args()
    rows = part1()
    draws = part2(args.draws) if args.draws > 1 else {}
    print(json.dumps({"pose_sets": rows, "draws": draws}))


if __name__ == "__main__":
    main()
