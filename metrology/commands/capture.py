"""``gcps capture``: acquire one stack locally, without a server (docs/acquisition.md).

``gcps capture --camera BACKEND --out STACK.zip [--codec gcps-v1|FILE.json]`` shows the patterns on
a local projector page (or none, with the virtual camera), grabs each frame, checks it, and
writes the stack with its checks beside it (``STACK.checks.json``). With ``--exposures auto`` or
``--exposures 1,10,100`` it writes a multi-exposure capture (docs/exposures.md) as the agent
uploads it (:func:`~metrology.acquisition.agent.client.acquire_capture`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from metrology.commands import acquisition as shared
from metrology.commands.acquisition import bad


def register(subparsers: Any) -> None:
    """Add ``capture`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("capture", help="acquire one stack locally, without a server")
    shared.add_camera_options(p)
    p.add_argument("--out", required=True, help="the stack, a .zip (checks beside it in .checks.json)")
    p.add_argument("--codec", default="gcps-v1", help="gcps-v1 or gcps-v1:WIDTHxHEIGHT (default gcps-v1, 1024x768)")
    p.add_argument("--role", choices=["reference", "object", "master", "stage"], default="object")
    p.add_argument("--z-in", type=float, help="stage position, mm (role stage; the virtual camera's stage height)")
    p.add_argument("--rig", help="rig JSON (the virtual camera's geometry)")
    p.add_argument("--exposure", type=float, help="exposure, ms (default: auto-exposure from the white frame)")
    shared.add_exposures_options(p, "this capture (instead of --exposure)")
    p.add_argument("--projector", choices=["page", "none"], default="page", help="page: serve the projector page")
    p.add_argument("--port", type=int, default=8765, help="port of the local projector page (default 8765)")
    p.add_argument("--confirm-timeout", type=float, default=60.0, help="seconds to wait for the page to show a pattern")
    p.set_defaults(func=cmd_capture)


def cmd_capture(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.acquisition.agent.cameras import AcquisitionTarget, CameraError
    from metrology.acquisition.agent.client import acquire_capture
    from metrology.acquisition.agent.patterns import resolve_codec
    from metrology.acquisition.agent.sequencer import AcquisitionError, InstantProjector
    from metrology.core.io.atomic import atomic_path, write_text_atomic

    exposures, bracket = shared.exposure_choice(args)
    if exposures is not None and args.exposure is not None:
        raise bad("give --exposure (one exposure) or --exposures (a multi-exposure capture), not both")

    try:
        codec = resolve_codec(args.codec)
    except ValueError as exc:
        raise bad(str(exc)) from None
    out = Path(args.out)
    if out.suffix.lower() != ".zip":
        raise bad(f"--out {args.out}: give a .zip path for the stack")
    if not out.resolve().parent.is_dir():
        raise bad(f"--out {args.out}: folder {out.resolve().parent} does not exist")
    geometry: dict[str, Any] = {}
    if args.rig:
        geometry = json.loads(Path(args.rig).read_text())
    if args.role == "stage" and args.z_in is None:
        raise bad("--z-in is required for --role stage")
    camera = shared.open_camera(args)
    if args.projector == "none" and camera.name.split("+")[0] != "virtual":
        raise bad("--projector none works with the virtual camera only; use --projector page")
    projector: Any
    if args.projector == "page":
        from metrology.acquisition.agent.local_projector import LocalPageProjector

        projector = LocalPageProjector(codec, port=args.port, timeout_s=args.confirm_timeout)
        print(f"projector page: {projector.url} (open it full screen on the projector)", flush=True)
    else:
        projector = InstantProjector()
    try:
        camera.open()
        camera.prepare(AcquisitionTarget(role=args.role, z_in_mm=args.z_in, codec=codec, rig_geometry=geometry))
        result = acquire_capture(
            projector,
            camera,
            codec,
            exposure_ms=args.exposure,
            exposures=exposures,
            bracket=bracket,
            options=shared.sequence_options(args),
        )
    except (AcquisitionError, CameraError) as exc:
        raise bad(str(exc)) from None
    finally:
        camera.close()
        if args.projector == "page":
            projector.close()
    with atomic_path(out) as tmp:
        tmp.write_bytes(result.data)
    checks_path = out.with_suffix(".checks.json")
    checks: dict[str, Any] = {"camera": camera.name, "exposure_ms": result.exposure_ms}
    if result.exposures_ms is not None:
        checks["exposures_ms"] = result.exposures_ms
        checks["bracket"] = result.bracket.to_dict() if result.bracket is not None else None
    checks["frames"] = result.reports
    write_text_atomic(json.dumps(checks, indent=2) + "\n", checks_path)
    summary = {
        "out": str(out),
        "checks": str(checks_path),
        "camera": camera.name,
        "exposure_ms": result.exposure_ms,
        "regrabs": sum(r["regrabs"] for r in result.reports),
    }
    if result.exposures_ms is not None:
        summary["exposures_ms"] = result.exposures_ms
    return summary
