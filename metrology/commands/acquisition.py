"""What the acquisition subcommands (``gcps agent``, ``gcps capture``) share: their camera and
sequencing options (docs/acquisition.md)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where used, so that gcps starts without them
    from metrology.acquisition.agent.bracketing import BracketOptions, ExposureChoice
    from metrology.acquisition.agent.cameras import RigCameras
    from metrology.acquisition.agent.sequencer import SequenceOptions


def bad(message: str) -> Exception:
    """A user error: ``gcps`` prints it as one line and exits with status 2 (ValueError, so that
    ``python -m metrology.cli`` catches it too)."""
    return ValueError(message)


def json_option(value: str | None, option: str) -> dict[str, Any] | None:
    if value is None:
        return None
    try:
        data = json.loads(value)
    except ValueError:
        raise bad(f"{option} must be a JSON object, got {value!r}") from None
    if not isinstance(data, dict):
        raise bad(f"{option} must be a JSON object, got {value!r}")
    return data


def faults(value: str | None) -> tuple[int, int, int]:
    """``latency=N,saturate=M[,camera=K]``: every N-th / M-th grab faulty on camera K (default 0; testing aid)."""
    if not value:
        return 0, 0, 0
    counts = {"latency": 0, "saturate": 0, "camera": 0}
    for item in value.split(","):
        key, _, number = item.partition("=")
        if key.strip() not in counts or not number.strip().isdigit():
            raise bad(f"--inject-faults expects latency=N,saturate=M[,camera=K], got {value!r}")
        counts[key.strip()] = int(number)
    return counts["latency"], counts["saturate"], counts["camera"]


def open_camera(args: argparse.Namespace) -> RigCameras:
    """The rig's cameras ``--camera`` (and ``--camera1``) name, wrapped to inject faults when asked."""
    from metrology.acquisition.agent.cameras import FaultyCamera, make_cameras

    specs = [args.camera] + ([args.camera1] if args.camera1 else [])
    try:
        cameras = make_cameras(
            specs,
            trigger_line=args.trigger_line,
            scene=json_option(args.scene, "--scene"),
            options=json_option(args.sim_options, "--sim-options"),
        )
    except ValueError as exc:
        raise bad(str(exc)) from None
    latency, saturate, camera = faults(args.inject_faults)
    if latency or saturate:
        cameras = FaultyCamera(cameras, latency_every=latency, saturate_every=saturate, camera=camera)
    return cameras


def sequence_options(args: argparse.Namespace) -> SequenceOptions:
    """The sequencer's settle time and grabs per pattern."""
    from metrology.acquisition.agent.sequencer import SequenceOptions

    try:
        return SequenceOptions(settle_s=args.settle, max_grabs=args.max_grabs)
    except ValueError as exc:
        raise bad(str(exc)) from None


def add_exposures_options(p: argparse.ArgumentParser, serves: str) -> None:
    """``--exposures`` and ``--max-exposures`` (multi-exposure captures, docs/exposures.md); ``serves``
    says which captures they apply to."""
    p.add_argument(
        "--exposures",
        help=f"multi-exposure captures for {serves} (docs/exposures.md): 'auto' (bracketed from white and "
        "black frames) or up to 8 exposure times in ms, e.g. 1,10,100",
    )
    p.add_argument("--max-exposures", type=int, default=3, help="most exposures of an automatic bracket (default 3)")


def exposures_option(value: str | None) -> ExposureChoice | None:
    """``--exposures``: None, ``"auto"``, or the exposure times (ms, distinct, at most 8), shortest first."""
    from metrology.acquisition.agent.bracketing import parse_exposures

    try:
        return parse_exposures(value)
    except ValueError as exc:
        raise bad(f"--{exc}") from None


def bracket_options(max_exposures: int) -> BracketOptions:
    """The automatic bracket's options with ``--max-exposures``."""
    from metrology.acquisition.agent.bracketing import BracketOptions

    try:
        return BracketOptions(max_exposures=max_exposures)
    except ValueError as exc:
        raise bad(f"--max-exposures: {exc}") from None


def exposure_choice(args: argparse.Namespace) -> tuple[ExposureChoice | None, BracketOptions]:
    """``--exposures`` and the automatic bracket's options with ``--max-exposures``."""
    return exposures_option(args.exposures), bracket_options(args.max_exposures)


def add_camera_options(p: argparse.ArgumentParser) -> None:
    """The camera and sequencing options of ``agent`` and ``capture``."""
    p.add_argument(
        "--camera",
        required=True,
        help="opencv:DEVICE (index, /dev/videoN or a video file), genicam:PRODUCER.cti, virtual "
        "(camera 0 of a stereo rig; virtual renders every camera of the rig)",
    )
    p.add_argument("--camera1", help="camera 1 of a stereo rig (two-camera rigs), a backend as --camera")
    p.add_argument(
        "--trigger-line",
        metavar="LINE",
        help="stereo rigs of two GenICam cameras: expose both on one trigger, camera 0 on software, camera 1 on "
        "its input LINE (e.g. Line0) wired to camera 0's exposure output (default: grab one after the other)",
    )
    p.add_argument("--settle", type=float, default=0.1, help="wait after each confirmed pattern, s (default 0.1)")
    p.add_argument("--max-grabs", type=int, default=4, help="grabs per pattern before giving up (default 4)")
    p.add_argument("--scene", help='virtual camera: the object scene, JSON, e.g. \'{"name": "sphere"}\'')
    p.add_argument("--sim-options", help="virtual camera: simulation options, JSON, e.g. '{\"bit_depth\": 8}'")
    p.add_argument(
        "--inject-faults",
        metavar="latency=N,saturate=M[,camera=K]",
        help="testing: every N-th grab late, M-th saturated, on camera K (default 0)",
    )
