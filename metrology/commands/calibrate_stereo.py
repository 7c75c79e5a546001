"""``gcps calibrate-stereo``: two cameras and their pose calibrated from board poses (docs/stereo-calibration.md).

    gcps calibrate-stereo --board chessboard:9x7:25 --poses P1 P2 ... --projector-size 1920 1080 \\
        --out RIG.json --report REPORT.json

Each pose is a capture folder holding ``cam0/`` and ``cam1/``: in each either a single board image
(PNG, TIFF or BMP), or a codec stack (the codec's frames; ``--codec`` or the capture's top-level
``codec.json``) whose white frames (and long sine phase sequences) are averaged into the board image.
A pose of codec stacks may also be a zip (a capture of several cameras, docs/stereo.md).
``RIG.json`` is a stereo rig file (``X_c1 = R X_c0 + T``), ``REPORT.json`` the explaining report
(``gcps-stereo-calibration-report/1``). ``--projector-size`` defaults to the codec's projector size.
With codec stacks coding both axes, ``--projector`` also calibrates the projector against camera 0
from the decoded coordinates (``X_p = R X_c0 + T`` in the rig's ``projector``).
Exit 2 with one line naming the problem (a missing camera folder, fewer than two poses, a board not
found in a named pose's camera); nothing is written then.
"""

from __future__ import annotations

import argparse
import functools
import time
from pathlib import Path
from typing import Any

from metrology.commands.common import check_output


def register(subparsers: Any) -> None:
    """Add ``calibrate-stereo`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser(
        "calibrate-stereo", help="calibrate two cameras and their pose (stereo rig) from board poses, with a report"
    )
    p.add_argument("--board", required=True, help="chessboard:COLSxROWS:SQUARE_MM, circles:... or acircles:... (mm)")
    p.add_argument(
        "--poses",
        nargs="+",
        required=True,
        metavar="CAPTURE",
        help="capture folders (cam0/, cam1/) or zips of stacks, one per pose",
    )
    p.add_argument("--out", required=True, help="stereo rig file to write (.json)")
    p.add_argument("--report", required=True, help="calibration report to write (.json)")
    p.add_argument(
        "--projector-size",
        type=float,
        nargs=2,
        metavar=("W", "H"),
        help="projector size in the codec's units, written to the rig (default: the codec's)",
    )
    p.add_argument("--codec", help="codec of captures holding stacks (file or built-in name); default codec.json")
    p.add_argument("--fix-k3", action="store_true", help="hold the radial distortion coefficient k3 at 0")
    p.add_argument(
        "--fixed-intrinsics",
        action="store_true",
        help="keep each camera's own intrinsics in the stereo fit (default: refine both jointly with the pose)",
    )
    p.add_argument(
        "--projector",
        action="store_true",
        help="also calibrate the projector against camera 0 (needs codec stacks coding both axes)",
    )
    p.set_defaults(func=cmd_calibrate_stereo)


def _image_files(folder: Path) -> list[Path]:
    from metrology.core.io import IMAGE_EXTENSIONS
    from metrology.core.io.archives import is_junk

    return sorted(
        p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS and not is_junk(p.name)
    )


def _camera_images(folder: Path, codec: Any) -> Any:
    """A camera folder's single image ``(H, W)``, or its codec stack ``(frames, H, W)`` in codec order."""
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.io.images import decode_grey_image

    files = _image_files(folder)
    if len(files) == 1:
        return decode_grey_image(files[0].read_bytes(), str(files[0]))
    return read_codec_stack(folder, codec).images


def _zip_camera_stack(source: str, codec: Any, index: int) -> Any:
    """Camera ``index``'s stack of a zipped pose (the zip is read once per camera)."""
    from metrology.core.codecs.stack import ExposureStack, read_camera_stacks

    stack = read_camera_stacks(source, codec).stacks[index]
    if isinstance(stack, ExposureStack):
        raise ValueError(f"pose {source}: a multi-exposure capture cannot be a calibration pose; give one exposure")
    return stack


