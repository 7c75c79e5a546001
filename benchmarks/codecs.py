"""Codec decoding throughput (issue 11, item 7), against baselines timed in the same run.

    .venv/bin/python benchmarks/codecs.py                 # the four rows + OpenCV-contrib GrayCodePattern
    .venv/bin/python benchmarks/codecs.py --no-opencv --repeats 5

Four 2048x1536 8-bit stacks (camera = 2048x1536, seeing a 1920x1080 projector through a
mild affine map, 1.5 grey levels of noise, rendered by :func:`render_codec`'s pattern model):

* ``24-frame axis``: u only, an 18-step square-wave phase of period 32 px + 6 gray bits of
  32-px words, thresholded at the phase mean;
* ``32-frame two-axis``: the kamino410 layout: per axis 3-step phases at periods 200/3 and
  100 px (heterodyne beat of 200 px) + a gray code of 100-px words with inverse frames
  (5 bits u, 4 bits v), white, black;
* ``42-frame two-axis gray``: OpenCV-style single-pixel gray code with inverses, 11 bits u
  (2048 words) and 10 bits v, white, black.
* ``48-frame axis``: the 24-frame axis with 42 phase steps, for the cost per frame.

``targets`` prints issue 22's ratios from these medians: the 24-frame decode over the copy of
its frames (target <= 4) and the 48-frame row's milliseconds per frame over the 24-frame row's
(target <= 1.5).

Each row is timed as :func:`decode_codec` (all outputs: coordinates, modulation, mean,
noise, reasons: what ``gcps decode --quality`` computes), as ``coordinates only`` (no noise
maps: what ``gcps decode`` without ``--quality`` computes), both with the compiled phase-sum
kernel loaded (:mod:`metrology.core.codecs.kernels`, as in a worker; ``--no-compiled``: without),
as ``decode, OpenCV passes`` (the same decode with the kernel unloaded, what a ``gcps decode``
process runs), and beside them ``memory bound``:
``np.copyto`` of the stack's bytes (the bytes decoding must read at least), in the same
process, interleaved, medians of
``--repeats`` runs. ``OpenCV GrayCodePattern`` decodes the 42-frame stack's layout
(OpenCV's own patterns of a 1920x1080 projector, 2 cameras) with
``benchmarks/opencv_baseline.py`` in its own environment (``benchmarks/opencv_env.sh``).
Prints one JSON object.
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
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.core.allocation import retain_freed_memory  # noqa: E402
from metrology.core.codecs import Codec, codec_from_dict  # noqa: E402
from metrology.core.codecs.decode import KERNELS_MODULE, CodecDecoding, decode_codec  # noqa: E402
from metrology.core.codecs.render import _emitted, frame_roles  # noqa: E402

WIDTH, HEIGHT = 2048, 1536
PROJECTOR = {"width": 1920, "height": 1080}


def codec_24(frames: int = 24) -> Codec:
    """u only: ``frames - 6`` square-wave phase steps of period 32 px, then 6 gray bits of 32-px words."""
    steps = frames - 6
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": frames,
            "projector": PROJECTOR,
            "axes": {
                "u": {
                    "phase": [{"frames": list(range(steps)), "period": 32.0, "waveform": "square", "origin": -0.5}],
                    "gray": {"frames": list(range(steps, frames)), "word": 32.0, "origin": -0.5, "order": "msb_first"},
                }
            },
        }
    )


def codec_48() -> Codec:
    """The 24-frame axis with 42 phase steps: twice the frames, for the per-frame cost."""
    return codec_24(48)


def codec_32() -> Codec:
    def axis(first_phase: int, gray: list[int]) -> dict[str, Any]:
        p = 200 / 3
        return {
            "phase": [
                {"frames": [first_phase, first_phase + 1, first_phase + 2], "period": p, "origin": p / 3},
                {"frames": [first_phase + 3, first_phase + 4, first_phase + 5], "period": 100.0, "origin": 100 / 3},
            ],
            "gray": {"frames": gray[0::2], "inverse_frames": gray[1::2], "word": 100.0, "origin": 0.0},
            "unwrap": ["gray", "beat:0,1", "phase:1", "phase:0"],
        }

    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 32,
            "projector": PROJECTOR,
            "white": [30],
            "black": [31],
            "axes": {"u": axis(0, list(range(12, 22))), "v": axis(6, list(range(22, 30)))},
        }
    )


def codec_42() -> Codec:
    """OpenCV's GrayCodePattern layout for a 1024x768 projector: 10 column bits, then 10 row bits,
    MSB first, each as (pattern, inverse); then white, black."""
    u = list(range(0, 20))
    v = list(range(20, 40))
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 42,
            "projector": {"width": 1024, "height": 768},
            "white": [40],
            "black": [41],
            "axes": {
                "u": {"gray": {"frames": u[0::2], "inverse_frames": u[1::2], "word": 1.0, "origin": -0.5}},
                "v": {"gray": {"frames": v[0::2], "inverse_frames": v[1::2], "word": 1.0, "origin": -0.5}},
            },
        }
    )


def synthetic_stack(codec: Codec, seed: int = 0, noise: float = 1.5) -> np.ndarray:
    """8-bit camera images: u, v an affine map of the camera pixel, separable patterns + noise."""
    rng = np.random.default_rng(seed)
    cols = np.arange(WIDTH, dtype=np.float64)
    rows = np.arange(HEIGHT, dtype=np.float64)
    u = cols * (codec.projector_width / WIDTH) - 0.3
    v = rows * (codec.projector_height / HEIGHT) - 0.3
    images = np.empty((codec.n_frames, HEIGHT, WIDTH), np.uint8)
    for f, role in enumerate(frame_roles(codec)):
        if role.kind in ("phase", "gray"):
            line = _emitted(role, u if role.axis == "u" else v, 0.8, 1.0)
        else:
            line = np.full(WIDTH, 1.0 if role.kind == "white" else 0.0)
        value = 12 + 200 * line
        plane = np.broadcast_to(value[None, :] if role.axis != "v" else value[:, None], (HEIGHT, WIDTH))
        images[f] = np.clip(np.rint(plane + rng.normal(0, noise, (HEIGHT, WIDTH)).astype(np.float32)), 0, 255)
    return images


def interleaved(funcs: dict[str, Callable[[], object]], repeats: int) -> tuple[dict[str, float], dict[str, float]]:
    """Median wall and CPU (all threads of the process) seconds per call, runs interleaved in shuffled order."""
    times: dict[str, list[float]] = {name: [] for name in funcs}
    cpu: dict[str, list[float]] = {name: [] for name in funcs}
    for func in funcs.values():
        func()  # warm-up
    for _ in range(repeats):
        order = list(funcs)
        random.shuffle(order)
        for name in order:
            start, start_cpu = time.perf_counter(), time.process_time()
            funcs[name]()
            times[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    return (
        {name: statistics.median(t) for name, t in times.items()},
        {name: statistics.median(t) for name, t in cpu.items()},
    )


def decode_without_kernel(stack: np.ndarray, codec: Codec, threads: int | None) -> CodecDecoding:
    """:func:`decode_codec` as a process that has not loaded the compiled kernel runs it (the
    decoder uses the kernel only where its module is loaded: unloaded for this call)."""
    kernels = sys.modules.pop(KERNELS_MODULE, None)
    try:
        return decode_codec(stack, codec, threads=threads)
    finally:
        if kernels is not None:
            sys.modules[KERNELS_MODULE] = kernels


def opencv_baselines(repeats: int) -> dict[str, Any] | None:
    """OpenCV-contrib in its own environment: GrayCodePattern on the 42-frame layout, and the
    3-step SinusoidalPattern (PSP) phase map at the same frame size (the 32-frame row's phase part)."""
    try:
        py = subprocess.run(
            ["bash", str(ROOT / "benchmarks" / "opencv_env.sh")], check=True, capture_output=True, text=True
        ).stdout.strip()
        gray = subprocess.run(
            [py, str(ROOT / "benchmarks" / "opencv_graycode_codecs.py"), "--repeats", str(repeats)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        psp = subprocess.run(
            [
                py,
                str(ROOT / "benchmarks" / "opencv_baseline.py"),
                "--width",
                str(WIDTH),
                "--height",
                str(HEIGHT),
                "--skip-graycode",
                "--no-unwrap",
                "--repeats",
                str(repeats),
            ],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        return {"graycode": json.loads(gray.strip().splitlines()[-1]), "psp": json.loads(psp.strip().splitlines()[-1])}
    except (subprocess.CalledProcessError, OSError, json.JSONDecodeError) as exc:
        print(f"OpenCV baseline unavailable: {exc}", file=sys.stderr)
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-opencv", action="store_true")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--rows", default="24,32,42,48", help="which stacks, e.g. 24 or 24,42")
    parser.add_argument("--no-compiled", action="store_true", help="decode without the compiled kernel")
    args = parser.parse_args()
    retain_freed_memory()
    if not args.no_compiled:
        from metrology.core.codecs import kernels

        kernels.warm()
    makers = {
        "24": ("24-frame axis", codec_24),
        "32": ("32-frame two-axis", codec_32),
        "42": ("42-frame two-axis gray", codec_42),
        "48": ("48-frame axis", codec_48),
    }
    result: dict[str, Any] = {
        "size": f"{WIDTH}x{HEIGHT}",
        "threads": args.threads,
        "compiled_kernel": not args.no_compiled,
        "rows": {},
        "loadavg": os.getloadavg(),
    }
    px = WIDTH * HEIGHT
    for key in args.rows.split(","):
        label, make = makers[key]
        codec = make()
        stack = synthetic_stack(codec)
        copy = np.empty_like(stack)
        medians, cpu = interleaved(
            {
                "decode": lambda stack=stack, codec=codec: decode_codec(stack, codec, threads=args.threads),
                "coordinates only": lambda stack=stack, codec=codec: decode_codec(
                    stack, codec, with_noise=False, threads=args.threads
                ),
                "decode, OpenCV passes": lambda stack=stack, codec=codec: decode_without_kernel(
                    stack, codec, args.threads
                ),
                "memory bound": lambda stack=stack, copy=copy: np.copyto(copy, stack),
            },
            args.repeats,
        )
        decoded = decode_codec(stack, codec, threads=args.threads)
        result["rows"][label] = {
            "frames": codec.n_frames,
            "bytes_read": int(stack.nbytes),
            "decode_ms": round(medians["decode"] * 1e3, 2),
            "decode_mpx_s": round(px / medians["decode"] / 1e6, 1),
            "decode_cpu_ms": round(cpu["decode"] * 1e3, 2),
            "coordinates_only_ms": round(medians["coordinates only"] * 1e3, 2),
            "coordinates_only_mpx_s": round(px / medians["coordinates only"] / 1e6, 1),
            "opencv_passes_ms": round(medians["decode, OpenCV passes"] * 1e3, 2),
            "opencv_passes_cpu_ms": round(cpu["decode, OpenCV passes"] * 1e3, 2),
            "opencv_passes_ratio_to_memory_bound": round(medians["decode, OpenCV passes"] / medians["memory bound"], 2),
            "memory_bound_ms": round(medians["memory bound"] * 1e3, 2),
            "memory_bound_cpu_ms": round(cpu["memory bound"] * 1e3, 2),
            # CPU time over the copy's: steadier than the wall ratio when other jobs share the cores
            "cpu_ratio_to_memory_bound": round(cpu["decode"] / cpu["memory bound"], 2),
            "opencv_passes_cpu_ratio_to_memory_bound": round(cpu["decode, OpenCV passes"] / cpu["memory bound"], 2),
            "memory_bound_mpx_s": round(px / medians["memory bound"] / 1e6, 1),
            "ratio_to_memory_bound": round(medians["decode"] / medians["memory bound"], 2),
            "coordinates_only_ratio_to_memory_bound": round(medians["coordinates only"] / medians["memory bound"], 2),
            "decode_ms_per_frame": round(medians["decode"] * 1e3 / codec.n_frames, 3),
            "decoded_fraction": {name: round(float(a.valid.mean()), 4) for name, a in decoded.axes.items()},
        }
    one, two = result["rows"].get("24-frame axis"), result["rows"].get("48-frame axis")
    if one is not None and two is not None:
        # issue 22's targets: a 24-frame codec at most 4x the copy of its frames, 48 frames at most
        # 1.5x the per-frame cost of 24 (both rows' medians from this process)
        result["targets"] = {
            "24-frame decode / copy of its frames (<= 4)": one["ratio_to_memory_bound"],
            "48-frame per-frame cost / 24-frame per-frame cost (<= 1.5)": round(
                two["decode_ms_per_frame"] / one["decode_ms_per_frame"], 3
            ),
            "24-frame decode without the kernel / copy of its frames": one["opencv_passes_ratio_to_memory_bound"],
        }
    if not args.no_opencv:
        baseline = opencv_baselines(max(1, args.repeats // 3))
        if baseline is not None:
            result["opencv"] = baseline
            gray_rate = baseline["graycode"]["graycode_mpx_s_per_camera_frame"]
            row = result["rows"].get("42-frame two-axis gray")
            if row is not None:
                row["opencv_graycode_mpx_s"] = round(gray_rate, 2)
                row["speedup_vs_opencv_graycode"] = round(row["decode_mpx_s"] / gray_rate, 1)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
