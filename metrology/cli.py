"""The ``gcps`` command line (docs/command-line.md): a user-facing tool and the contract of external checks.

``main`` builds the parser from the subcommand modules (:data:`metrology.commands.SUBCOMMANDS`,
one module each under :mod:`metrology.commands`) and runs one. Exit status 0 on success, 2 with a
one-line message on bad input. Outputs are written only once everything has been computed, each
atomically, so a failed run leaves no partial file behind. Heavy libraries are imported inside
the subcommands that use them, to keep start-up short.
"""

from __future__ import annotations

import argparse
import atexit
import functools
import gc
import importlib
import json
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

from metrology.commands import SUBCOMMANDS
from metrology.commands.common import EXIT_BAD_INPUT, BadInputError

# numpy's OpenBLAS on one thread in a gcps process unless the environment says otherwise, set before
# numpy is imported (the subcommands import it; the imports above do not): the commands parallelise
# over row tiles on their own threads and their BLAS calls are thin (N x 3 fits), while OpenBLAS's idle
# worker spins for about 0.1 s after numpy's import, 25-40 ms of CPU of every gcps process.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

GC_FIRST_THRESHOLD = 50_000
"""The cyclic collector's first-generation threshold in a gcps process (Python's default: 700).
A process imports numpy, OpenCV and the package's modules, allocating objects that are never
garbage, and a collection ran every 700 of them: 58 collections, 11 ms holding the GIL, in a
``gcps measure`` of a 1280x1024 pair. Cycles are still collected, every 50,000 allocations."""
gc.set_threshold(GC_FIRST_THRESHOLD, *gc.get_threshold()[1:])


_STATUS: list[int] = []
"""The exit status of :func:`run`'s command once it returned (the process then ends in :func:`_end_now`)."""


def _end_now() -> None:
    """The last exit callback of a ``gcps`` process (registered below, before any other): once
    :func:`run`'s command returned, the interpreter has waited for the threads and run every other
    exit callback; what is left of its exit is tearing down the modules and collecting their
    objects, 5-10 ms of CPU and 8-20 ms of wall time of a ``gcps measure`` process that only
    returns memory to the system, which the process's end does at once. The standard streams are
    flushed and the process ends with the command's status (``os._exit``). Registered when this
    module is imported (the imports above register none), and not where a callback came first (a
    coverage tool's, say, which must run after the command's)."""
    if _STATUS:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_STATUS[0])


if getattr(atexit, "_ncallbacks", lambda: -1)() == 0:
    atexit.register(_end_now)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``gcps`` parser: every subcommand module's ``register`` (``argv`` None); given the
    arguments it will parse, ``argv``, only the module of the subcommand they name (their first
    argument that is not an option) when they name one, since their parse is then the same (the
    subcommand's own parser, the same top-level usage) and building all of them is about 17 ms of
    CPU of every ``gcps`` process's start-up (11 ms for ``measure``'s alone). ``gcps --help`` and
    an unknown command get every subcommand (their listing, the "invalid choice" message)."""
    command = _command(argv)
    modules = SUBCOMMANDS if command is None else (command,)
    parser = argparse.ArgumentParser(
        prog="gcps",
        description="Gray-code + phase-shift fringe-projection profilometer (gcps-v1 conventions).",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing on success")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in modules:
        importlib.import_module(f"metrology.commands.{name}").register(sub)
    return parser


def _command(argv: Sequence[str] | None) -> str | None:
    """The subcommand module that the arguments ``argv`` name: their first argument not starting
    with ``-`` (the top-level options, ``--quiet`` and ``--help``, take no value), as typed on the
    command line (``calibrate-procam`` for :mod:`metrology.commands.calibrate_procam`); None when
    ``argv`` is None, has no such argument or it names no subcommand."""
    if argv is None:
        return None
    token = next((arg for arg in argv if not arg.startswith("-")), None)
    if token is None:
        return None
    module = token.replace("-", "_")
    return module if module in SUBCOMMANDS and module.replace("_", "-") == token else None


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; print its summary (JSON) unless ``--quiet``; the exit status."""
    _freeze_objects_at_exit()
    parser = build_parser(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    from metrology.core.allocation import retain_freed_memory

    retain_freed_memory()  # frame-sized temporaries are reused instead of page-faulting again
    func: Callable[[argparse.Namespace], dict[str, Any]] = args.func
    try:
        summary = func(args)
    except BadInputError as exc:
        return _fail(str(exc))
    except (ValueError, OSError) as exc:  # rig, codec and stack errors are ValueError; file errors OSError
        return _fail(str(exc))
    if not args.quiet:
        print(json.dumps(summary))
    return 0


@functools.cache
def _freeze_objects_at_exit() -> None:
    """At the interpreter's exit, move every object into the cyclic collector's permanent generation
    (``gc.freeze``): the collections of the interpreter's finalisation then skip the objects of
    numpy, OpenCV and the package (about 40 ms of a ``gcps measure`` process's 65 ms exit on the
    reference machine). Registered once per process; only the exit is affected."""
    atexit.register(gc.freeze)


def run() -> NoReturn:
    """The ``gcps`` console script and ``python -m metrology.cli``: :func:`main` with the process's
    arguments, its status the process's (ended by :func:`_end_now` where it is registered)."""
    status = main()
    _STATUS.append(status)
    sys.exit(status)


def _fail(message: str) -> int:
    line = " ".join(message.split())
    print(f"gcps: error: {line}", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":  # pragma: no cover
    run()
