"""``gcps rig import``: write a pinhole or stereo rig file from calibration outputs (see docs/pinhole.md,
docs/stereo-calibration.md).

::

    gcps rig import --out RIG.json --camera-size W H --projector-size W H \\
        --set camera_K=SRC --set camera_dist=SRC --set projector_K=SRC --set projector_dist=SRC \\
        --set R=SRC --set T=SRC            # or --set rvec=SRC instead of R
    gcps rig import --out RIG.json --projector-size W H --opencv calibration.xml
    gcps rig import --out STEREO.json --projector-size W H --opencv stereo.yml   # M1 D1 M2 D2 R T
    gcps rig import --out STEREO.json --camera-size W H --projector-size W H \
        --set camera0_K=SRC --set camera0_dist=SRC --set camera1_K=SRC --set camera1_dist=SRC \
        --set R=SRC --set T=SRC            # camera 1's pose, X_c1 = R X_c0 + T

``SRC`` is a text matrix file, ``FILE.yml#NODE``, ``FILE.xml#NODE``, ``FILE.npz#KEY``,
``FILE.npy`` or ``FILE.json#dotted.key`` (:mod:`metrology.core.rig_import`). ``--set`` wins
over what ``--opencv`` found. A FileStorage file with ``M1 D1 M2 D2``, a pose (``R T`` or
``Rlr Tlr``) and no projector node is a two-camera file and gives a stereo rig; ``--model``
overrides that. Prints a JSON summary naming the model and the source of every value.
"""

from __future__ import annotations

import argparse
from typing import Any

SET_KEYS = (
    "camera_K, camera_dist, projector_K, projector_dist, R, rvec, T; for a stereo rig camera0_K, camera0_dist, "
    "camera1_K, camera1_dist, R, rvec, T and optionally projector_K, projector_dist, projector_R, projector_rvec, "
    "projector_T"
)


def register(subparsers: Any) -> None:
    """Add ``gcps rig`` (with its ``import`` subcommand) to the ``gcps`` parser's subparsers."""
    rig = subparsers.add_parser("rig", help="rig files: import a calibrated pinhole or stereo rig")
    sub = rig.add_subparsers(dest="rig_command", required=True, metavar="ACTION")
    p = sub.add_parser(
        "import",
        help="write a pinhole or stereo rig file from calibration matrices (text, OpenCV YAML/XML, npz, npy, JSON)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, help="rig file to write (.json)")
    p.add_argument("--camera-size", type=int, nargs=2, metavar=("W", "H"), help="camera image size, px")
    p.add_argument(
        "--projector-size",
        type=float,
        nargs=2,
        metavar=("W", "H"),
        required=True,
        help="projector size in projector units (the codec's)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=SRC",
        help=f"one value: KEY one of {SET_KEYS} (repeatable)",
    )
    p.add_argument("--opencv", metavar="FILE", help="OpenCV FileStorage file: values found by their node names")
    p.add_argument(
        "--model",
        choices=("pinhole", "stereo"),
        help="rig model to write (default: recognised from the --opencv file's nodes or the --set keys)",
    )
    p.set_defaults(func=cmd_rig_import)


def cmd_rig_import(args: argparse.Namespace) -> dict[str, Any]:
    """Read every source (:func:`metrology.core.rig_import.import_rig`), write the rig atomically;
    return the summary."""
    from metrology.core.io import atomic_path
    from metrology.core.rig_import import import_rig

    imported = import_rig(
        projector_size=tuple(args.projector_size),
        camera_size=tuple(args.camera_size) if args.camera_size else None,
        opencv=args.opencv,
        sets=list(args.set),
        model=args.model,
    )
    with atomic_path(args.out) as tmp:
        tmp.write_text(imported.rig.to_json(), encoding="utf-8")
    return {"out": args.out, **imported.summary()}
