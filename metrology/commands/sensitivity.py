"""``gcps sensitivity``: the systematic-error curves of Eqs. 22-25 and Fig. 6 of a rig whose model
has the paper's parameters (docs/command-line.md).

::

    gcps sensitivity --rig RIG.json [--param L|d|alpha] [--z-mm Z] --out SENS.json
"""

from __future__ import annotations

import argparse
from typing import Any, Literal

from metrology.commands.common import BadInputError, check_parent, load_model, write_json


def register(subparsers: Any) -> None:
    """Add ``sensitivity`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("sensitivity", help="systematic-error curves of Eqs. 22-25 and Fig. 6")
    p.add_argument("--rig", required=True)
    p.add_argument("--param", choices=["L", "d", "alpha"], help="one parameter (default: all three)")
    p.add_argument("--z-mm", type=float, default=40.0, help="constant height of the study, mm (default 40)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_sensitivity)


def cmd_sensitivity(args: argparse.Namespace) -> dict[str, Any]:
    """The curves of the chosen parameters, written as JSON; the summary."""
    from metrology.core.geometry.crossed_axes import Rig
    from metrology.core.sensitivity import sensitivity_curves
    from metrology.version import software_version

    model = load_model(args.rig)
    if not model.calibration_parameters or not isinstance(model, Rig):
        raise BadInputError(
            f"the sensitivity study needs the paper's L, d and alpha; a {model.short_label} rig has none"
        )
    params: list[Literal["L", "d", "alpha"]] = [args.param] if args.param else ["L", "d", "alpha"]
    curves = {param: sensitivity_curves(model, param, z_mm=args.z_mm) for param in params}
    check_parent(args.out, "--out")
    report = {"rig": model.to_dict(), "z_mm": args.z_mm, "curves": curves, "software_version": software_version()}
    write_json(report, args.out)
    return {"out": args.out, "params": params}
