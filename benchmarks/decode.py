"""Decode + triangulate throughput, against baselines timed in the same run.

    .venv/bin/python benchmarks/decode.py            # 1280x1024 and 2048x2048
    .venv/bin/python benchmarks/decode.py --no-opencv --sizes 1280x1024

What is timed (medians over ``--repeats`` interleaved runs in shuffled order, so a
noisy shared machine affects all rows alike, each after flushing the caches):

* ``decode + triangulate vs kept reference``: :func:`~metrology.core.measure.measure` of an 8-bit
  object stack against a :class:`Reference` decoded once (the common case: one
  reference plane, many objects). Decode (Eqs. 1-3) + Eq. 14 + Eq. 17, fused per
  tile, with the mixed-pixel filter and the blur correction turned off.
* ``full pipeline``: the defaults, i.e. also the mixed-pixel filter (code jumps,
  visibility dips, 2-px band, blur-bias bound) and the camera-blur bias correction;
  ``both stacks`` decodes the reference inside the timed call too (and estimates its
  blur); ``no blur-bias bound`` leaves out the filter's crease test
  (``max_blur_bias_codes=0``), the cost of that test by difference.
* ``same, numpy kernel``: the same with the fused path's numpy kernel
  (:func:`~metrology.core.decode.decode_rows` then the model's ``triangulate_rows``), as a ``gcps
  measure`` process runs it; the other rows take the compiled kernel
  (:mod:`metrology.core.decode_kernels`, the same numbers), loaded before timing as a Celery
  worker has it (it imports numba as it starts).
* ``codec self-check (8 row pairs)``: what the fused path adds for the codec self-check
  (:func:`~metrology.core.measure.check_gcps_v1_sample`: the fused kernel's intermediate values
  on 8 pairs of rows, then checked); it is inside the ``decode + triangulate`` rows, this row alone says
  how much of them it is.
* ``memory bound``: ``np.copyto`` of the bytes the job must touch (11 uint8
  images in, one float32 out: 15 bytes per pixel) -- the floor.
* ``OpenCV GrayCodePattern``/``PSP``: OpenCV-contrib's structured_light
  decoders in their own environment (``benchmarks/opencv_env.sh``), timed by
  ``benchmarks/opencv_baseline.py`` on the same frame size; per camera frame.

Peak extra memory: ``tracemalloc`` peak of the object measurement (full pipeline),
inputs and the kept reference excluded, plus the per-thread scratch arrays the
tiles reuse, in bytes per pixel.

glibc is asked to keep freed memory for reuse (:mod:`metrology.core.allocation`),
as the ``gcps`` command and the Celery workers do; ``--release-freed-memory``
measures with its defaults instead, where every fresh frame-sized array is
page-faulted in again (4 ms per 5 MB on the reference VM).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.core import decode_kernels, kernel_choice  # noqa: E402
from metrology.core.allocation import retain_freed_memory  # noqa: E402
from metrology.core.filters import FilterOptions  # noqa: E402
from metrology.core.geometry.crossed_axes import (  # noqa: E402
    Rig,
    camera_ray_point,
    codes_of_points,
)
from metrology.core.measure import MeasureOptions, check_gcps_v1_sample, measure, prepare_reference  # noqa: E402
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity  # noqa: E402
from metrology.core.tiling import scratch_nbytes  # noqa: E402


def synthetic_pair(width: int, height: int, seed: int = 0) -> tuple[Rig, np.ndarray, np.ndarray]:
    """An 8-bit reference/object pair (plane at 40 mm), 1.5 grey levels of noise."""
    rig = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=width, height_px=height)
    rng = np.random.default_rng(seed)
    x_a = rig.column_x_mm()

    def stack(z_mm: float) -> np.ndarray:
        x_h, _ = camera_ray_point(rig, x_a, 0.0, z_mm)
        codes = codes_of_points(rig, x_h, z_mm)
        rows = np.stack([12 + 200 * pattern_intensity(codes, n) for n in PATTERN_NAMES])
        images = np.broadcast_to(rows[:, None, :], (11, height, width)) + rng.normal(0, 1.5, (11, height, width))
        return np.clip(np.round(images), 0, 255).astype(np.uint8)

    return rig, stack(0.0), stack(40.0)


def numpy_kernel(func):
    """``func()`` with the fused path's numpy kernel (``decode_rows``, as a ``gcps measure`` process
    runs it) instead of the compiled one."""
    kernel_choice.COMPILED = False
    try:
        return func()
    finally:
        kernel_choice.COMPILED = None


def median_time(func, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def opencv_baseline(width: int, height: int) -> dict | None:
    env = ROOT / "benchmarks" / "opencv_env.sh"
    try:
        python = subprocess.run(["bash", str(env)], check=True, capture_output=True, text=True).stdout.split()[-1]
        out = subprocess.run(
            [python, str(ROOT / "benchmarks" / "opencv_baseline.py"), "--width", str(width), "--height", str(height)],
            check=True,
            capture_output=True,
            text=True,
            timeout=600,
        ).stdout
        return json.loads(out.strip().splitlines()[-1])
    except (subprocess.SubprocessError, OSError, ValueError, IndexError) as exc:
        print(f"  (OpenCV baseline unavailable: {exc})")
        return None


def run_size(width: int, height: int, repeats: int, with_opencv: bool) -> dict:
    rig, ref_stack, obj_stack = synthetic_pair(width, height)
    mpx = width * height / 1e6
    options = MeasureOptions(gray_only=False)
    reference = prepare_reference(rig, ref_stack, None, options)
    touched = np.empty(15 * width * height, np.uint8)
    touched_out = np.empty_like(touched)

    bare = MeasureOptions(filters=FilterOptions(edge_band_px=0, blur_variance_px2=0.0), gray_only=False)
    # the mixed-pixel filter without its crease test
    no_bound = MeasureOptions(filters=FilterOptions(max_blur_bias_codes=0.0), gray_only=False)
    bare_reference = prepare_reference(rig, ref_stack, None, bare)
    rows = {
        "memory bound (copy 15 B/px)": lambda: np.copyto(touched_out, touched),
        "decode + triangulate vs kept reference": lambda: measure(
            rig, obj_stack, reference=bare_reference, options=bare
        ),
        "  same, numpy kernel": lambda: numpy_kernel(
            lambda: measure(rig, obj_stack, reference=bare_reference, options=bare)
        ),
        "  codec self-check (8 row pairs)": lambda: check_gcps_v1_sample(obj_stack, None, rig.nlp),
        "  same, 1 thread": lambda: measure(rig, obj_stack, reference=bare_reference, options=bare, threads=1),
        "decode + triangulate, both stacks decoded": lambda: measure(rig, obj_stack, reference=ref_stack, options=bare),
        "full pipeline vs kept reference": lambda: measure(rig, obj_stack, reference=reference, options=options),
        "  same, no blur-bias bound": lambda: measure(rig, obj_stack, reference=reference, options=no_bound),
        "full pipeline, both stacks decoded": lambda: measure(rig, obj_stack, reference=ref_stack, options=options),
    }
    for func in rows.values():
        func()  # warm up
    samples: dict[str, list[float]] = {name: [] for name in rows}
    # interleaved in a shuffled order, so background load hits every row alike, and with the
    # caches flushed before each run (a 64 MB copy), so no row inherits another's warm data
    rng = random.Random(0)
    flush_src = np.ones(64 << 20, np.uint8)
    flush_dst = np.empty_like(flush_src)
    names = list(rows)
    for _ in range(repeats):
        rng.shuffle(names)
        for name in names:
            np.copyto(flush_dst, flush_src)
            samples[name].append(median_time(rows[name], 1))
    seconds = {name: statistics.median(values) for name, values in samples.items()}

    tracemalloc.start()
    measure(rig, obj_stack, reference=reference, options=options)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    peak += scratch_nbytes()  # the threads' scratch arrays, allocated in the warm-up, count too

    result = {
        "size": f"{width}x{height}",
        "cpus": os.cpu_count(),
        "seconds": seconds,
        "mpx_per_s": {name: mpx / s for name, s in seconds.items()},
        "peak_extra_bytes_per_px": peak / (width * height),
    }
    floor = seconds["memory bound (copy 15 B/px)"]
    print(f"\n{width}x{height} ({mpx:.2f} Mpx), medians of {repeats} interleaved runs")
    print(f"  {'what':40s} {'ms':>8s} {'Mpx/s':>8s} {'x floor':>8s}")
    for name, s in seconds.items():
        print(f"  {name:40s} {s * 1e3:8.2f} {mpx / s:8.1f} {s / floor:8.1f}")
    print(f"  peak extra memory, object vs kept reference: {result['peak_extra_bytes_per_px']:.1f} bytes/px")
    # issue 22's target: decode + triangulate against a kept reference at most 3x the memory bound
    ratio = seconds["decode + triangulate vs kept reference"] / floor
    result["target_ratio_to_memory_bound"] = ratio
    print(f"  target: decode + triangulate vs kept reference / memory bound = {ratio:.2f} (<= 3)")
    if with_opencv:
        cv = opencv_baseline(width, height)
        if cv:
            result["opencv"] = cv
            ours = result["mpx_per_s"]["decode + triangulate vs kept reference"]
            rates = {
                "GrayCodePattern.decode, per camera frame": cv.get("graycode", {}).get("mpx_per_s_per_camera_frame"),
                "SinusoidalPattern PSP computePhaseMap": cv.get("psp", {}).get("computePhaseMap", {}).get("mpx_per_s"),
            }
            for name, rate in rates.items():
                if rate:
                    print(f"  OpenCV {name:33s} {rate:8.2f} Mpx/s   decode + triangulate / OpenCV = {ours / rate:.0f}x")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="1280x1024,2048x2048")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--no-opencv", action="store_true")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument(
        "--release-freed-memory",
        action="store_true",
        help="leave glibc's defaults (freed frames go back to the kernel and page-fault when reused)",
    )
    args = parser.parse_args()
    # numba imported and the compiled kernel loaded, as in a Celery worker (jobs.handlers.preload_job_code)
    decode_kernels.warm()
    if not args.release_freed_memory:
        print(f"freed memory kept for reuse (metrology.core.allocation): {retain_freed_memory()}")
    results = []
    for size in args.sizes.split(","):
        width, height = (int(v) for v in size.lower().split("x"))
        results.append(run_size(width, height, args.repeats, not args.no_opencv))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
