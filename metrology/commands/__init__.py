"""The ``gcps`` subcommands, one module each; :mod:`metrology.cli` builds the parser from
:data:`SUBCOMMANDS` and runs one (docs/command-line.md).

Each module has ``register(subparsers)`` (adds its subcommand, whose ``func`` reads the inputs,
calls the pipeline and writes the outputs) and imports heavy libraries inside its functions only,
so ``gcps`` starts fast. Modules that are not subcommands:

- :mod:`.common`: the bad-input error, output checks, reading rig files of any model and
  captures of any codec, the measurement options of the commands that measure;
- :mod:`.acquisition`: the camera and sequencing options of ``agent`` and ``capture``.
"""

from __future__ import annotations

SUBCOMMANDS: tuple[str, ...] = (
    "patterns",
    "decode",
    "simulate",
    "measure",
    "calibrate",
    "characterize",
    "acceptance",
    "sensitivity",
    "agent",
    "capture",
    "rig",
    "calibrate_procam",
    "calibrate_stereo",
    "gamma_correct",
    "cache",
    "inspect",
)
"""The subcommand modules of this package, in the order ``gcps --help`` lists them."""
