"""``gcps characterize`` and ``gcps acceptance`` with a pinhole rig (docs/pinhole.md): captures of
any codec (``--codec``, else each capture's ``codec.json``), heights above the reference
capture's fitted plane, VDI/VDE 2634-2 fits on the camera-frame points.

Called by :mod:`metrology.cli` when ``--rig`` is a pinhole rig file; the crossed-axes paths are
unchanged.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def _codec(args: argparse.Namespace) -> Any:
    from metrology.core.codecs import builtin_codec, read_codec

    name = getattr(args, "codec", None)
    if not name:
        return None
    return read_codec(name) if Path(name).is_file() else builtin_codec(name)


def _write_json(report: dict[str, Any], path: str) -> None:
    from metrology.core.io import write_text_atomic

    write_text_atomic(json.dumps(report, indent=2, allow_nan=False) + "\n", path)


def cmd_characterize_pinhole(args: argparse.Namespace, rows: tuple[int, ...] | None) -> dict[str, Any]:
    """Stage series through a pinhole rig: the pipeline's
    :func:`~metrology.pipeline.characterize.characterize_pinhole`, the report JSON; the summary."""
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.core.io import read_series
    from metrology.pipeline import CharacterizeOptions, characterize_pinhole

    options = CharacterizeOptions(n_points=args.points, rows=rows, patch_px=args.patch)
    rig = PinholeRig.from_json(Path(args.rig).read_text(encoding="utf-8"))
    series = read_series(args.series)
    reference = read_codec_stack(args.reference, _codec(args))
    codec = reference.codec

    def stacks() -> Any:  # streamed: a bad capture stops the run before any output is written
        for position in series.positions:
            for repeat, capture in enumerate(position.captures):
                yield position.z_in_mm, repeat, read_codec_stack(str(capture), codec).images

    result = characterize_pinhole(
        rig, reference.images, stacks(), codec, options, triangulate=getattr(args, "triangulate", "auto")
    )
    report = {**result.to_dict(), "rig": rig.to_dict(), "codec": codec.to_dict()}
    _write_json(report, args.out)
    return {"out": args.out, "positions": len(series.positions), **report["overall"]}


def cmd_acceptance_pinhole(args: argparse.Namespace) -> dict[str, Any]:
    """VDI/VDE 2634-2 through a pinhole rig: the pipeline's
    :func:`~metrology.pipeline.acceptance.acceptance_pinhole`, the result JSON; the summary."""
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.pipeline import AcceptanceOptions, acceptance_pinhole

    options = AcceptanceOptions(
        test=args.test, diameter_mm=args.diameter, spacing_mm=args.spacing, min_height_mm=args.min_height
    )
    rig = PinholeRig.from_json(Path(args.rig).read_text(encoding="utf-8"))
    obj = read_codec_stack(args.object, _codec(args))
    reference = read_codec_stack(args.reference, obj.codec) if args.reference else None
    result = acceptance_pinhole(
        rig,
        None if reference is None else reference.images,
        obj.images,
        obj.codec,
        options,
        triangulate=getattr(args, "triangulate", "auto"),
    )
    _write_json({**result.to_dict(), "rig": rig.to_dict(), "codec": obj.codec.to_dict()}, args.out)
    return {"out": args.out, "test": args.test}
