"""``gcps patterns --codec C --out DIR``: the projector images of any codec (docs/codecs.md).

``gcps patterns --width W --height H`` (the eleven gcps-v1 images) is unchanged; with ``--codec``
the images are the codec's frames at its projector size, 8-bit PNG, named in frame order
(the codec's file names, or ``NN.png``; ``prefix*suffix`` globs give ``prefixNNsuffix``), with
the codec written beside them as ``codec.json`` so the folder documents itself.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path, PurePosixPath
from typing import Any


def add_codec_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--codec`` to the ``patterns`` subcommand."""
    parser.add_argument("--codec", help="write the frames of this codec (file or built-in name) instead of gcps-v1")


def frame_file_names(codec: Any) -> list[str]:
    """File name of each frame of ``codec`` (see the module docstring)."""
    n = codec.n_frames
    if not isinstance(codec.frames, int):
        return [name if PurePosixPath(name).suffix else f"{name}.png" for name in codec.frames]
    digits = max(2, len(str(n - 1)))
    prefix, suffix = "", ".png"
    if codec.files and codec.files.count("*") == 1 and not any(ch in codec.files for ch in "?[]"):
        head, tail = codec.files.split("*")
        if tail.lower().endswith((".png", ".tif", ".tiff", ".bmp")) and "/" not in tail:
            prefix, suffix = head, tail
    return [f"{prefix}{i:0{digits}d}{suffix}" for i in range(n)]


def write_codec_patterns(codec: Any, dest: str | os.PathLike[str]) -> Path:
    """Write the projector images of ``codec`` and its ``codec.json`` as a new folder or a .zip (atomic)."""
    import cv2
    import numpy as np

    from metrology.core.codecs import codec_patterns
    from metrology.core.io.atomic import write_files_new_folder_atomic, write_files_zip_atomic

    images = codec_patterns(codec)
    files: dict[str, bytes] = {}
    for name, image in zip(frame_file_names(codec), images, strict=True):
        ext = PurePosixPath(name).suffix.lower()
        ok, buf = cv2.imencode(ext, np.ascontiguousarray(image))
        if not ok:
            raise OSError(f"OpenCV could not encode {name}")
        files[name] = buf.tobytes()
    files["codec.json"] = codec.to_json().encode()
    target = Path(dest)
    if target.suffix.lower() == ".zip":
        return write_files_zip_atomic(files, target)
    if target.exists():
        raise ValueError(f"--out {dest}: already exists; give a new folder or a .zip")
    return write_files_new_folder_atomic(files, target)


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
