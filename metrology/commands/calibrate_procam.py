"""``gcps calibrate-procam``: camera and projector calibrated from board poses (docs/procam-calibration.md).

    gcps calibrate-procam --codec C --board chessboard:9x7:25 --poses P1 P2 ... --out RIG.json --report REPORT.json
    gcps calibrate-procam --correspondences FILE --board SPEC --out RIG.json --report REPORT.json

Each pose is a capture folder or .zip of the codec (both axes coded). ``RIG.json`` is a pinhole
rig file (docs/pinhole.md), ``REPORT.json`` the explaining report. Exit 2 with one line naming
the problem on bad input (board spec, codec, stacks, fewer than two usable poses); nothing is
written then. A pose whose board is not found or poorly decoded is reported and left out.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add ``calibrate-procam`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser(
        "calibrate-procam", help="calibrate camera and projector (pinhole rig) from board poses, with a report"
    )
    p.add_argument("--board", required=True, help="chessboard:COLSxROWS:SQUARE_MM, circles:... or acircles:... (mm)")
    p.add_argument("--codec", help="codec file (gcps-codec/1) or built-in name; default each capture's codec.json")
    p.add_argument("--poses", nargs="+", metavar="CAPTURE", help="capture folders or .zip files, one per board pose")
    p.add_argument(
        "--correspondences", metavar="FILE", help="camera/projector points per pose (JSON) instead of --poses"
    )
    p.add_argument("--out", required=True, help="pinhole rig file to write (.json)")
    p.add_argument("--report", required=True, help="calibration report to write (.json)")
    p.add_argument("--figures", metavar="DIR", help="write one residual arrow plot per used pose (SVG) into DIR")
    p.add_argument("--save-correspondences", metavar="FILE", help="also write the poses' points (.json)")
    p.add_argument(
        "--window", type=int, metavar="PX", help="half-size of each corner's homography window (default auto)"
    )
    p.add_argument(
        "--min-decoded", type=float, default=0.25, metavar="FRACTION", help="decoded fraction a corner's window needs"
    )
    p.add_argument("--fix-k3", action="store_true", help="hold the radial distortion coefficient k3 at 0")
    p.add_argument(
        "--fixed-intrinsics",
        action="store_true",
        help="keep each device's own intrinsics in the stereo fit (default: refine both jointly with the pose)",
    )
    p.add_argument("--min-modulation", type=float, metavar="GREY", help="decoder: smallest fringe amplitude")
    p.add_argument("--min-inverse-contrast", type=float, metavar="GREY", help="decoder: smallest |bit - inverse|")
    p.set_defaults(func=cmd_calibrate_procam)


def _check_json_out(path: str, option: str) -> Path:
    out = Path(path)
    if out.suffix.lower() != ".json":
        raise ValueError(f"{option} {path}: extension must be .json")
    if not out.resolve().parent.is_dir():
        raise ValueError(f"{option} {path}: folder {out.resolve().parent} does not exist")
    return out.resolve()


def _pose_images(source: str, codec: Any) -> Any:
    """A pose capture's frames in codec order, ``(frames, H, W)`` (read when the pipeline needs them)."""
    from metrology.core.codecs.stack import read_codec_stack

    return read_codec_stack(source, codec).images


