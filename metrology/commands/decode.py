"""``gcps decode``: absolute projector coordinates of a capture of any codec (docs/codecs.md).

    gcps decode --stack DIR_OR_ZIP [--codec C] --out UV.npy [--quality Q.npz]

``UV.npy``: ``(H, W, 2)`` float32, u and v in projector units, NaN for an axis the codec does not
code or a pixel not decoded. ``Q.npz``: per coded axis a in {u, v}, ``modulation_a`` and
``noise_a`` (float32, grey levels) and ``reason_a`` (uint8: 0 valid, 1 too dark, 2 saturated,
3 outside the projector, 4 gray/phase inconsistent, 5 low inverse contrast, 6 slip repaired
but kept, 7 gray level ambiguous); for a multi-exposure capture (a folder or zip with
``exposures.json``, docs/exposures.md), fused per pixel, also ``exposure_a`` (uint8 index of the
exposure each pixel used, least exposed first; 255 where none), and the JSON summary counts the
pixels per exposure (``exposures``). The codec is ``--codec`` (a file or a built-in name), else the capture's
``codec.json``, else gcps-v1 for a stack of the eleven named patterns. Exit 2 with one line on a
bad codec field or a stack that does not match its codec; nothing is written then.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add ``decode`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("decode", help="projector coordinates (u, v) of a capture of any codec")
    p.add_argument(
        "--stack", required=True, help="capture folder or .zip (may hold codec.json; exposures.json: multi-exposure)"
    )
    p.add_argument("--codec", help="codec file (gcps-codec/1) or built-in name (gcps-v1, gcps-v1:WxH)")
    p.add_argument("--out", required=True, help="(H, W, 2) float32 u, v, NaN where not decoded (.npy)")
    p.add_argument(
        "--quality", help="modulation_a, noise_a, reason_a (and exposure_a: multi-exposure) per coded axis (.npz)"
    )
    group = p.add_argument_group("validity (defaults: docs/codecs.md)")
    group.add_argument("--min-modulation", type=float, metavar="GREY", help="smallest fringe amplitude B, grey levels")
    group.add_argument(
        "--min-inverse-contrast", type=float, metavar="GREY", help="smallest |bit - inverse| of a gray bit, grey levels"
    )
    group.add_argument(
        "--consistency", type=float, metavar="PERIODS", help="allowed distance outside the gray word's cell, periods"
    )
    group.add_argument(
        "--unwrap-consistency",
        type=float,
        metavar="PERIODS",
        help="allowed distance of a phase stage from the coarser phase stage it is unwrapped from, periods",
    )
    group.add_argument(
        "--saturation", type=float, metavar="GREY", help="grey level counted as saturated (default: full scale)"
    )
    group.add_argument("--no-slip-repair", action="store_true", help="do not repair gray-code slips")
    p.set_defaults(func=cmd_decode)


def _check_output(path: str, suffix: str, option: str) -> None:
    if Path(path).suffix.lower() != suffix:
        raise ValueError(f"{option} {path}: extension must be {suffix}")
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise ValueError(f"{option} {path}: folder {parent} does not exist")


def cmd_decode(args: argparse.Namespace) -> dict[str, Any]:
    """Decode ``--stack`` and write ``--out`` (and ``--quality``) atomically; returns the summary."""
    import numpy as np

    from metrology.core.codecs import read_codec
    from metrology.core.codecs.decode import CodecDecodeOptions, decode_codec
    from metrology.core.codecs.exposures import decode_exposures
    from metrology.core.codecs.stack import (
        CodecStack,
        ExposureCodecStack,
        is_exposure_capture,
        read_codec_stack,
        read_exposure_stack,
    )
    from metrology.core.io import atomic_path

    _check_output(args.out, ".npy", "--out")
    if args.quality is not None:
        _check_output(args.quality, ".npz", "--quality")
        if Path(args.quality).resolve() == Path(args.out).resolve():
            raise ValueError("--quality must differ from --out")
    options = CodecDecodeOptions(
        min_modulation=args.min_modulation,
        min_inverse_contrast=args.min_inverse_contrast,
        consistency_periods=args.consistency,
        unwrap_consistency_periods=args.unwrap_consistency,
        saturation_level=args.saturation,
        repair_slips=not args.no_slip_repair,
    )
    codec = read_codec(args.codec) if args.codec else None
    start = time.perf_counter()
    stack: CodecStack | ExposureCodecStack
    if is_exposure_capture(args.stack):
        stack = read_exposure_stack(args.stack, codec)
    else:
        stack = read_codec_stack(args.stack, codec)
    read_s = time.perf_counter() - start
    start = time.perf_counter()
    with_noise = args.quality is not None
    if isinstance(stack, ExposureCodecStack):  # fused per pixel (docs/exposures.md)
        decoded = decode_exposures(stack.stack, stack.codec, options, with_noise=with_noise)
    else:
        decoded = decode_codec(stack.images, stack.codec, options, with_noise=with_noise)
    decode_s = time.perf_counter() - start
    uv = decoded.uv()
    with atomic_path(args.out) as tmp_uv:
        np.save(tmp_uv, uv)
        if args.quality is not None:
            with atomic_path(args.quality) as tmp_q:
                arrays: dict[str, Any] = decoded.quality_arrays()
                np.savez_compressed(tmp_q, **arrays)
    summary = decoded.summary()
    summary.update(
        {
            "out": args.out,
            "quality": args.quality,
            "codec": stack.codec.name or stack.codec_source,
            "frames": stack.codec.n_frames,
            "bit_depth": stack.bit_depth,
            "timings_s": {"read": round(read_s, 3), "decode": round(decode_s, 3)},
        }
    )
    return summary
