"""``gcps acceptance``: VDI/VDE 2634 part 2 quantities from a capture of a plane, a sphere or a
ball bar, for a rig file of any model and captures of any codec (docs/command-line.md).

::

    gcps acceptance --rig RIG.json [--reference REF] --object OBJ --test flatness|probing|spacing
                    [--diameter D_MM] [--spacing S_MM] [--min-height MM] [--codec C] --out RESULT.json

The capture is measured as a measurement is; the fits run on its points in the model frame.
probing and spacing segment the spheres by their height above the reference plane (``--reference``
required); flatness needs none where the rig's model measures without one.
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
    """Add ``acceptance`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser(
        "acceptance", help="VDI/VDE 2634-2 quantities from a capture of a plane, sphere or ball bar"
    )
    p.add_argument("--rig", required=True, help="rig file of any model")
    p.add_argument("--reference", help="capture of the reference plane (probing and spacing need it)")
    p.add_argument("--object", required=True, help="capture of the plane, the sphere or the two spheres")
    p.add_argument(
        "--test",
        required=True,
        choices=["flatness", "probing", "spacing"],
        help="flatness of a plane; probing error (form, size) of a sphere; spacing of two spheres",
    )
    p.add_argument("--diameter", type=float, help="probing: calibrated sphere diameter, mm")
    p.add_argument("--spacing", type=float, help="spacing: calibrated centre distance, mm")
    p.add_argument(
        "--min-height",
        type=float,
        default=1.0,
        help="probing/spacing: pixels this high above the reference plane belong to the spheres, mm (default 1)",
    )
    p.add_argument("--out", required=True, help="result JSON (with and without the 0.3 %% outlier rejection)")
    p.add_argument("--codec", help="codec file or built-in name of the captures (default: codec.json, else gcps-v1)")
    add_measure_options(p)
    p.set_defaults(func=cmd_acceptance)


def cmd_acceptance(args: argparse.Namespace) -> dict[str, Any]:
    """Read the rig and the captures, measure and fit (the pipeline), write the result."""
    from metrology.pipeline.acceptance import AcceptanceOptions, acceptance

    needs = {"probing": "diameter", "spacing": "spacing"}
    if args.test in needs and getattr(args, needs[args.test]) is None:
        raise BadInputError(f"--test {args.test} needs --{needs[args.test]}")
    check_parent(args.out, "--out")
    options = AcceptanceOptions(
        test=args.test,
        diameter_mm=args.diameter,
        spacing_mm=args.spacing,
        min_height_mm=args.min_height,
        **settings_of(args),
    )
    model = load_model(args.rig)
    if args.reference is None and (model.requires_reference or options.needs_reference):
        why = (
            f"the {args.test} test segments the spheres by height"
            if options.needs_reference
            else (f"a {model.short_label} rig measures against a capture of the reference plane")
        )
        raise BadInputError(f"--reference is required: {why}")
    codec = captures_codec(args.codec, [("reference", args.reference), ("object", args.object)])
    reference = None if args.reference is None else read_capture(args.reference, codec, model, "reference")
    obj = read_capture(args.object, codec, model, "object")
    result = acceptance(model, reference, obj, options, codec=codec)
    report = {**result.to_dict(), "rig": model.to_dict()}
    if codec is not None:
        report["codec"] = codec.to_dict()
    write_json(report, args.out)
    return {"out": args.out, "test": args.test}
