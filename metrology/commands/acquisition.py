"""What the acquisition subcommands (``gcps agent``, ``gcps capture``) share: their camera and
sequencing options (docs/acquisition.md)."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where used, so that gcps starts without them
    from metrology.acquisition.agent.cameras import Camera
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


def faults(value: str | None) -> tuple[int, int]:
    """``latency=N,saturate=M``: every N-th / M-th grab faulty (testing aid)."""
    if not value:
        return 0, 0
    counts = {"latency": 0, "saturate": 0}
    for item in value.split(","):
        key, _, number = item.partition("=")
        if key.strip() not in counts or not number.strip().isdigit():
            raise bad(f"--inject-faults expects latency=N,saturate=M, got {value!r}")
        counts[key.strip()] = int(number)
    return counts["latency"], counts["saturate"]


def open_camera(args: argparse.Namespace) -> Camera:
    """The camera ``--camera`` names (wrapped to inject faults when asked)."""
    from metrology.acquisition.agent.cameras import FaultyCamera, make_camera

    try:
        camera = make_camera(
            args.camera,
            scene=json_option(args.scene, "--scene"),
            options=json_option(args.sim_options, "--sim-options"),
        )
    except ValueError as exc:
        raise bad(str(exc)) from None
    latency, saturate = faults(args.inject_faults)
    if latency or saturate:
        camera = FaultyCamera(camera, latency_every=latency, saturate_every=saturate)
    return camera


def sequence_options(args: argparse.Namespace) -> SequenceOptions:
    """The sequencer's settle time and grabs per pattern."""
    from metrology.acquisition.agent.sequencer import SequenceOptions

    try:
        return SequenceOptions(settle_s=args.settle, max_grabs=args.max_grabs)
    except ValueError as exc:
        raise bad(str(exc)) from None


def add_camera_options(p: argparse.ArgumentParser) -> None:
    """The camera and sequencing options of ``agent`` and ``capture``."""
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
