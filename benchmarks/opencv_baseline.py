"""OpenCV structured_light baseline for the GCPS decode benchmark (issue 2, item 7 (b)).

Run it with the separate environment made by ``benchmarks/opencv_env.sh`` (its
opencv-contrib-python-headless ``cv2`` must not shadow the project's plain build)::

    PY=$(bash benchmarks/opencv_env.sh)
    $PY benchmarks/opencv_baseline.py --width 1280 --height 1024 --repeats 5

It prints ONE JSON line on stdout.  It imports only numpy and cv2 (never the
project's ``metrology`` package), so it runs from any working directory.

What is timed (everything else -- pattern generation, building the synthetic
camera images, the Python lists of arrays -- is set up beforehand, outside the
timers):

(a) ``cv2.structured_light.GrayCodePattern``, projector of the same size as the
    camera frame (W x H).  ``generate()`` gives 2*(ceil(log2 W)+ceil(log2 H))
    pattern images (column and row Gray codes, each with its inverse), plus
    ``getImagesForShadowMasks`` black/white.  Two synthetic cameras, each a
    W x H uint8 frame that sees the projector images translated by a few whole
    pixels (camera 0 by (dx0, dy0), camera 1 by (dx1, dy1)); the part of a
    frame outside the projector field is ambient-only (shadow), and the lit
    levels are 30 (dark) / 220 (bright) with ambient 10 and seeded Gaussian
    noise.  Timed: one call of
    ``decode(patternImages=[cam0_list, cam1_list], disparityMap=None,
    blackImages=[b0, b1], whiteImages=[w0, w1],
    flags=cv2.structured_light.DECODE_3D_UNDERWORLD)``, i.e. shadow masks of
    both cameras, per-pixel Gray decode of both cameras (column and row codes,
    pattern vs inverse), grouping of camera pixels by projector pixel, and
    the disparity map.  Throughput is quoted per camera frame:
    ``Mpx/s = 2 * W * H / median_seconds / 1e6`` (two camera frames decoded
    per call).

(b) ``cv2.structured_light.SinusoidalPattern`` with methodId=PSP (three-step
    phase shift, shiftValue 2*pi/3), pattern size = frame size, vertical
    fringes (horizontal=False), no markers.  The camera images are the three
    generated patterns themselves (uint8, frame size).  Timed:
    ``computePhaseMap(patternImages)`` (shadow mask + wrapped phase) and,
    separately, ``unwrapPhaseMap(wrapped, (W, H), shadowMask=mask)``
    (OpenCV's histogram-based spatial unwrapping).  ``Mpx/s = W * H /
    median_seconds / 1e6``.

Each measurement: one untimed warm-up call (``--warmup 0``: none), then up to
``--repeats`` timed calls, stopping early (after at least one) once ``--budget-s`` seconds are
used; the median is reported (min, max, CPU-time median and the number of
calls done too).  ``copy_gbps_*`` and ``loadavg_*`` record the machine state:
on a shared machine other processes slow everything here down.

API notes (opencv-contrib-python-headless 5.0.0.93, cv2 5.0.0):
- the parameters class is ``cv2.structured_light.SinusoidalPattern.Params``
  (also ``cv2.structured_light_SinusoidalPattern_Params``); there is no
  ``cv2.structured_light.SinusoidalPattern_Params``.
- ``GrayCodePattern.decode(patternImages[, disparityMap[, blackImages[,
  whiteImages[, flags]]]]) -> retval, disparityMap``; the disparity is CV_64F
  at camera resolution, here the x offset between the two cameras' pixels
  that decode to the same projector pixel (4 px for the default shifts), 0
  where undecodable.
- ``SinusoidalPattern.generate()`` with PSP gives 3 uint8 images; the fringe
  period is an integer number of pixels (e.g. 2048 px / 20 periods -> 102 px),
  hence ``phase_step_per_px_median`` slightly above the nominal value there.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time

import numpy as np

try:
    import cv2
except ImportError:  # pragma: no cover - environment problem, reported as JSON
    print(json.dumps({"error": "cv2 not importable; run with the python printed by benchmarks/opencv_env.sh"}))
    sys.exit(2)


AMBIENT = 10.0
DARK = 30.0
BRIGHT = 220.0
NOISE_SIGMA = 1.5


WARMUP = 1  # set from --warmup


def _timeit(fn, repeats: int, budget_s: float) -> dict:
    """WARMUP untimed calls, then up to ``repeats`` timed calls; stop early (after at
    least one timed call) once warm-up + timed calls have used ``budget_s`` seconds."""
    t0 = time.perf_counter()
    for _ in range(WARMUP):
        fn()  # warm-up, untimed
    warm = time.perf_counter() - t0
    spent = warm
    times, cpu = [], []
    while len(times) < repeats and (not times or spent < budget_s):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        cpu.append(time.process_time() - c0)
        times.append(dt)
        spent += dt
    return {
        "median_s": statistics.median(times),
        "min_s": min(times),
        "max_s": max(times),
        # CPU seconds of this process (all its threads) per call: a check on wall time
        # when other processes compete for the cores.
        "cpu_median_s": statistics.median(cpu),
        "repeats_requested": repeats,
        "repeats_done": len(times),
        "warmup_calls": WARMUP,
        "warmup_s": warm,
    }


def _copy_gbps(nbytes: int = 15 * 1280 * 1024, reps: int = 30) -> float:
    """Machine-state check: median memory copy bandwidth (read + write bytes / s) of a
    numpy copy of ``nbytes`` (by default the ~15 B/px a GCPS decode touches at 1280x1024)."""
    a = np.ones(nbytes, np.uint8)
    b = np.empty_like(a)
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        np.copyto(b, a)
        ts.append(time.perf_counter() - t0)
    return 2 * nbytes / statistics.median(ts) / 1e9


def _shifted_camera(proj: np.ndarray, dx: int, dy: int, rng: np.random.Generator) -> np.ndarray:
    """Camera frame (same size as ``proj``) seeing the projector image translated by
    (dx, dy): cam[y, x] = proj[y - dy, x - dx]; outside the field only ambient light."""
    h, w = proj.shape
    lit = np.full((h, w), AMBIENT, dtype=np.float32)
    lev = np.where(proj > 127, BRIGHT, DARK).astype(np.float32)
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    lit[yd, xd] = lev[ys, xs]
    lit += NOISE_SIGMA * rng.standard_normal(size=(h, w), dtype=np.float32)
    return np.clip(np.rint(lit), 0, 255).astype(np.uint8)


def bench_graycode(width: int, height: int, repeats: int, budget_s: float, shifts, seed: int) -> dict:
    sl = cv2.structured_light
    gc = sl.GrayCodePattern.create(width, height)
    ok, patterns = gc.generate()
    if not ok:
        return {"error": "GrayCodePattern.generate() returned False"}
    patterns = [np.asarray(p) for p in patterns]
    black_p, white_p = gc.getImagesForShadowMasks(
        np.zeros((height, width), np.uint8), np.zeros((height, width), np.uint8)
    )
    rng = np.random.default_rng(seed)
    cams, blacks, whites = [], [], []
    for dx, dy in shifts:
        cams.append([_shifted_camera(p, dx, dy, rng) for p in patterns])
        blacks.append(_shifted_camera(np.asarray(black_p), dx, dy, rng))
        whites.append(_shifted_camera(np.asarray(white_p), dx, dy, rng))

    result = {}

    def run():
        ok, disp = gc.decode(cams, None, blackImages=blacks, whiteImages=whites, flags=sl.DECODE_3D_UNDERWORLD)
        result["ok"], result["disp"] = ok, disp

    timing = _timeit(run, repeats, budget_s)
    disp = result["disp"]
    npx = width * height
    # Expected pixels decodable in camera 0: inside the projector field in both cameras
    # (a projector pixel must be seen by both cameras to get a disparity).
    (dx0, dy0), (dx1, dy1) = shifts
    common_w = width - (max(dx0, dx1, 0) - min(dx0, dx1, 0))
    common_h = height - (max(dy0, dy1, 0) - min(dy0, dy1, 0))
    nonzero = disp[disp != 0]
    vals, counts = np.unique(np.round(nonzero, 6), return_counts=True)
    top = sorted(zip(counts.tolist(), vals.tolist(), strict=True), reverse=True)[:3]
    t = timing["median_s"]
    return {
        "what": (
            "GrayCodePattern.decode(patternImages=[cam0, cam1], disparityMap=None, "
            "blackImages=[b0, b1], whiteImages=[w0, w1], flags=DECODE_3D_UNDERWORLD): "
            "shadow masks + Gray decode of 2 camera frames + stereo grouping + disparity, "
            "one call"
        ),
        "projector_size": [width, height],
        "camera_frame_size": [width, height],
        "cameras": 2,
        "pattern_images_per_camera": len(patterns),
        "plus_black_white_per_camera": 2,
        "camera_shifts_px_dx_dy": [list(s) for s in shifts],
        "synthetic_levels": {
            "ambient": AMBIENT,
            "dark": DARK,
            "bright": BRIGHT,
            "noise_sigma": NOISE_SIGMA,
            "seed": seed,
        },
        "decode_returned": bool(result["ok"]),
        **timing,
        "mpx_per_s_per_camera_frame": 2 * npx / t / 1e6,
        "mpx_per_s_formula": "2 cameras * W * H / median_s / 1e6",
        "mpx_per_s_per_stereo_pair": npx / t / 1e6,
        "disparity_dtype": str(disp.dtype),
        "disparity_nonzero_fraction": float(np.count_nonzero(disp)) / npx,
        "expected_valid_fraction": common_w * common_h / npx,
        "disparity_most_common_values": [{"value": v, "pixels": c} for c, v in top],
    }


def bench_psp(width: int, height: int, repeats: int, budget_s: float, periods: int, unwrap: bool) -> dict:
    sl = cv2.structured_light
    params = sl.SinusoidalPattern.Params()
    params.width = width
    params.height = height
    params.nbrOfPeriods = periods
    params.shiftValue = float(2 * math.pi / 3)
    params.methodId = sl.PSP
    params.nbrOfPixelsBetweenMarkers = 56
    params.horizontal = False
    params.setMarkers = False
    sp = sl.SinusoidalPattern.create(params)
    ok, patterns = sp.generate()
    if not ok:
        return {"error": "SinusoidalPattern.generate() returned False"}
    imgs = [np.ascontiguousarray(np.asarray(p)) for p in patterns]

    out = {}

    def run_phase():
        out["wrapped"], out["mask"] = sp.computePhaseMap(imgs)

    t_phase = _timeit(run_phase, repeats, budget_s)
    wrapped, mask = out["wrapped"], out["mask"]
    npx = width * height
    res = {
        "what": (
            "SinusoidalPattern(methodId=PSP).computePhaseMap(patternImages) on the 3 "
            "generated uint8 patterns used as camera frames: shadow mask + wrapped phase"
        ),
        "params": {
            "width": width,
            "height": height,
            "nbrOfPeriods": periods,
            "shiftValue": params.shiftValue,
            "methodId": "PSP",
            "nbrOfPixelsBetweenMarkers": params.nbrOfPixelsBetweenMarkers,
            "horizontal": False,
            "setMarkers": False,
        },
        "images": len(imgs),
        "image_dtype": str(imgs[0].dtype),
        "computePhaseMap": {**t_phase, "mpx_per_s": npx / t_phase["median_s"] / 1e6},
        "mpx_per_s_formula": "W * H / median_s / 1e6",
        "wrapped_dtype": str(np.asarray(wrapped).dtype),
        "shadow_mask_nonzero_fraction": float(np.count_nonzero(mask)) / npx,
    }
    # Sanity: the wrapped phase should step by 2*pi*periods/width per pixel along x
    # (up to sign and the 2*pi wraps).
    w = np.asarray(wrapped, dtype=np.float64)
    d = np.angle(np.exp(1j * np.diff(w[height // 2])))
    res["phase_step_per_px_median"] = float(np.median(np.abs(d)))
    res["phase_step_per_px_expected"] = 2 * math.pi * periods / width

    if unwrap:

        def run_unwrap():
            out["unwrapped"] = sp.unwrapPhaseMap(wrapped, (width, height), shadowMask=mask)

        try:
            t_unwrap = _timeit(run_unwrap, repeats, budget_s)
            u = np.asarray(out["unwrapped"], dtype=np.float64)
            row = u[height // 2]
            res["unwrapPhaseMap"] = {
                **t_unwrap,
                "mpx_per_s": npx / t_unwrap["median_s"] / 1e6,
                "what": "unwrapPhaseMap(wrapped, (W, H), shadowMask=mask): histogram-based "
                "spatial unwrapping (phase_unwrapping module)",
                "centre_row_range_rad": float(row.max() - row.min()),
                "centre_row_range_expected_rad": 2 * math.pi * periods * (width - 1) / width,
            }
        except cv2.error as exc:
            res["unwrapPhaseMap"] = {"error": str(exc).strip().splitlines()[-1]}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--psp-repeats", type=int, default=None, help="repeats for the PSP part (default: --repeats)")
    ap.add_argument("--periods", type=int, default=20, help="PSP fringe periods")
    ap.add_argument("--no-unwrap", action="store_true", help="skip timing unwrapPhaseMap")
    ap.add_argument(
        "--budget-s",
        type=float,
        default=20.0,
        help="per measurement: stop repeating (after >= 1 timed call) once warm-up "
        "+ timed calls used this many seconds",
    )
    ap.add_argument("--warmup", type=int, default=1, choices=(0, 1), help="untimed warm-up calls per measurement")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-graycode", action="store_true")
    ap.add_argument("--skip-psp", action="store_true")
    a = ap.parse_args(argv)
    if a.width < 16 or a.height < 16 or a.repeats < 1:
        ap.error("width/height must be >= 16 and repeats >= 1")

    global WARMUP
    WARMUP = a.warmup
    t_start = time.perf_counter()
    out = {
        "opencv_version": cv2.__version__,
        "numpy_version": np.__version__,
        "python": platform.python_version(),
        "cv2_threads": cv2.getNumThreads(),
        "cpu_count": os.cpu_count(),
        "loadavg_at_start": [round(x, 2) for x in os.getloadavg()],
        "copy_gbps_at_start": round(_copy_gbps(), 2),
        "frame": [a.width, a.height],
        "frame_mpx": a.width * a.height / 1e6,
    }
    shifts = [(2, 1), (6, 3)]
    if not a.skip_graycode:
        try:
            out["graycode"] = bench_graycode(a.width, a.height, a.repeats, a.budget_s, shifts, a.seed)
        except cv2.error as exc:
            out["graycode"] = {"error": str(exc).strip().splitlines()[-1]}
    if not a.skip_psp:
        try:
            out["psp"] = bench_psp(
                a.width, a.height, a.psp_repeats or a.repeats, a.budget_s, a.periods, not a.no_unwrap
            )
        except cv2.error as exc:
            out["psp"] = {"error": str(exc).strip().splitlines()[-1]}
    out["loadavg_at_end"] = [round(x, 2) for x in os.getloadavg()]
    out["copy_gbps_at_end"] = round(_copy_gbps(), 2)
    out["wall_s"] = time.perf_counter() - t_start
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
