"""Stereo speed at 1280x1024: rectify, match and triangulate a pair of decoded maps, beside
``cv2.remap`` of the two maps and ``cv2.triangulatePoints`` of the same matches, in the same run.

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/stereo.py [--repeats 15 --threads N]

The example stereo rig (``examples/stereo-rig.json``: two 1280x1024 cameras, both distorted,
150 mm apart) looks at a tilted plane lit by a projector between the cameras;
:func:`metrology.core.simulate.stereo.render_stereo_capture`'s caster gives each camera's exact
projector coordinate ``u`` per pixel (set up outside the timers). Rows:

- ``stereo: rectify + match + triangulate``: :meth:`PreparedStereo.combine` (both maps sampled on
  their rectified grids, matched along the rows, the disparity sampled back on camera 0's grid)
  then :meth:`PreparedStereo.triangulate_rows` of the whole frame to points (H, W, 3) float32;
  tables prepared beforehand (``prepare tables`` times that one-off cost);
- ``stereo + calibrated projector: fuse 3 pairs``: the same with the rig's projector calibrated (the
  projector that lights the plane): the camera-projector pairs fused with the camera pair
  (:mod:`metrology.core.geometry.stereo_fusion`), without noise maps (equal weights per camera);
- ``stereo 2-D match: match + triangulate`` and ``stereo 2-D + calibrated projector: fuse 3 pairs``:
  the same two with ``match="2d"`` (:class:`PreparedStereo2D`: each camera's ``u`` and ``v``, no
  rectification, the rays' midpoint), without and with the projector's pairs fused;
- ``cv2.remap of the two maps``: ``cv2.remap`` (bilinear, float32 maps) of both decoded maps onto
  the same rectified grids: the part of the work OpenCV does (quantised to 1/32 px, which is why
  the model samples with exact weights instead);
- ``cv2.triangulatePoints``: the matched pixels of the stereo row (camera-0 and camera-1
  rectified positions as rectified pixel coordinates, with the rectified projection matrices)
  triangulated by one call, plus the division by w.

Medians of ``--repeats`` calls after one warm-up (``cv2.triangulatePoints``: one call, it takes
seconds); Mpx/s = W H / median seconds counting every camera-0 pixel. Beside the wall clock, the
median process CPU time per call (all threads): on a shared, loaded machine the better measure of
the work. Prints one line per row, the load average and a JSON line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from metrology.core.geometry import model_from_dict
from metrology.core.geometry.stereo import StereoProjector, StereoRig
from metrology.core.geometry.stereo_match import PreparedStereo, _prepare_cached
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, cast_truth
from metrology.core.simulate.stereo import default_projector

ROOT = Path(__file__).resolve().parents[1]
PREPARE = "prepare tables"
STEREO = "stereo: rectify + match + triangulate"
REMAP = "cv2.remap of the two maps"
TRIANGULATE = "cv2.triangulatePoints"
FUSED = "stereo + calibrated projector: fuse 3 pairs"
MATCH_2D = "stereo 2-D match: match + triangulate"
FUSED_2D = "stereo 2-D + calibrated projector: fuse 3 pairs"


CPU_S: dict[str, float] = {}
"""Median process CPU seconds per call of each row (all threads), beside the wall-clock median."""


def _time(fn: Callable[[], object], repeats: int, name: str, warm: bool = True) -> float:
    """Median wall-clock seconds of ``repeats`` calls (after a warm-up call when ``warm``); the median
    CPU seconds go to :data:`CPU_S` under ``name`` (on a loaded machine the better measure of the work)."""
    if warm:
        fn()
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    CPU_S[name] = statistics.median(cpu)
    return statistics.median(times)


def _maps(rig: StereoRig) -> tuple[list[dict[str, np.ndarray]], StereoRig]:
    """Each camera's exact ``u`` and ``v`` of a plane 400 mm away, tilted by 10 degrees about y, and
    the rig with the projector that lights it calibrated."""
    angle = np.radians(10.0)
    placement = ScenePlacement(
        origin_mm=np.array([0.0, 0.0, 400.0]),
        e_x=np.array([np.cos(angle), 0.0, np.sin(angle)]),
        e_y=np.array([0.0, 1.0, 0.0]),
        e_n=np.array([np.sin(angle), 0.0, -np.cos(angle)]),
    )
    projector = default_projector(rig, placement, 300.0)
    scene = make_scene("plane", z_mm=0.0)
    maps = []
    R, T = np.asarray(rig.R), np.asarray(rig.T)
    for camera, (Rc, Tc) in zip((rig.camera0, rig.camera1), ((np.eye(3), np.zeros(3)), (R, T)), strict=True):
        pinhole = projector.pinhole_rig(camera, Rc, Tc)
        prepared = pinhole.prepare(pinhole.shape, (rig.projector.width, rig.projector.height))
        where = placement.in_frame(Rc, Tc)
        truth = cast_truth(prepared, scene, where)
        assert truth.v is not None
        maps.append({"u": truth.u.astype(np.float32), "v": truth.v.astype(np.float32)})
    lens = projector.projector
    calibrated = StereoProjector(lens.width, lens.height, K=lens.K, dist=lens.dist, R=projector.R, T=projector.T)
    return maps, dataclasses.replace(rig, projector=calibrated)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    rig = model_from_dict(json.loads((ROOT / "examples" / "stereo-rig.json").read_text()))
    assert isinstance(rig, StereoRig)
    maps, calibrated = _maps(rig)
    u0, u1 = maps[0]["u"], maps[1]["u"]
    h, w = rig.shape
    t0 = time.perf_counter()
    prepared = _prepare_cached(rig, "u")
    prepare_s = time.perf_counter() - t0
    assert isinstance(prepared, PreparedStereo)
    points = np.empty((h, w, 3), np.float32)

    def stereo() -> None:
        combined = prepared.combine([{"u": u0}, {"u": u1}], None, args.threads)
        prepared.triangulate_rows(slice(0, h), combined.u, None, points_out=points)

    stereo_s = _time(stereo, args.repeats, STEREO)
    valid = np.isfinite(points[..., 2])

    fusing = _prepare_cached(calibrated, "u")
    fused_points = np.empty((h, w, 3), np.float32)

    def fused() -> None:
        combined = fusing.combine([{"u": u0}, {"u": u1}], None, args.threads)
        fusing.triangulate_rows(slice(0, h), combined.u, None, points_out=fused_points)

    fused_s = _time(fused, max(1, args.repeats // 3), FUSED)
    fused_agree = float(np.nanmax(np.abs(fused_points - points)))

    # the 2-D match, without and with the calibrated projector's pairs
    points_2d = {name: np.empty((h, w, 3), np.float32) for name in (MATCH_2D, FUSED_2D)}
    seconds_2d = {}
    for name, which in ((MATCH_2D, rig), (FUSED_2D, calibrated)):
        prepared_2d = _prepare_cached(which, "u", "2d")

        def match_2d(p: PreparedStereo = prepared_2d, out: np.ndarray = points_2d[name]) -> None:
            combined = p.combine(maps, None, args.threads)
            p.triangulate_rows(slice(0, h), combined.u, None, points_out=out)

        seconds_2d[name] = _time(match_2d, max(1, args.repeats // 3), name)
    agree_2d = {name: float(np.nanmax(np.abs(p - points))) for name, p in points_2d.items()}

    # cv2.remap of the two maps onto the same rectified grids
    rect = prepared.rect
    remap_maps = []
    for sampler in prepared.forward:
        cols = sampler.width
        x = ((sampler.index % cols).astype(np.float32) + sampler.wx).astype(np.float32)
        y = (sampler.index // cols + sampler.wy).astype(np.float32)
        remap_maps.append((x, y))

    def remap() -> None:
        for (x, y), image in zip(remap_maps, (u0, u1), strict=True):
            cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))

    remap_s = _time(remap, args.repeats, REMAP)

    # cv2.triangulatePoints of the same matches (rectified pixel coordinates, rectified P0, P1)
    combined = prepared.combine([{"u": u0}, {"u": u1}])
    d = combined.u
    assert d is not None
    xn, yn = prepared.xn, prepared.yn
    r = rect.R0 @ np.stack([xn.ravel(), yn.ravel(), np.ones(xn.size)])
    x0 = r[0] / r[2] * rect.f
    y0 = r[1] / r[2] * rect.f
    ok = np.isfinite(d.ravel())
    pts0 = np.stack([x0[ok], y0[ok]])
    pts1 = np.stack([x0[ok] + d.ravel()[ok] * rect.f, y0[ok]])
    P0 = np.array([[rect.f, 0, 0, 0], [0, rect.f, 0, 0], [0, 0, 1, 0]], np.float64)
    P1 = P0.copy()
    P1[0, 3] = rect.f * rect.baseline_mm

    def triangulate() -> None:
        X = cv2.triangulatePoints(P0, P1, pts0, pts1)
        _ = X[:3] / X[3]

    tri_s = _time(triangulate, 1, TRIANGULATE, warm=False)  # seconds per call: once is enough
    X = cv2.triangulatePoints(P0, P1, pts0, pts1)
    Xr = (X[:3] / X[3]).T
    ours = points.reshape(-1, 3)[ok].astype(np.float64)
    agree = float(np.abs(Xr @ rect.R0 - ours).max())  # R0^T X_r, row vectors
    mpx = h * w / 1e6
    rows = {PREPARE: prepare_s, STEREO: stereo_s, FUSED: fused_s, **seconds_2d, REMAP: remap_s, TRIANGULATE: tri_s}
    for name, seconds in rows.items():
        cpu = CPU_S.get(name)
        cpu_text = f"  cpu {cpu * 1e3:8.1f} ms" if cpu is not None else ""
        print(f"{name:40s} {seconds * 1e3:8.1f} ms  {mpx / seconds:7.1f} Mpx/s{cpu_text}")
    print(f"matched {valid.mean():.1%} of camera 0's pixels; cv2.triangulatePoints agrees within {agree * 1e3:.4f} um")
    print(f"fused points agree with the camera pair's within {fused_agree * 1e3:.4f} um")
    for name, value in agree_2d.items():
        print(f"{name}: points agree with the epipolar camera pair's within {value * 1e3:.4f} um")
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} cores")
    report = {"size": [w, h], "seconds": rows, "cpu_seconds": CPU_S, "valid_fraction": float(valid.mean())}
    print(
        json.dumps(
            {
                **report,
                "agree_mm": agree,
                "fused_agree_mm": fused_agree,
                "agree_2d_mm": agree_2d,
                "load_average": load,
            }
        )
    )


if __name__ == "__main__":
    main()
