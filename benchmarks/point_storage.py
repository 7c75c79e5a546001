"""Bytes per pixel of a measurement's stored points: the stored point map (points.npz) beside the
float32 depth map and the dense (H, W, 3) float32 points stored before, on realistic virtual captures.

Usage (from the repository root, PYTHONPATH set to it)::

    python benchmarks/point_storage.py [--supersample 3]

Captures (realistic 8-bit renders, :meth:`SimulationOptions.realistic_8bit` with ``--supersample``
sub-rays per pixel and axis, measured with the
pipeline's :func:`~metrology.pipeline.measure.measure` as a job does):

- ``pinhole``: issue 22's pinhole rig (1280x1024 camera, distorted camera and projector) with a
  u-only codec of 12 phase frames and a 6-bit gray code, a sphere 740 mm away, no reference (depths);
- ``pinhole half-empty``: the same capture with the left half of every frame black (nothing lit
  there, as where no object is);
- ``crossed-axes``: the paper's rig, a sphere against its reference plane (its points are the
  heights on the camera rays: the job stores no points, ``points.npz`` is shown for comparison).

Sizes are the bytes of the files the job writes (``numpy.save`` of the depth map,
:func:`metrology.core.io.write_point_map` of the points), divided by the camera's pixels; each
row checks that the point map reads back bit for bit. Prints one line per capture and a JSON line.
"""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from metrology.core.codecs import codec_from_dict
from metrology.core.geometry import model_from_dict
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.io import read_point_map, write_point_map
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, SimulationOptions, render_capture
from metrology.pipeline.measure import measure

RIG_FILE = Path(__file__).resolve().parents[1] / "examples" / "distorted-pinhole-rig.json"
"""Issue 22's rig (docs/pinhole.md)."""

ISSUE_CODEC = {
    "codec": "gcps-codec/1",
    "frames": 20,
    "projector": {"width": 1920, "height": 1080},
    "white": [18],
    "black": [19],
    "axes": {
        "u": {
            "phase": [{"frames": list(range(12)), "period": 60.0, "shift": 1, "origin": 30.0, "waveform": "sine"}],
            "gray": {"frames": list(range(12, 18)), "word": 30.0, "order": "msb_first", "origin": 0.0},
        }
    },
}
"""Issue 22's codec: 12 phase frames (period 60, shift +1, origin 30), a 6-bit gray code of 30-px
words (MSB first, origin 0) on u, then a white and a black frame."""


def npy_size(array: np.ndarray) -> int:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return len(buffer.getvalue())


def row(name: str, z_mm: np.ndarray, points_mm: np.ndarray, stores_points: bool) -> dict[str, Any]:
    """Sizes of one measurement's depth map, stored point map and dense points, bytes and bytes/px."""
    buffer = io.BytesIO()
    write_point_map(buffer, points_mm)
    data = buffer.getvalue()
    back = read_point_map(data)
    assert np.array_equal(back.view(np.uint32), points_mm.view(np.uint32)), "point map not bit-exact"
    pixels = z_mm.size
    depth = npy_size(np.asarray(z_mm, np.float32))
    dense = npy_size(points_mm)
    measured = float(np.isfinite(points_mm).all(axis=-1).mean())
    return {
        "capture": name,
        "shape": list(z_mm.shape),
        "measured_fraction": round(measured, 4),
        "depth_bytes": depth,
        "points_npz_bytes": len(data),
        "dense_points_bytes": dense,
        "depth_B_per_px": round(depth / pixels, 3),
        "points_npz_B_per_px": round(len(data) / pixels, 3),
        "dense_points_B_per_px": round(dense / pixels, 3),
        "points_npz_over_depth": round(len(data) / depth, 3),
        "job_stores_points": stores_points,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--supersample", type=int, default=3, help="sub-rays per pixel and axis of the renders")
    args = parser.parse_args()
    rows = []

    rig = model_from_dict(json.loads(RIG_FILE.read_text()))
    codec = codec_from_dict(ISSUE_CODEC)
    options = SimulationOptions.realistic_8bit(seed=5, supersample=args.supersample)
    capture = render_capture(
        rig, make_scene("sphere", radius_mm=120.0), codec, options, placement=ScenePlacement.facing_camera(740.0)
    )
    result = measure(rig, None, capture.images, codec=codec)
    rows.append(row("pinhole", result.z_mm, result.points_mm(), not result.measurement.points_follow_from_heights))
    half = capture.images.copy()
    half[:, :, : half.shape[2] // 2] = 0
    result = measure(rig, None, half, codec=codec)
    rows.append(
        row("pinhole half-empty", result.z_mm, result.points_mm(), not result.measurement.points_follow_from_heights)
    )

    reference = render_capture(PAPER_RIG, make_scene("reference", PAPER_RIG), None, options)
    obj = render_capture(PAPER_RIG, make_scene("sphere", PAPER_RIG), None, options)
    result = measure(PAPER_RIG, reference.images, obj.images)
    rows.append(row("crossed-axes", result.z_mm, result.points_mm(), not result.measurement.points_follow_from_heights))

    for r in rows:
        print(
            f"{r['capture']:>20} {r['shape'][1]}x{r['shape'][0]}: measured {100 * r['measured_fraction']:.1f} %, "
            f"depth {r['depth_B_per_px']:.3f} B/px, points.npz {r['points_npz_B_per_px']:.3f} B/px "
            f"({r['points_npz_over_depth']:.2f}x the depth map), dense points {r['dense_points_B_per_px']:.3f} B/px; "
            f"job stores points: {r['job_stores_points']}"
        )
    print(json.dumps({"point_storage": rows}))


if __name__ == "__main__":
    main()