def cmd_calibrate_procam(args: argparse.Namespace) -> dict[str, Any]:
    """Observe the poses, calibrate, write ``--out`` and ``--report`` atomically; returns a summary."""
    from metrology.core.codecs import read_codec
    from metrology.core.codecs.stack import read_capture_codec
    from metrology.core.io import write_text_atomic
    from metrology.core.procam import calibrate_procam, parse_board
    from metrology.core.procam.correspondences import correspondences_dict, read_correspondences
    from metrology.pipeline.calibrate_procam import (
        ProcamOptions,
        ProcamPose,
        calibrate_procam_stacks,
        report_json_text,
    )
    from metrology.pipeline.jsonsafe import json_safe
    from metrology.version import software_version

    board = parse_board(args.board)
    outs = {"--out": _check_json_out(args.out, "--out"), "--report": _check_json_out(args.report, "--report")}
    if args.save_correspondences:
        outs["--save-correspondences"] = _check_json_out(args.save_correspondences, "--save-correspondences")
    if len(set(outs.values())) != len(outs):
        raise ValueError(f"{', '.join(outs)} must be different files")
    if not 0.0 <= args.min_decoded <= 1.0:
        raise ValueError(f"--min-decoded must be within 0..1, got {args.min_decoded}")
    if args.figures and not Path(args.figures).is_dir():
        raise ValueError(f"--figures {args.figures}: folder does not exist")
    if args.window is not None and not 1 <= args.window <= 200:
        raise ValueError(f"--window must be 1..200 pixels, got {args.window}")
    if bool(args.poses) == bool(args.correspondences):
        raise ValueError("give either --poses (with --codec or each capture's codec.json) or --correspondences")
    start = time.perf_counter()
    if args.correspondences:
        poses, camera_size, projector_size = read_correspondences(args.correspondences, board)
        result = calibrate_procam(
            poses,
            board,
            camera_size,
            projector_size,
            min_decoded_fraction=args.min_decoded,
            fix_k3=args.fix_k3,
            joint=not args.fixed_intrinsics,
        )
        rig, poses = result.rig, list(result.poses)
        report = dict(result.report)
        report["software_version"] = software_version()
        report["timings_s"] = {"total": round(time.perf_counter() - start, 3)}
    else:
        options = ProcamOptions(
            board=args.board,
            window=args.window,
            min_decoded=args.min_decoded,
            fix_k3=args.fix_k3,
            joint=not args.fixed_intrinsics,
            min_modulation=args.min_modulation,
            min_inverse_contrast=args.min_inverse_contrast,
        )
        codec = read_codec(args.codec) if args.codec else None
        names = [Path(p).name or str(p) for p in args.poses]
        if len(set(names)) != len(names):
            names = [str(p) for p in args.poses]
        # every pose's codec is checked first; its images are read when its turn comes and released
        # after it is observed (one pose in memory at a time); the pipeline names a pose whose size differs
        stacks: list[ProcamPose] = []
        for name, source in zip(names, args.poses, strict=True):
            if not Path(source).exists():
                raise ValueError(f"--poses {source}: no such folder or file")
            pose_codec = codec if codec is not None else read_capture_codec(source)
            if pose_codec is None:
                raise ValueError(f"--poses {source}: no codec.json in the capture; give --codec")
            images = functools.partial(_pose_images, source, pose_codec)
            stacks.append(ProcamPose(name=name, images=images, codec=pose_codec))
        outcome = calibrate_procam_stacks(stacks, options)
        rig, report = outcome.rig, dict(outcome.report)
        poses, camera_size, projector_size = outcome.poses, outcome.camera_size, outcome.projector_size
        report["timings_s"] = {**report["timings_s"], "total": round(time.perf_counter() - start, 3)}
    report_text = report_json_text(report)
    if args.save_correspondences:
        corr = correspondences_dict(poses, camera_size, projector_size)
        write_text_atomic(json.dumps(json_safe(corr), indent=2) + "\n", outs["--save-correspondences"])
    if args.figures:
        from metrology.core.procam.figures import residual_svg

        for pose in report["poses"]:
            if pose["used"]:
                safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in pose["name"])
                write_text_atomic(residual_svg(report, pose["name"]), Path(args.figures) / f"residuals_{safe}.svg")
    write_text_atomic(rig.to_json(), outs["--out"])
    write_text_atomic(report_text, outs["--report"])
    return {
        "out": args.out,
        "report": args.report,
        "poses_used": report["poses_used"],
        "poses_total": report["poses_total"],
        "camera_rms_px": report["camera_rms_px"],
        "projector_rms_px": report["projector_rms_px"],
        "stereo_rms_px": report["stereo_rms_px"],
        "warnings": [w["cause"] for w in report["warnings"]],
    }
