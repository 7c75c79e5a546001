"""Distorted pinhole rigs (issue 22): the undistortion kernel beside ``cv2.undistortPoints``, and
warm triangulation through a distorted projector beside the same rig without projector
distortion, in the same process.

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/distortion.py [--repeats 7] [--threads N] [--kernels compiled|numpy]

The rig is issue 22's public calibration (1280x1024 camera and 1920x1080 projector, both
strongly distorted); a plane 740 mm away gives the exact projector coordinates of every pixel
(:func:`metrology.core.simulate.cast_truth`, outside the timers). Rows, each a median of
``--repeats`` calls after a warm-up, the cases of a table timed in turn (interleaved) so that the
machine's load falls on all of them alike:

- ``undistort camera frame``: :func:`metrology.core.distortion.undistort_pixels` on the 1.3 M
  pixel centres (1e-6 px) beside ``cv2.undistortPoints`` with criteria (COUNT + EPS, 100, 1e-9)
  on the same points; also the 2.1 M projector pixels with the projector's coefficients;
- ``triangulate u``: ``triangulate_frame`` of u alone, every pixel of the frame counted (valid or
  not), through the distorted projector (epipolar table) and the same rig with the projector's
  distortion set to zero (closed form); ``triangulate u, v``: both axes (undistortion grid);
- ``prepare``: the tables of each rig from scratch (no local cache), once.

The process is warm as a Celery worker is: numba imported and the compiled kernels loaded before
the timers (:func:`metrology.core.compiled.warm_all`; ``--kernels compiled``, the default);
``--kernels numpy`` times the numpy twins instead (:mod:`metrology.core.geometry.pinhole_numpy`,
what a ``gcps measure`` process runs).

Prints one line per row, the ratios, and a JSON line. Timings on a shared machine are noisy:
compare the ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from metrology.core import kernel_choice
from metrology.core.compiled import warm_all
from metrology.core.distortion import Distortion, project_normalized, undistort_pixels
from metrology.core.geometry.base import triangulate_frame
from metrology.core.geometry.pinhole import PinholeProjector, PinholeRig, _camera_tables, _prepare_cached
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, cast_truth

RIG_FILE = Path(__file__).resolve().parents[1] / "examples" / "distorted-pinhole-rig.json"
"""Issue 22's rig (docs/pinhole.md)."""
RIG = PinholeRig.from_json(RIG_FILE.read_text())
CAMERA, PROJECTOR = RIG.camera, RIG.projector
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)


CPU_MEDIANS: dict[str, float] = {}
"""The median CPU seconds (this process, all threads) of the cases of the last :func:`interleaved`."""


