"""``gcps patterns``: the projector images of gcps-v1 or of any codec (docs/codecs.md).

::

    gcps patterns --width W --height H [--nlp N] [--square] --out DIR_OR_ZIP
    gcps patterns --codec C --out DIR_OR_ZIP

``--width W --height H``: the eleven gcps-v1 images. With ``--codec`` the images are the codec's
frames at its projector size, 8-bit PNG, named in frame order (the codec's file names, or
``NN.png``; ``prefix*suffix`` globs give ``prefixNNsuffix``), with the codec written beside them
as ``codec.json`` so the folder documents itself.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from metrology.commands.common import BadInputError


def register(subparsers: Any) -> None:
    """Add ``patterns`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("patterns", help="write the eleven projector images (or a codec's) as PNG")
    p.add_argument("--width", type=int, help="projector width, px (gcps-v1)")
    p.add_argument("--height", type=int, help="projector height, px (gcps-v1)")
    p.add_argument("--nlp", type=int, default=128, help="light codes across the width (default 128)")
    p.add_argument("--square", action="store_true", help="square-wave phase patterns (smooth on decoding)")
    p.add_argument("--out", required=True, help="output folder or .zip")
    p.add_argument("--codec", help="write the frames of this codec (file or built-in name) instead of gcps-v1")
    p.set_defaults(func=cmd_patterns)


def cmd_patterns(args: argparse.Namespace) -> dict[str, Any]:
    """The gcps-v1 images of ``--width x --height``, or the frames of ``--codec``; the summary."""
    from metrology.core.io import write_stack
    from metrology.core.patterns import projector_patterns

    if args.codec is not None:
        return cmd_codec_patterns(args)
    if args.width is None or args.height is None:
        raise BadInputError("give --width and --height (gcps-v1) or --codec")
    if args.width <= 0 or args.height <= 0:
        raise BadInputError(f"--width and --height must be positive, got {args.width}x{args.height}")
    images = projector_patterns(args.width, args.height, nlp=args.nlp, square=args.square)
    write_stack(images, args.out)
    return {"out": args.out, "patterns": int(images.shape[0])}


def write_codec_patterns(codec: Any, dest: str | os.PathLike[str]) -> Path:
    """Write the projector images of ``codec`` and its ``codec.json`` as a new folder or a .zip (atomic)."""
    from metrology.core.codecs import codec_patterns
    from metrology.core.codecs.stack import write_codec_stack

    return write_codec_stack(codec, codec_patterns(codec), dest)


def cmd_codec_patterns(args: argparse.Namespace) -> dict[str, Any]:
    """``gcps patterns --codec``: refuses --width/--height/--nlp/--square beside it."""
    from metrology.core.codecs import read_codec

    if args.width is not None or args.height is not None or args.square or args.nlp != 128:
        raise ValueError("--codec gives the projector size and the patterns: drop --width, --height, --nlp, --square")
    codec = read_codec(args.codec)
    write_codec_patterns(codec, args.out)
    return {
        "out": args.out,
        "patterns": codec.n_frames,
        "projector": [codec.projector_width, codec.projector_height],
    }
