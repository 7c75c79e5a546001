"""Pinhole triangulation speed at 2048x1536, beside cv2.triangulatePoints, in the same run.

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/pinhole.py [--width 2048 --height 1536 --repeats 5 --threads N]

A rig distorted on both devices (k1 k2 p1 p2 k3 on the camera; projector distorted or not)
looks at a tilted plane; :func:`metrology.core.simulate.cast_truth` gives the exact
projector coordinates (u, v) per camera pixel (set up outside the timers). Rows:

- ``one axis, no projector distortion``: u only, closed form (Mobius map of u per pixel);
- ``one axis, projector distortion``: u only, Newton on each pixel's epipolar line;
- ``both axes, projector distortion``: (u, v) undistorted jointly, then the plane of u;
- ``cv2.triangulatePoints``: the same correspondences, camera pixels and projector
  coordinates both undistorted beforehand (``cv2.undistortPoints``, untimed, a favour to
  OpenCV), then one ``cv2.triangulatePoints`` call on the valid pixels plus the division by
  w: DLT on 2xN float64 arrays.

The fastest call of each row is printed too: on a shared machine it is the better estimate of
the uncontended speed. Every pinhole row includes the per-pixel tables being already prepared (they are computed
once per rig, like the rays); the row ``prepare tables`` times that one-off cost. Medians
of ``--repeats`` calls after one warm-up; Mpx/s = W H / median seconds (all camera pixels,
valid or not). Prints one line per row and a JSON line; timings on a shared machine are noisy:
compare the ratios within one run. The process is warm as a Celery worker is (its compiled kernels
loaded first: :func:`metrology.core.compiled.warm_all`), so the distorted rows run the pinhole
model's compiled kernels.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from metrology.core.compiled import warm_all
from metrology.core.distortion import undistort_pixels
from metrology.core.geometry.base import triangulate_frame
from metrology.core.geometry.pinhole import (
    PinholeCamera,
    PinholeProjector,
    PinholeRig,
    _camera_tables,
    _prepare_cached,
    look_at_rig,
)
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, cast_truth


def _time(fn: Callable[[], object], repeats: int) -> float:
    """Median of ``repeats`` timed calls after a warm-up; the fastest call goes to LAST_BEST."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    LAST_BEST[0] = min(times)
    return median


LAST_BEST = [math.nan]


def _rig(width: int, height: int, projector_dist: tuple[float, ...]) -> PinholeRig:
    f = 1.2 * width
    K = ((f, 0.0, (width - 1) / 2), (0.0, f, (height - 1) / 2), (0.0, 0.0, 1.0))
    camera = PinholeCamera(width, height, K, (-0.1, 0.03, 0.001, -0.0005, 0.0))
    projector = PinholeProjector(
        1280, 800, ((1500.0, 0.0, 640.0), (0.0, 1500.0, 400.0), (0.0, 0.0, 1.0)), projector_dist
    )
    return look_at_rig(camera, projector, (-200.0, 10.0, 15.0), (0.0, 0.0, 700.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--width", type=int, default=2048)
    parser.add_argument("--height", type=int, default=1536)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    warm_all()  # a worker's process: the compiled kernels, as the workers take them
    w, h = args.width, args.height
    rows: dict[str, float] = {}

    best: dict[str, float] = {}

    def report(name: str, seconds: float, timed: bool = True) -> None:
        rows[name] = seconds
        line = f"{name:40s} {seconds * 1e3:9.1f} ms  {w * h / seconds / 1e6:8.1f} Mpx/s"
        if timed:
            best[name] = LAST_BEST[0]
            line += f"   (fastest {LAST_BEST[0] * 1e3:.1f} ms, {w * h / LAST_BEST[0] / 1e6:.1f} Mpx/s)"
        print(line, flush=True)

    plain = _rig(w, h, ())
    distorted = _rig(w, h, (0.06, -0.03, 0.0008, -0.0004, 0.0))
    scene, placement = make_scene("plane", z_mm=0.0), ScenePlacement.facing_camera(700.0)
    truth_plain = cast_truth(plain.prepare(plain.shape, (1280, 800)), scene, placement)
    truth = cast_truth(distorted.prepare(distorted.shape, (1280, 800)), scene, placement)
    u0 = truth_plain.u.astype(np.float32)
    u = truth.u.astype(np.float32)
    v = truth.v.astype(np.float32)

    # the ray casting above prepared both rigs (and cached their tables): time them from scratch
    _prepare_cached.cache_clear()
    _camera_tables.cache_clear()
    t0 = time.perf_counter()
    prep_plain = plain.prepare()
    prep_plain.tables()
    report("prepare tables, no projector distortion", time.perf_counter() - t0, timed=False)
    _camera_tables.cache_clear()
    t0 = time.perf_counter()
    prep = distorted.prepare()
    prep.tables()
    report("prepare tables, projector distortion", time.perf_counter() - t0, timed=False)
    threads = args.threads

    report(
        "one axis, no projector distortion",
        _time(lambda: triangulate_frame(prep_plain, u0, None, heights=False, threads=threads), args.repeats),
    )
    report(
        "one axis, projector distortion",
        _time(lambda: triangulate_frame(prep, u, None, heights=False, threads=threads), args.repeats),
    )
    report(
        "both axes, projector distortion",
        _time(lambda: triangulate_frame(prep, u, v, heights=False, threads=threads), args.repeats),
    )

    # cv2.triangulatePoints on the same correspondences (undistorted beforehand, untimed)
    valid = np.isfinite(u) & np.isfinite(v)
    kk, jj = np.nonzero(valid)
    cam = distorted.camera
    cu = undistort_pixels(np.asarray(cam.K), cam.distortion, jj.astype(np.float64), kk.astype(np.float64))
    pu = undistort_pixels(
        np.asarray(distorted.projector.K), distorted.projector.distortion, u[valid].astype(np.float64), v[valid]
    )
    cam_pts = np.stack([cu.x, cu.y])
    proj_pts = np.stack([pu.x, pu.y])
    P_cam = np.hstack([np.eye(3), np.zeros((3, 1))])
    P_proj = np.hstack([np.asarray(distorted.R), np.asarray(distorted.T)[:, None]])

    def dlt() -> np.ndarray:
        X = cv2.triangulatePoints(P_cam, P_proj, cam_pts, proj_pts)
        return X[:3] / X[3]

    report("cv2.triangulatePoints (undistorted, DLT)", _time(dlt, args.repeats))
    # agreement of the two on the same data
    res = triangulate_frame(prep, u, v, heights=False)
    assert res.points_mm is not None
    gap = float(np.nanmax(np.abs(res.points_mm[valid].T - dlt())))
    print(f"max |pinhole - DLT| = {gap * 1e3:.3f} um over {int(valid.sum())} valid pixels")
    base = rows["cv2.triangulatePoints (undistorted, DLT)"]
    ratios = {name: base / s for name, s in rows.items() if not name.startswith(("cv2", "prepare"))}
    for name, r in ratios.items():
        print(f"{name:40s} {r:6.1f}x cv2.triangulatePoints")
    _prepare_cached.cache_clear()
    print(json.dumps({"width": w, "height": h, "seconds": rows, "fastest_s": best, "speedup_vs_cv2": ratios}))


if __name__ == "__main__":
    main()
