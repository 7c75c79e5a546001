"""``gcps characterize``: linearity and accuracy from a stage series (paper section 5), for a rig
file of any model and captures of any codec (docs/command-line.md).

::

    gcps characterize --rig RIG.json --reference REF --series SERIES.json --out REPORT.json
                      [--codec C] [--points N] [--rows R,R] [--patch P] [--triangulate ...] [decoding options]

Each capture of the series is measured against the reference as a measurement is (the pipeline's
:func:`~metrology.pipeline.characterize.characterize`); captures are read one at a time.
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
    """Add ``characterize`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("characterize", help="linearity and accuracy from a stage series")
    p.add_argument("--rig", required=True, help="rig file of any model")
    p.add_argument("--reference", required=True)
    p.add_argument("--series", required=True, help="SERIES.json listing stage positions and captures")
    p.add_argument("--out", required=True, help="report JSON")
    p.add_argument("--patch", type=int, default=5, help="test-point patch size, px (default 5)")
    p.add_argument("--points", type=int, default=21, help="test points along X (default 21)")
    p.add_argument("--rows", help="rows of the test points, comma-separated (default: middle row)")
    p.add_argument("--codec", help="codec file or built-in name of the captures (default: codec.json, else gcps-v1)")
    add_measure_options(p)
    p.set_defaults(func=cmd_characterize)


def cmd_characterize(args: argparse.Namespace) -> dict[str, Any]:
    """Read the rig, the reference and (streamed) the series; characterize; write the report."""
    from metrology.core.io import read_series
    from metrology.pipeline.characterize import CharacterizeOptions, characterize

    check_parent(args.out, "--out")
    rows = None
    if args.rows:
        try:
            rows = tuple(int(v) for v in args.rows.split(","))
        except ValueError as exc:
            raise BadInputError(f"--rows {args.rows!r}: expected comma-separated row indices") from exc
    options = CharacterizeOptions(**settings_of(args), n_points=args.points, rows=rows, patch_px=args.patch)
    model = load_model(args.rig)
    series = read_series(args.series)
    codec = captures_codec(args.codec, [("reference", args.reference)])
    reference = read_capture(args.reference, codec, model, "reference")

    def stacks() -> Any:  # streamed: a bad capture stops the run before any output is written
        for position in series.positions:
            for repeat, capture in enumerate(position.captures):
                yield position.z_in_mm, repeat, read_capture(str(capture), codec, model, f"series capture {capture}")

    result = characterize(model, reference, stacks(), options, codec=codec)
    report = {**result.to_dict(), "rig": model.to_dict()}
    if codec is not None:
        report["codec"] = codec.to_dict()
    write_json(report, args.out)
    return {"out": args.out, "positions": len(series.positions), **report["overall"]}
