"""``gcps agent``: run as a real rig's capture agent for the application (docs/acquisition.md).

``gcps agent --server URL --token TOKEN --rig ID --camera BACKEND`` registers with the application
as the rig's capture agent and runs the acquisitions queued for the rig (dashboard or
``POST /api/rigs/{id}/captures/acquire/``), driving the rig's projector page.
"""

from __future__ import annotations

import argparse
from typing import Any

from metrology.commands.acquisition import (
    add_camera_options,
    add_exposures_options,
    bad,
    exposure_choice,
    open_camera,
    sequence_options,
)


def register(subparsers: Any) -> None:
    """Add ``agent`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("agent", help="run as a rig's capture agent for the application")
    p.add_argument("--server", required=True, help="the application's URL, e.g. http://lab:8000")
    p.add_argument("--token", required=True, help="your API token (python manage.py createuser prints it)")
    p.add_argument("--rig", type=int, required=True, help="the rig's id")
    add_camera_options(p)
    p.add_argument("--poll", type=float, default=1.0, help="seconds between looks for queued acquisitions")
    p.add_argument(
        "--max-acquisitions", type=int, default=0, help="stop after this many (default 0: run until stopped)"
    )
    p.add_argument("--confirm-timeout", type=float, default=30.0, help="seconds to wait for the page to show a pattern")
    add_exposures_options(p, "the acquisitions that choose neither exposures nor an exposure")
    p.set_defaults(func=cmd_agent)


def cmd_agent(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.acquisition.agent.cameras import CameraError
    from metrology.acquisition.agent.client import AgentClient, AgentOptions, ProtocolError, run_agent
    from metrology.version import software_version

    if not args.server.startswith(("http://", "https://")):
        raise bad(f"--server must be an http:// or https:// URL, got {args.server!r}")
    camera = open_camera(args)
    exposures, bracket = exposure_choice(args)
    client = AgentClient(args.server, args.token, args.rig)
    options = AgentOptions(
        sequence=sequence_options(args),
        poll_s=args.poll,
        max_acquisitions=args.max_acquisitions,
        confirm_timeout_s=args.confirm_timeout,
        exposures=exposures,
        bracket=bracket,
    )
    try:
        return run_agent(client, camera, options, software_version())
    except ProtocolError as exc:
        raise bad(f"agent refused: {exc}") from None
    except CameraError as exc:
        raise bad(str(exc)) from None
