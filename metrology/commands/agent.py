"""``gcps agent`` and ``gcps capture``: acquire stacks from a real rig (docs/acquisition.md).

``gcps agent --server URL --token TOKEN --rig ID --camera BACKEND`` registers with the application
as the rig's capture agent and runs the acquisitions queued for the rig (dashboard or
``POST /api/rigs/{id}/captures/acquire/``), driving the rig's projector page.
``gcps capture --camera BACKEND --out DIR`` acquires one stack locally, without a server.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where used, so that gcps starts without them
    from metrology.acquisition.agent.cameras import Camera
    from metrology.acquisition.agent.sequencer import SequenceOptions


def _bad(message: str) -> Exception:
    """A user error: ``gcps`` prints it as one line and exits with status 2 (ValueError, so that
    ``python -m metrology.cli`` catches it too)."""
    return ValueError(message)


def _json_option(value: str | None, option: str) -> dict[str, Any] | None:
    if value is None:
        return None
    try:
        data = json.loads(value)
    except ValueError:
        raise _bad(f"{option} must be a JSON object, got {value!r}") from None
    if not isinstance(data, dict):
        raise _bad(f"{option} must be a JSON object, got {value!r}")
    return data


def _faults(value: str | None) -> tuple[int, int]:
    """``latency=N,saturate=M``: every N-th / M-th grab faulty (testing aid)."""
    if not value:
        return 0, 0
    counts = {"latency": 0, "saturate": 0}
    for item in value.split(","):
        key, _, number = item.partition("=")
        if key.strip() not in counts or not number.strip().isdigit():
            raise _bad(f"--inject-faults expects latency=N,saturate=M, got {value!r}")
        counts[key.strip()] = int(number)
    return counts["latency"], counts["saturate"]


def _camera(args: argparse.Namespace) -> Camera:
    from metrology.acquisition.agent.cameras import FaultyCamera, make_camera

    try:
        camera = make_camera(
            args.camera,
            scene=_json_option(args.scene, "--scene"),
            options=_json_option(args.sim_options, "--sim-options"),
        )
    except ValueError as exc:
        raise _bad(str(exc)) from None
    latency, saturate = _faults(args.inject_faults)
    if latency or saturate:
        camera = FaultyCamera(camera, latency_every=latency, saturate_every=saturate)
    return camera


def _sequence_options(args: argparse.Namespace) -> SequenceOptions:
    from metrology.acquisition.agent.sequencer import SequenceOptions

    try:
        return SequenceOptions(settle_s=args.settle, max_grabs=args.max_grabs)
    except ValueError as exc:
        raise _bad(str(exc)) from None


def _add_camera_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--camera",
        required=True,
        help="opencv:DEVICE (index, /dev/videoN or a video file), genicam:PRODUCER.cti, virtual",
    )
    p.add_argument("--settle", type=float, default=0.1, help="wait after each confirmed pattern, s (default 0.1)")
    p.add_argument("--max-grabs", type=int, default=4, help="grabs per pattern before giving up (default 4)")
    p.add_argument("--scene", help='virtual camera: the object scene, JSON, e.g. \'{"name": "sphere"}\'')
    p.add_argument("--sim-options", help="virtual camera: simulation options, JSON, e.g. '{\"bit_depth\": 8}'")
    p.add_argument(
        "--inject-faults", metavar="latency=N,saturate=M", help="testing: every N-th grab late, M-th saturated"
    )


def cmd_agent(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.acquisition.agent.cameras import CameraError
    from metrology.acquisition.agent.client import AgentClient, AgentOptions, ProtocolError, run_agent
    from metrology.version import software_version

    if not args.server.startswith(("http://", "https://")):
        raise _bad(f"--server must be an http:// or https:// URL, got {args.server!r}")
    camera = _camera(args)
    client = AgentClient(args.server, args.token, args.rig)
    options = AgentOptions(
        sequence=_sequence_options(args),
        poll_s=args.poll,
        max_acquisitions=args.max_acquisitions,
        confirm_timeout_s=args.confirm_timeout,
    )
    try:
        return run_agent(client, camera, options, software_version())
    except ProtocolError as exc:
        raise _bad(f"agent refused: {exc}") from None
    except CameraError as exc:
        raise _bad(str(exc)) from None


def cmd_capture(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.acquisition.agent.cameras import AcquisitionTarget, CameraError
    from metrology.acquisition.agent.client import stack_zip
    from metrology.acquisition.agent.patterns import resolve_codec
    from metrology.acquisition.agent.sequencer import AcquisitionError, InstantProjector, run_sequence
    from metrology.core.io.atomic import atomic_path, write_text_atomic

    try:
        codec = resolve_codec(args.codec)
    except ValueError as exc:
        raise _bad(str(exc)) from None
    out = Path(args.out)
    if out.suffix.lower() != ".zip":
        raise _bad(f"--out {args.out}: give a .zip path for the stack")
    if not out.resolve().parent.is_dir():
        raise _bad(f"--out {args.out}: folder {out.resolve().parent} does not exist")
    geometry: dict[str, Any] = {}
    if args.rig:
        geometry = json.loads(Path(args.rig).read_text())
    if args.role == "stage" and args.z_in is None:
        raise _bad("--z-in is required for --role stage")
    camera = _camera(args)
    if args.projector == "none" and camera.name.split("+")[0] != "virtual":
        raise _bad("--projector none works with the virtual camera only; use --projector page")
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
        result = run_sequence(projector, camera, codec, exposure_ms=args.exposure, options=_sequence_options(args))
    except (AcquisitionError, CameraError) as exc:
        raise _bad(str(exc)) from None
    finally:
        camera.close()
        if args.projector == "page":
            projector.close()
    reports = result.frame_reports()
    data = stack_zip(result.images, codec)
    with atomic_path(out) as tmp:
        tmp.write_bytes(data)
    checks_path = out.with_suffix(".checks.json")
    checks = {"camera": camera.name, "exposure_ms": result.exposure_ms, "frames": reports}
    write_text_atomic(json.dumps(checks, indent=2) + "\n", checks_path)
    return {
        "out": str(out),
        "checks": str(checks_path),
        "camera": camera.name,
        "exposure_ms": result.exposure_ms,
        "regrabs": sum(r["regrabs"] for r in reports),
    }


def register(subparsers: Any) -> None:
    """Add ``agent`` and ``capture`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("agent", help="run as a rig's capture agent for the application")
    p.add_argument("--server", required=True, help="the application's URL, e.g. http://lab:8000")
    p.add_argument("--token", required=True, help="your API token (python manage.py createuser prints it)")
    p.add_argument("--rig", type=int, required=True, help="the rig's id")
    _add_camera_options(p)
    p.add_argument("--poll", type=float, default=1.0, help="seconds between looks for queued acquisitions")
    p.add_argument(
        "--max-acquisitions", type=int, default=0, help="stop after this many (default 0: run until stopped)"
    )
    p.add_argument("--confirm-timeout", type=float, default=30.0, help="seconds to wait for the page to show a pattern")
    p.set_defaults(func=cmd_agent)

    p = subparsers.add_parser("capture", help="acquire one stack locally, without a server")
    _add_camera_options(p)
    p.add_argument("--out", required=True, help="the stack, a .zip (checks beside it in .checks.json)")
    p.add_argument("--codec", default="gcps-v1", help="gcps-v1 or gcps-v1:WIDTHxHEIGHT (default gcps-v1, 1024x768)")
    p.add_argument("--role", choices=["reference", "object", "master", "stage"], default="object")
    p.add_argument("--z-in", type=float, help="stage position, mm (role stage; the virtual camera's stage height)")
    p.add_argument("--rig", help="rig JSON (the virtual camera's geometry)")
    p.add_argument("--exposure", type=float, help="exposure, ms (default: auto-exposure from the white frame)")
    p.add_argument("--projector", choices=["page", "none"], default="page", help="page: serve the projector page")
    p.add_argument("--port", type=int, default=8765, help="port of the local projector page (default 8765)")
    p.add_argument("--confirm-timeout", type=float, default=60.0, help="seconds to wait for the page to show a pattern")
    p.set_defaults(func=cmd_capture)
