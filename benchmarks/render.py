"""CPU and wall time of the virtual rig's typical renders, each from cold caches (issue 22).

    .venv/bin/python benchmarks/render.py                       # every case, 3 repeats, JSON on stdout
    .venv/bin/python benchmarks/render.py --cases paper16,board --repeats 5
    .venv/bin/python benchmarks/render.py --save /tmp/images.npz  # also keep each case's images

Cases: the paper's crossed-axes rig 640x480 (a sphere: gcps-v1 noise-free 16-bit and realistic
8-bit, and a u+v gcps-codec on it), a distorted pinhole rig 800x600 with a u+v gcps-codec
(realistic 8-bit with 2 and 3 sub-rays, noise-free 16-bit), the procam tests' board pose 0
(``tests/core/procam/virtual_rig.py:rendered_pose(0)``) and a two-camera stereo capture. Every
run clears the renderers' kept tables and noise-free renders first, so each sample is a whole
render. Printed: per case the median of the repeats' process CPU and wall seconds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _clear_caches() -> None:
    from metrology.core.codecs import render as codec_render
    from metrology.core.simulate import paper_rig

    codec_render._TABLES.clear()
    codec_render._CLEAN.clear()
    paper_rig._TABLE_CACHE.clear()


def cases() -> dict[str, Callable[[], np.ndarray]]:
    from metrology.core.geometry.crossed_axes import PAPER_RIG
    from metrology.core.procam.virtual import render_board
    from metrology.core.scenes import make_scene
    from metrology.core.simulate import noise_free_16bit, realistic_8bit, render_capture
    from tests.core.procam import virtual_rig as procam
    from tests.stereo_rig import RIG as STEREO_RIG
    from tests.stereo_rig import codec as stereo_codec

    sphere = make_scene("sphere", radius_mm=60.0)
    pinhole_sphere = make_scene("sphere", radius_mm=40.0)
    uv = procam.make_codec()
    stereo_uv = stereo_codec("uv")

    def capture(model: object, scene: object, codec: object, opts: object) -> Callable[[], np.ndarray]:
        return lambda: render_capture(model, scene, codec, opts).images  # type: ignore[arg-type]

    return {
        "paper16": capture(PAPER_RIG, sphere, None, noise_free_16bit()),
        "paper8": capture(PAPER_RIG, sphere, None, realistic_8bit()),
        "paper_codec8": capture(PAPER_RIG, sphere, uv, realistic_8bit(supersample=1)),
        "pinhole16": capture(procam.RIG, pinhole_sphere, uv, noise_free_16bit()),
        "pinhole8_ss2": capture(procam.RIG, pinhole_sphere, uv, realistic_8bit(supersample=2)),
        "pinhole8_ss3": capture(procam.RIG, pinhole_sphere, uv, realistic_8bit()),
        "board": lambda: render_board(procam.RIG, procam.BOARD, procam.pose(0), uv, procam.OPTIONS, seed=0),
        "stereo8": lambda: _stacks(render_capture(STEREO_RIG, sphere_stereo, stereo_uv, realistic_8bit())),
        "stereo16": lambda: _stacks(render_capture(STEREO_RIG, sphere_stereo, stereo_uv, noise_free_16bit())),
    }


sphere_stereo = None


def _stacks(capture: object) -> np.ndarray:
    """Every camera's stack of a capture, flattened end to end."""
    return np.concatenate([s.reshape(-1) for s in capture.camera_stacks])  # type: ignore[attr-defined]


def main() -> None:
    global sphere_stereo
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--save", default="", help="write each case's images to this .npz")
    args = parser.parse_args()
    from metrology.core.scenes import make_scene

    sphere_stereo = make_scene("sphere", radius_mm=30.0)
    table = cases()
    names = [n for n in args.cases.split(",") if n] or list(table)
    for name in names:  # warm imports and compiled kernels outside the timings
        _clear_caches()
        table[name]()
        break
    results: dict[str, dict[str, float]] = {}
    saved: dict[str, np.ndarray] = {}
    for name in names:
        cpu, wall = [], []
        for _ in range(args.repeats):
            _clear_caches()
            c0, w0 = time.process_time(), time.perf_counter()
            images = table[name]()
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        saved[name] = np.asarray(images)
        results[name] = {"cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall)}
    if args.save:
        np.savez(args.save, **saved)
    print(json.dumps(results))


if __name__ == "__main__":
    main()
