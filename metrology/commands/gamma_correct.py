"""``gcps gamma-correct``: decoded projector coordinates of a capture already taken, with the
projector's gamma error removed (docs/procam-calibration.md, "Projector gamma").

    gcps gamma-correct --stack DIR_OR_ZIP [--codec C] --gamma G [--blur-px B] --out UV.npy [--rig RIG.json]

Each coded axis whose last unwrapping stage is a sine phase sequence is corrected
(:func:`metrology.core.procam.gamma.correct_coordinate`); ``UV.npy`` is as ``gcps decode``'s.
With ``--rig`` (any model; a pinhole rig gives depths), the summary reports the RMS and largest change of the depth the
correction makes, in micrometres: the periodic height error it removes.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add ``gamma-correct`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("gamma-correct", help="decode a capture and remove the projector gamma's phase error")
    p.add_argument("--stack", required=True, help="capture folder or .zip")
    p.add_argument("--codec", help="codec file or built-in name (default: the capture's codec.json)")
    p.add_argument("--gamma", type=float, required=True, help="projector gamma (e.g. the report's gamma_estimate)")
    p.add_argument("--blur-px", type=float, default=0.0, help="projector blur sigma, projector units (default 0)")
    p.add_argument("--out", required=True, help="(H, W, 2) float32 u, v corrected (.npy)")
    p.add_argument("--rig", help="rig file: report the change of depth (pinhole) or height in micrometres")
    p.set_defaults(func=cmd_gamma_correct)


def cmd_gamma_correct(args: argparse.Namespace) -> dict[str, Any]:
    """Decode, correct, write ``--out`` atomically; returns the summary."""
    import numpy as np

    from metrology.core.codecs import read_codec
    from metrology.core.codecs.decode import decode_codec
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.io import atomic_path
    from metrology.core.procam.gamma import correct_coordinate

    if Path(args.out).suffix.lower() != ".npy":
        raise ValueError(f"--out {args.out}: extension must be .npy")
    if not Path(args.out).resolve().parent.is_dir():
        raise ValueError(f"--out {args.out}: folder does not exist")
    if not (math.isfinite(args.gamma) and 0.2 <= args.gamma <= 5.0):
        raise ValueError(f"--gamma must be within 0.2..5, got {args.gamma}")
    if not (math.isfinite(args.blur_px) and args.blur_px >= 0):
        raise ValueError(f"--blur-px must be >= 0, got {args.blur_px}")
    rig = None
    if args.rig:
        from metrology.core.io import read_model

        rig = read_model(args.rig)  # a GeometryError (a ValueError) names the file and the bad key
    codec = read_codec(args.codec) if args.codec else None
    stack = read_codec_stack(args.stack, codec)
    decoded = decode_codec(stack.images, stack.codec, with_noise=False)
    uv = decoded.uv()
    corrected = uv.copy()
    axes: dict[str, Any] = {}
    for index, name in enumerate(("u", "v")):
        axis = stack.codec.axes.get(name)
        if axis is None or not axis.phase:
            continue
        last = min(axis.phase, key=lambda seq: seq.period)  # the finest stage sets the coordinate
        if last.waveform != "sine":
            axes[name] = {"corrected": False, "why": "square-wave phase (gamma does not move its phase)"}
            continue
        x = correct_coordinate(
            uv[..., index],
            last.period,
            last.origin,
            len(last.frames),
            args.gamma,
            shift=last.shift,
            blur_px=args.blur_px,
        )
        corrected[..., index] = x.astype(np.float32)
        change = (x - uv[..., index])[np.isfinite(x)]
        axes[name] = {
            "corrected": True,
            "period": last.period,
            "steps": len(last.frames),
            "correction_rms": float(np.sqrt(np.mean(change**2))) if change.size else None,
            "correction_max": float(np.abs(change).max()) if change.size else None,
        }
    summary: dict[str, Any] = {"out": args.out, "gamma": args.gamma, "blur_px": args.blur_px, "axes": axes}
    if rig is not None:
        from metrology.core.geometry.base import triangulate_frame

        coded = [n for n in ("u", "v") if n in stack.codec.axes]
        pick = {n: (uv[..., i] if n in coded else None) for i, n in enumerate(("u", "v"))}
        fixed = {n: (corrected[..., i] if n in coded else None) for i, n in enumerate(("u", "v"))}
        prepared = rig.prepare(rig.shape, (stack.codec.projector_width, stack.codec.projector_height))

        def depth(coordinates: dict[str, Any]) -> Any:
            points = triangulate_frame(prepared, coordinates["u"], coordinates["v"], heights=False).points_mm
            assert points is not None
            return points[..., 2]

        before, after = depth(pick), depth(fixed)
        dz = (after - before)[np.isfinite(after) & np.isfinite(before)].astype(np.float64) * 1000.0
        summary["depth_change_um"] = {
            "rms": float(np.sqrt(np.mean(dz**2))) if dz.size else None,
            "max": float(np.abs(dz).max()) if dz.size else None,
        }
    with atomic_path(args.out) as tmp:
        np.save(tmp, corrected)
    return summary
