"""OpenCV-contrib GrayCodePattern on the 42-frame layout of benchmarks/codecs.py (issue 11, item 7).

Runs in the separate environment of ``benchmarks/opencv_env.sh`` (its contrib ``cv2`` must not
shadow the project's plain build); imports only numpy and cv2; prints ONE JSON line::

    PY=$(bash benchmarks/opencv_env.sh)
    $PY benchmarks/opencv_graycode_codecs.py --repeats 3

A 1024x768 projector (``GrayCodePattern.create(1024, 768)``: 10 column + 10 row bits, each with
its inverse, plus black and white: 42 images) seen by two 2048x1536 8-bit cameras at a
magnification of 2 (each projector pixel covers 2x2 camera pixels), shifted by a few pixels,
levels 30/220 with ambient 10 and 1.5 grey levels of noise. Timed: one call of
``decode([cam0, cam1], blackImages, whiteImages, DECODE_3D_UNDERWORLD)``, which decodes the
column and row gray codes of both cameras (pattern vs inverse, shadow masks from white/black)
and matches them; quoted per camera frame: ``Mpx/s = 2 W H / median_s / 1e6``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import cv2
import numpy as np

WIDTH, HEIGHT = 2048, 1536
PROJ_W, PROJ_H = 1024, 768


def camera(pattern: np.ndarray, dx: int, dy: int, rng: np.random.Generator) -> np.ndarray:
    ys = (np.arange(HEIGHT) - dy) // 2
    xs = (np.arange(WIDTH) - dx) // 2
    inside = (ys[:, None] >= 0) & (ys[:, None] < PROJ_H) & (xs[None, :] >= 0) & (xs[None, :] < PROJ_W)
    proj = pattern[np.clip(ys, 0, PROJ_H - 1)][:, np.clip(xs, 0, PROJ_W - 1)]
    level = np.where(proj > 127, 220.0, 30.0).astype(np.float32)
    level = np.where(inside, level, 10.0).astype(np.float32)
    level += 1.5 * rng.standard_normal(level.shape, dtype=np.float32)
    return np.clip(np.rint(level), 0, 255).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sl = cv2.structured_light
    gc = sl.GrayCodePattern.create(PROJ_W, PROJ_H)
    ok, patterns = gc.generate()
    assert ok
    patterns = [np.asarray(p) for p in patterns]
    black_p = np.zeros((PROJ_H, PROJ_W), np.uint8)
    white_p = np.full((PROJ_H, PROJ_W), 255, np.uint8)
    rng = np.random.default_rng(0)
    cams, blacks, whites = [], [], []
    for dx, dy in ((2, 1), (6, 3)):
        cams.append([camera(p, dx, dy, rng) for p in patterns])
        blacks.append(camera(black_p, dx, dy, rng))
        whites.append(camera(white_p, dx, dy, rng))

    def run() -> None:
        gc.decode(cams, None, blacks, whites, sl.DECODE_3D_UNDERWORLD)

    run()
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    median = statistics.median(times)
    print(
        json.dumps(
            {
                "opencv_version": cv2.__version__,
                "projector": [PROJ_W, PROJ_H],
                "frame": [WIDTH, HEIGHT],
                "images_per_camera": len(patterns) + 2,
                "cameras": 2,
                "graycode_decode_median_s": median,
                "graycode_mpx_s_per_camera_frame": 2 * WIDTH * HEIGHT / median / 1e6,
                "repeats": args.repeats,
            }
        )
    )


if __name__ == "__main__":
    main()