def interleaved(cases: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median seconds of each case, the cases called in turn ``repeats`` times after a warm-up;
    their median CPU seconds go to :data:`CPU_MEDIANS` (less sensitive to a loaded machine)."""
    for fn in cases.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in cases}
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    CPU_MEDIANS.clear()
    CPU_MEDIANS.update({name: statistics.median(ts) for name, ts in cpu.items()})
    return {name: statistics.median(ts) for name, ts in times.items()}


def _grid(w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    jj, kk = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return jj, kk


def undistortion_rows(repeats: int) -> dict[str, float]:
    """Our kernel beside cv2.undistortPoints on every pixel of each device; worst residuals."""
    out: dict[str, float] = {}
    for name, K, dist, (w, h) in (
        ("camera", CAMERA.K, CAMERA.dist, (CAMERA.width_px, CAMERA.height_px)),
        ("projector", PROJECTOR.K, PROJECTOR.dist, (int(PROJECTOR.width), int(PROJECTOR.height))),
    ):
        k, d = np.asarray(K), np.asarray(dist)
        jj, kk = _grid(w, h)
        pts = np.stack([jj.ravel(), kk.ravel()], axis=-1).reshape(-1, 1, 2)
        distortion = Distortion.from_coeffs(d)
        med = interleaved(
            {
                "ours": lambda k=k, dist=distortion, jj=jj, kk=kk: undistort_pixels(k, dist, jj, kk),
                "cv2": lambda k=k, d=d, pts=pts: cv2.undistortPoints(pts, k, d, None, None, None, CRITERIA),
            },
            repeats,
        )
        res = undistort_pixels(k, distortion, jj, kk)
        u, v = project_normalized(k, distortion, res.x, res.y)
        ours_err = float(np.hypot(u - jj, v - kk).max())
        ref = cv2.undistortPoints(pts, k, d, None, None, None, CRITERIA).reshape(h, w, 2)
        u, v = project_normalized(k, distortion, ref[..., 0], ref[..., 1])
        cv2_err = float(np.hypot(u - jj, v - kk).max())
        print(
            f"undistort {name} frame {w}x{h}: ours {med['ours'] * 1e3:7.1f} ms (worst {ours_err:.1e} px), "
            f"cv2.undistortPoints {med['cv2'] * 1e3:7.1f} ms (worst {cv2_err:.1e} px): "
            f"ours / cv2 = {med['ours'] / med['cv2']:.2f}",
            flush=True,
        )
        out[f"undistort_{name}_ours_s"] = med["ours"]
        out[f"undistort_{name}_cv2_s"] = med["cv2"]
        out[f"undistort_{name}_ratio"] = med["ours"] / med["cv2"]
    return out


def triangulation_rows(repeats: int, threads: int | None) -> dict[str, float]:
    """Warm triangulation, distorted projector beside the same rig without its distortion."""
    distorted = RIG
    plain = PinholeRig(CAMERA, PinholeProjector(1920, 1080, PROJECTOR.K, ()), RIG.R, RIG.T)
    out: dict[str, float] = {}
    for name, rig in (("distorted", distorted), ("plain", plain)):
        _prepare_cached.cache_clear()
        _camera_tables.cache_clear()
        t0 = time.perf_counter()
        rig.prepare().tables()
        out[f"prepare_{name}_s"] = time.perf_counter() - t0
        print(f"prepare tables, {name} projector: {out[f'prepare_{name}_s'] * 1e3:.0f} ms (no local cache)", flush=True)
    scene, placement = make_scene("plane", z_mm=0.0), ScenePlacement.facing_camera(740.0)
    truth = cast_truth(distorted.prepare(), scene, placement)
    truth0 = cast_truth(plain.prepare(), scene, placement)
    u, v = truth.u.astype(np.float32), truth.v.astype(np.float32)
    u0, v0 = truth0.u.astype(np.float32), truth0.v.astype(np.float32)
    pd, p0 = distorted.prepare(), plain.prepare()
    pd.undistortion_grid()  # as measure() does for a codec of both axes, before the timers
    res = triangulate_frame(pd, u, None, heights=False)
    assert res.points_mm is not None
    err = np.linalg.norm(res.points_mm - truth.points_mm, axis=-1)[truth.lit]
    print(f"distorted projector, u only: {int(truth.lit.sum())} lit pixels, worst error {err.max() * 1e3:.3f} um")
    med = interleaved(
        {
            "u distorted": lambda: triangulate_frame(pd, u, None, heights=False, threads=threads),
            "u plain": lambda: triangulate_frame(p0, u0, None, heights=False, threads=threads),
            "uv distorted": lambda: triangulate_frame(pd, u, v, heights=False, threads=threads),
            "uv plain": lambda: triangulate_frame(p0, u0, v0, heights=False, threads=threads),
        },
        repeats,
    )
    n = CAMERA.width_px * CAMERA.height_px
    for axes in ("u", "uv"):
        a, b = med[f"{axes} distorted"], med[f"{axes} plain"]
        ca, cb = CPU_MEDIANS[f"{axes} distorted"], CPU_MEDIANS[f"{axes} plain"]
        print(
            f"triangulate {axes:2s}: distorted projector {a * 1e3:6.1f} ms ({n / a / 1e6:5.1f} Mpx/s), "
            f"without projector distortion {b * 1e3:6.1f} ms ({n / b / 1e6:5.1f} Mpx/s): ratio {a / b:.2f}; "
            f"CPU time {ca * 1e3:.1f} ms and {cb * 1e3:.1f} ms: ratio {ca / cb:.2f}",
            flush=True,
        )
        out[f"triangulate_{axes}_distorted_s"] = a
        out[f"triangulate_{axes}_plain_s"] = b
        out[f"triangulate_{axes}_ratio"] = a / b
        out[f"triangulate_{axes}_cpu_ratio"] = ca / cb
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--kernels", choices=("compiled", "numpy"), default="compiled")
    args = parser.parse_args()
    if args.kernels == "compiled":  # a warm process, as a worker: numba loaded before any timer
        warm_all()
    else:
        kernel_choice.COMPILED = False
    with tempfile.TemporaryDirectory() as cache:
        os.environ["GCPS_LOCAL_CACHE_DIR"] = cache  # measure the preparation, not a previous run's cache
        rows = undistortion_rows(args.repeats)
        rows.update(triangulation_rows(args.repeats, args.threads))
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
