"""``gcps calibrate``: the paper's L and alpha (and d) of a rig from captures of a master block
(paper section 4; docs/command-line.md).

::

    gcps calibrate --rig RIG.json --reference REF --master MASTER [--master MASTER2 ...]
                   --master-height H_MM [--method paper|lsq] [--roi R0:R1,C0:C1] --out RIG_CALIBRATED.json

The rig's model must have parameters the paper's calibration adjusts (the crossed-axes rig's);
a pinhole rig is calibrated from board poses (``gcps calibrate-procam``).
"""

from __future__ import annotations

import argparse
from typing import Any

from metrology.commands.common import (
    BadInputError,
    add_measure_options,
    captures_codec,
    check_parent,
    load_model,
    read_capture,
    settings_of,
    write_json,
)


def register(subparsers: Any) -> None:
    """Add ``calibrate`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("calibrate", help="calibrate L and alpha on a master block")
    p.add_argument("--rig", required=True, help="rig JSON with the rough starting values")
    p.add_argument("--reference", required=True)
    p.add_argument(
        "--master",
        required=True,
        action="append",
        help="capture stack of the master block (repeatable for --method lsq)",
    )
    p.add_argument("--master-height", type=float, required=True, help="master block height, mm")
    p.add_argument("--method", choices=["paper", "lsq"], default="lsq", help="calibration method (default lsq)")
    p.add_argument("--delta-z", type=float, default=0.025, help="paper: required accuracy, mm (default 0.025)")
    p.add_argument("--m-hat", type=float, default=0.0001, help="paper: slope threshold (default 0.0001)")
    p.add_argument("--max-iterations", type=int, default=None, help="iteration cap")
    p.add_argument("--fit-d", action="store_true", help="lsq: also fit d")
    p.add_argument("--roi", help="top-face region 'row0:row1,col0:col1' (default: found automatically)")
    p.add_argument("--codec", help="codec file or built-in name of the captures (default: codec.json, else gcps-v1)")
    p.add_argument("--out", required=True, help="calibrated rig JSON")
    add_measure_options(p, triangulate=False)
    p.set_defaults(func=cmd_calibrate)


def parse_roi(text: str | None) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """``--roi 'row0:row1,col0:col1'`` as ((row0, row1), (col0, col1)), half-open pixels."""
    if not text:
        return None
    try:
        rows, cols = text.split(",")
        r0, r1 = (int(v) for v in rows.split(":"))
        c0, c1 = (int(v) for v in cols.split(":"))
    except ValueError as exc:
        raise BadInputError(f"--roi {text!r}: expected 'row0:row1,col0:col1'") from exc
    if r1 <= r0 or c1 <= c0 or r0 < 0 or c0 < 0:
        raise BadInputError(f"--roi {text!r}: empty or negative range")
    return (r0, r1), (c0, c1)


def cmd_calibrate(args: argparse.Namespace) -> dict[str, Any]:
    """Read the rig and the captures, calibrate (the pipeline), write the calibrated rig file."""
    from metrology.pipeline.calibrate import CalibrateOptions, calibrate

    if not args.master_height > 0:
        raise BadInputError(f"--master-height must be positive, got {args.master_height}")
    if args.method == "paper" and len(args.master) > 1:
        raise BadInputError("--method paper takes one --master capture")
    check_parent(args.out, "--out")
    settings = settings_of(args)
    options = CalibrateOptions(
        master_height_mm=args.master_height,
        method=args.method,
        filters=settings["filters"],
        gcps_v1=settings["gcps_v1"],
        roi=parse_roi(args.roi),
        fit_d=args.fit_d,
        max_iterations=args.max_iterations or None,
        delta_z_mm=args.delta_z,
        m_hat=args.m_hat,
    )
    model = load_model(args.rig)
    codec = captures_codec(args.codec, [("reference", args.reference), *(("master", m) for m in args.master)])
    reference = read_capture(args.reference, codec, model, "reference")
    masters = [read_capture(path, codec, model, "master") for path in args.master]
    result = calibrate(model, reference, masters, options, codec=codec)
    report = {**result.calibration.to_dict(), "options": options.to_dict(), "software_version": result.software_version}
    write_json({**result.rig.to_dict(), "calibration": report}, args.out)
    return {
        "out": args.out,
        "method": report["method"],
        "iterations": report["iterations"],
        "converged": report["converged"],
        "L_mm": report["L_mm"],
        "alpha_rad": report["alpha_rad"],
    }