def _pose_loaders(source: str, codec: Any) -> tuple[Any, Any, Any]:
    """Loaders of the pose's two cameras' images (a single image each, or codec stacks) and the
    codec of its stacks (None for single images). A folder holds ``cam0/`` and ``cam1/`` with a
    single image or a stack each; a zip holds stacks."""
    from metrology.core.codecs.stack import read_capture_codec
    from metrology.core.stereo_calibration import CAMERAS

    root = Path(source)
    if not root.exists():
        raise ValueError(f"--poses {source}: no such folder or file")
    if root.is_dir():
        folders = []
        counts = []
        for camera in CAMERAS:
            folder = root / camera
            if not folder.is_dir():
                raise ValueError(f"--poses {source}: no {camera}/ folder (a pose holds cam0/ and cam1/)")
            counts.append(len(_image_files(folder)))
            if counts[-1] == 0:
                raise ValueError(f"--poses {source}: {camera}/ holds no image (PNG, TIFF or BMP)")
            folders.append(folder)
        if counts == [1, 1]:
            single = [functools.partial(_camera_images, folder, None) for folder in folders]
            return single[0], single[1], None
    pose_codec = codec if codec is not None else read_capture_codec(root)
    if pose_codec is None:
        raise ValueError(f"--poses {source}: its cameras hold stacks but it has no codec.json; give --codec")
    if root.is_dir():
        loaders = tuple(functools.partial(_camera_images, root / camera, pose_codec) for camera in CAMERAS)
    else:
        loaders = tuple(functools.partial(_zip_camera_stack, source, pose_codec, k) for k in range(len(CAMERAS)))
    return loaders[0], loaders[1], pose_codec


def cmd_calibrate_stereo(args: argparse.Namespace) -> dict[str, Any]:
    """Read both cameras' board images of every pose, calibrate, write ``--out`` and ``--report``
    atomically; returns a summary."""
    from metrology.core.codecs import read_codec
    from metrology.core.io import write_text_atomic
    from metrology.core.procam import parse_board
    from metrology.pipeline.calibrate_procam import report_json_text
    from metrology.pipeline.calibrate_stereo import (
        StereoBoardImages,
        StereoCalibrationOptions,
        calibrate_stereo_images,
    )

    parse_board(args.board)
    check_output(args.out, (".json",), "--out")
    check_output(args.report, (".json",), "--report")
    if Path(args.out).resolve() == Path(args.report).resolve():
        raise ValueError("--out and --report must be different files")
    if len(args.poses) < 2:
        raise ValueError(f"--poses: need at least 2 board poses seen by both cameras, got {len(args.poses)}")
    start = time.perf_counter()
    codec = read_codec(args.codec) if args.codec else None
    names = [Path(p).name or str(p) for p in args.poses]
    if len(set(names)) != len(names):
        names = [str(p) for p in args.poses]
    poses: list[StereoBoardImages] = []
    projector_size = tuple(args.projector_size) if args.projector_size else None
    for name, source in zip(names, args.poses, strict=True):
        camera0, camera1, pose_codec = _pose_loaders(source, codec)
        if projector_size is None and pose_codec is not None:
            projector_size = (float(pose_codec.projector_width), float(pose_codec.projector_height))
        poses.append(
            StereoBoardImages(
                name=name,
                camera0=camera0,
                camera1=camera1,
                codec=pose_codec,
            )
        )
    if projector_size is None:
        raise ValueError("--projector-size W H is required (no codec gives the projector's size)")
    options = StereoCalibrationOptions(
        board=args.board,
        projector_size=(float(projector_size[0]), float(projector_size[1])),
        fix_k3=args.fix_k3,
        joint=not args.fixed_intrinsics,
        projector=args.projector,
    )
    outcome = calibrate_stereo_images(poses, options)
    report = dict(outcome.report)
    report["timings_s"] = {**report["timings_s"], "total": round(time.perf_counter() - start, 3)}
    write_text_atomic(outcome.rig.to_json(), Path(args.out))
    write_text_atomic(report_json_text(report), Path(args.report))
    return {
        "out": args.out,
        "report": args.report,
        "poses_used": report["poses_used"],
        "poses_total": report["poses_total"],
        "camera0_rms_px": report["camera0_rms_px"],
        "camera1_rms_px": report["camera1_rms_px"],
        "stereo_rms_px": report["stereo_rms_px"],
        "baseline_mm": report["baseline_mm"],
        "projector_calibrated": "projector_calibration" in report,
        "warnings": [w["cause"] for w in report["warnings"]],
    }
