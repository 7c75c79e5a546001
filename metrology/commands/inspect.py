"""``gcps inspect``: a scan against its nominal model: alignment, signed deviations, their
uncertainty and the conformance decision (docs/inspection.md).

::

    gcps inspect --nominal PART.stl|.ply|.obj --scan SCAN.ply|XYZ.npy [--sigma SIGMA.npy]
                 [--init auto|identity|PAIRS.json] [--tolerance MM] [--k K] [--systematic-mm MM]
                 [--seed N] [--features FEATURES.json] --out REPORT.json [--deviations DEV.npy]
                 [--aligned ALIGNED.ply]

The command reads its inputs, calls the pipeline's :func:`~metrology.pipeline.inspect.inspect`
and writes its outputs, each atomically, only once all are computed: a refused run (exit 2,
one line) leaves no file behind.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from metrology.commands.common import BadInputError, check_output, write_json

if TYPE_CHECKING:
    from metrology.core.inspection.scan import Scan


def register(subparsers: Any) -> None:
    """Add ``inspect`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("inspect", help="a scan against its nominal model: alignment, deviations, conformance")
    p.add_argument(
        "--nominal",
        required=True,
        help="nominal triangle mesh in mm (.stl binary or ASCII, .ply, .obj; .step/.stp with cadquery-ocp)",
    )
    p.add_argument(
        "--scan", required=True, help="points: .ply (x y z [sigma_mm]) or (H, W, 3) .npy as gcps measure --xyz writes"
    )
    p.add_argument("--sigma", help="(H, W) sigma along the camera rays, mm (.npy, with an .npy scan)")
    p.add_argument(
        "--init",
        default="auto",
        help="auto (global registration, default), identity, or a JSON file of >= 3 {scan, nominal} point pairs",
    )
    p.add_argument("--tolerance", type=float, metavar="MM", help="allowed |deviation|, mm: conformance decisions")
    p.add_argument("--k", type=float, default=2.0, help="coverage factor of the decisions (default 2)")
    p.add_argument(
        "--systematic-mm",
        type=float,
        default=0.0,
        metavar="MM",
        help="the rig's systematic uncertainty, mm (default 0)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of --init auto (default 0)")
    p.add_argument(
        "--features",
        metavar="FEATURES.json",
        help='features to fit on regions of the aligned scan: a JSON list of {"name", "kind", "region"}',
    )
    p.add_argument("--out", required=True, help="report (.json, gcps-inspection/1)")
    p.add_argument("--deviations", help="float32 signed deviations in the scan's order, NaN where no point (.npy)")
    p.add_argument("--aligned", help="the scan's points in the nominal frame with deviation_mm (.ply)")
    p.set_defaults(func=cmd_inspect)


def cmd_inspect(args: argparse.Namespace) -> dict[str, Any]:
    """Read the nominal and the scan, inspect (the pipeline), write the outputs; the summary."""
    import time

    import numpy as np

    from metrology.core.inspection.feature_regions import FeatureSpec, parse_features
    from metrology.core.inspection.nominal import read_nominal
    from metrology.core.io import atomic_path
    from metrology.core.io.meshes import ply_points_bytes
    from metrology.pipeline.inspect import InspectOptions, Pair, parse_pairs

    check_output(args.out, (".json",), "--out")
    check_output(args.deviations, (".npy",), "--deviations")
    check_output(args.aligned, (".ply",), "--aligned")
    started = time.perf_counter()
    init: str = args.init
    pairs: tuple[Pair, ...] = ()
    if init not in ("auto", "identity"):
        pairs_file = Path(init)
        if pairs_file.suffix.lower() != ".json" or not pairs_file.is_file():
            raise BadInputError(f"--init {init}: must be auto, identity or an existing .json file of point pairs")
        try:
            pairs = tuple(parse_pairs(json.loads(pairs_file.read_text())))
        except (ValueError, UnicodeDecodeError) as exc:
            raise BadInputError(f"--init {init}: {exc}") from None
        if len(pairs) < 3:
            raise BadInputError(f"--init {init}: at least 3 point pairs are needed, got {len(pairs)}")
        init = "pairs"
    features: tuple[FeatureSpec, ...] = ()
    if args.features:
        features_file = Path(args.features)
        if features_file.suffix.lower() != ".json" or not features_file.is_file():
            raise BadInputError(f"--features {args.features}: must be an existing .json file")
        try:
            features = parse_features(json.loads(features_file.read_text()))
        except (ValueError, UnicodeDecodeError) as exc:
            raise BadInputError(f"--features {args.features}: {exc}") from None
    try:
        options = InspectOptions(
            init=init,
            pairs=pairs,
            tolerance_mm=args.tolerance,
            k=args.k,
            systematic_mm=args.systematic_mm,
            seed=args.seed,
            features=features,
        )
    except ValueError as exc:
        raise BadInputError(str(exc)) from None
    try:
        nominal = read_nominal(args.nominal)
    except (ValueError, OSError) as exc:
        raise BadInputError(f"--nominal {args.nominal}: {exc}") from None
    scan = read_scan(args.scan, args.sigma)
    read_s = time.perf_counter() - started
    from metrology.pipeline.inspect import inspect

    try:
        result = inspect(nominal, scan, options)
    except ValueError as exc:
        raise BadInputError(f"--scan {args.scan}: {exc}") from None
    provenance = {
        "nominal": {"file": Path(args.nominal).name, **nominal.summary()},
        "scan": scan.source,
        "rig": None,
        "read_s": read_s,
    }
    report = result.report(provenance)
    if args.deviations:
        with atomic_path(args.deviations) as tmp:
            np.save(tmp, result.deviation_map())
    if args.aligned:
        valid = result.valid
        columns = {axis: result.aligned_mm[valid, i] for i, axis in enumerate("xyz")}
        columns["deviation_mm"] = result.deviation_mm[valid]
        if scan.sigma_mm is not None:
            columns["sigma_mm"] = result.uncertainty_mm[valid]
        data = ply_points_bytes(columns)
        with atomic_path(args.aligned) as tmp:
            tmp.write_bytes(data)
    write_json(report, args.out)
    return {
        "out": args.out,
        "points": report["deviation"]["points"],
        "rms_mm": report["alignment"]["rms_mm"],
        "symmetric_dof": len(report["alignment"]["symmetric_dof"]),
        "conformance": report["conformance"],
        "features": {f["name"]: f["difference"] or f["error"] for f in report.get("features", [])},
        "warnings": list(nominal.warnings),
    }


def read_scan(path: str, sigma_path: str | None) -> Scan:
    """The scan of ``--scan`` (``.ply`` or ``.npy``) and ``--sigma``; BadInputError with one line."""
    import numpy as np

    from metrology.core.inspection.scan import scan_from_ply, scan_from_point_map

    file = Path(path)
    suffix = file.suffix.lower()
    if suffix not in (".ply", ".npy"):
        raise BadInputError(f"--scan {path}: must be a .ply point cloud or an (H, W, 3) .npy point map")
    if not file.is_file():
        raise BadInputError(f"--scan {path}: no such file")
    data = file.read_bytes()
    source: dict[str, Any] = {"file": file.name, "sha256": hashlib.sha256(data).hexdigest(), "format": suffix[1:]}
    try:
        if suffix == ".ply":
            if sigma_path:
                raise BadInputError("--sigma goes with an .npy scan; a PLY scan carries sigma_mm per vertex")
            scan = scan_from_ply(data, source)
        else:
            import io

            points = np.load(io.BytesIO(data), allow_pickle=False)
            sigma = None
            if sigma_path:
                sigma_file = Path(sigma_path)
                if not sigma_file.is_file():
                    raise BadInputError(f"--sigma {sigma_path}: no such file")
                sigma_data = sigma_file.read_bytes()
                sigma = np.load(io.BytesIO(sigma_data), allow_pickle=False)
                source["sigma"] = {"file": sigma_file.name, "sha256": hashlib.sha256(sigma_data).hexdigest()}
            if not isinstance(points, np.ndarray) or points.dtype.kind != "f":
                raise ValueError("the points must be a float array")
            scan = scan_from_point_map(points, sigma, source)
    except ValueError as exc:
        raise BadInputError(f"--scan {path}: {exc}") from None
    if not scan.valid.any():
        raise BadInputError(f"--scan {path}: no points")
    return scan
