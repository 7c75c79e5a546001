"""What the ``gcps`` subcommands share: the bad-input error, output checks and writes, reading a
rig file of any model and captures of any codec, and the measurement options of the commands
that measure (``measure``, ``calibrate``, ``characterize``, ``acceptance``).

Heavy libraries are imported inside the functions that use them, to keep start-up short.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from metrology.core.codecs.model import Codec
    from metrology.core.geometry.base import GeometryModel
    from metrology.core.measure import MeasureOptions


class BadInputError(Exception):
    """A user error: reported as one line, exit status 2 (:func:`metrology.cli.main`)."""


EXIT_BAD_INPUT = 2
"""Exit status of a run refused for bad input."""


# --------------------------------------------------------------------------- outputs
def write_json(data: Any, path: str | Path) -> None:
    """``data`` as indented JSON (no NaN), written atomically."""
    from metrology.core.io import write_text_atomic

    write_text_atomic(json.dumps(data, indent=2, allow_nan=False) + "\n", path)


def check_out_suffix(path: str, allowed: Sequence[str], option: str) -> None:
    """BadInputError unless ``path`` ends with one of ``allowed`` (case-insensitive)."""
    if Path(path).suffix.lower() not in allowed:
        raise BadInputError(f"{option} {path}: extension must be one of {', '.join(allowed)}")


def check_parent(path: str, option: str) -> None:
    """BadInputError unless the folder of ``path`` exists."""
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise BadInputError(f"{option} {path}: folder {parent} does not exist")


def check_output(path: str | None, allowed: Sequence[str], option: str) -> None:
    """:func:`check_out_suffix` and :func:`check_parent` of an optional output."""
    if path:
        check_out_suffix(path, allowed, option)
        check_parent(path, option)


# --------------------------------------------------------------------------- inputs
def load_model(path: str) -> GeometryModel:
    """The geometric model of a rig file of any model (:func:`metrology.core.io.read_model`)."""
    from metrology.core.io import read_model

    return read_model(path)


def codec_option(value: str | None) -> Codec | None:
    """A ``--codec`` value: a codec file, else a built-in name (None when not given)."""
    if not value:
        return None
    from metrology.core.codecs import builtin_codec, read_codec

    return read_codec(value) if Path(value).is_file() else builtin_codec(value)


def captures_codec(option: str | None, captures: Sequence[tuple[str, str | None]]) -> Codec | None:
    """The codec of a command's captures: ``--codec`` (a file or a built-in name), else the
    captures' own ``codec.json`` (they must agree), else None (gcps-v1 named patterns)."""
    from metrology.core.codecs import read_codec
    from metrology.core.codecs.stack import read_capture_codec

    if option:
        return read_codec(option)
    found: dict[str, Any] = {}
    for what, path in captures:
        if path and Path(path).exists():
            codec = read_capture_codec(path)
            if codec is not None:
                found[what] = codec
    if len({json.dumps(codec.to_dict(), sort_keys=True) for codec in found.values()}) > 1:
        raise BadInputError(f"the {' and '.join(found)} captures hold different codec.json files; give --codec")
    return next(iter(found.values()), None)


def read_capture(path: str, codec: Codec | None, model: GeometryModel, what: str) -> Any:
    """The ``(frames, H, W)`` images of a capture: the eleven named gcps-v1 patterns when ``codec``
    is gcps-v1 (or None), else the codec's frames in its order; an
    :class:`~metrology.core.codecs.stack.ExposureStack` for a multi-exposure capture
    (docs/exposures.md); one stack per camera for a rig of several cameras (``cam0/``, ``cam1/``...,
    docs/stereo.md); checked against the rig's cameras.

    Raises
    ------
    BadInputError
        Naming ``what`` (reference, object...) and the problem.
    """
    from metrology.core.codecs.model import is_gcps_v1
    from metrology.core.codecs.stack import is_exposure_capture, read_codec_stack, read_exposure_stack

    if not Path(path).exists():
        raise BadInputError(f"{what} stack {path}: not found")
    if model.cameras > 1:
        return _read_cameras(path, codec, model, what)
    try:
        if is_exposure_capture(path):  # a multi-exposure capture (docs/exposures.md)
            stack = read_exposure_stack(path, codec).stack
            shape = stack.frame_shape
            if shape != tuple(model.shape):
                h, w = shape
                mh, mw = model.shape
                raise BadInputError(f"{what} stack: the frames are {w}x{h} px but the rig's camera is {mw}x{mh} px")
            return stack
        if is_gcps_v1(codec):
            from metrology.core.io import read_stack

            return read_stack(path, rig=model).images
        images = read_codec_stack(path, codec).images
    except ValueError as exc:
        raise BadInputError(f"{what} stack: {exc}") from exc
    if tuple(images.shape[1:]) != tuple(model.shape):
        h, w = images.shape[1:]
        mh, mw = model.shape
        raise BadInputError(f"{what} stack: the frames are {w}x{h} px but the rig's camera is {mw}x{mh} px")
    return images


def _read_cameras(path: str, codec: Codec | None, model: GeometryModel, what: str) -> tuple[Any, ...]:
    """One stack per camera of a capture of several cameras (``cam0/``, ``cam1/``...; an
    :class:`~metrology.core.codecs.stack.ExposureStack` each for a multi-exposure one, ``cam0/exp0/``
    ...), each checked against its camera's size."""
    from metrology.core.codecs.stack import read_camera_stacks

    try:
        read = read_camera_stacks(path, codec, model.cameras)
    except ValueError as exc:
        raise BadInputError(f"{what} stack: {exc}") from exc
    stacks = read.stacks
    for index, (shape, expected) in enumerate(zip(read.frame_shapes, model.camera_shapes, strict=True)):
        if tuple(shape) != tuple(expected):
            h, w = shape
            mh, mw = expected
            raise BadInputError(
                f"{what} stack: camera {index}'s frames are {w}x{h} px but the rig's camera {index} is {mw}x{mh} px"
            )
    return stacks


# --------------------------------------------------------------------------- measurement options
def add_measure_options(parser: argparse.ArgumentParser, *, triangulate: bool = True) -> None:
    """The decoding and filter options (and the triangulation's) of a command that measures."""
    group = parser.add_argument_group("decoding and filters")
    group.add_argument(
        "--min-modulation",
        type=float,
        default=None,
        metavar="GREY",
        help="modulation threshold in grey levels (default: 4%% of full scale)",
    )
    group.add_argument(
        "--consistency",
        type=float,
        default=0.35,
        metavar="CODES",
        help="gcps-v1: allowed gray/phase disagreement beyond the gray cell, code units (default 0.35)",
    )
    group.add_argument(
        "--smoothing",
        type=float,
        default=0.0,
        metavar="PX",
        help="gcps-v1: Gaussian smoothing of square-wave fringes along X, pixels (default 0: sinusoidal)",
    )
    group.add_argument(
        "--discontinuity",
        type=float,
        default=1.0,
        metavar="CODES",
        help="drop both pixels of a neighbour pair whose codes jump by more (mixed pixels); 0 disables (default 1.0)",
    )
    group.add_argument(
        "--edge-band",
        type=int,
        default=2,
        metavar="PX",
        help="drop valid pixels within this many pixels of an invalid pixel or a discontinuity (default 2)",
    )
    group.add_argument(
        "--field-margin",
        type=float,
        default=0.25,
        metavar="CODES",
        help="refuse codes closer than this to the coded field's edges (default 0.25)",
    )
    if triangulate:
        geometry = parser.add_argument_group("triangulation")
        geometry.add_argument(
            "--triangulate",
            choices=["auto", "u", "v"],
            default="auto",
            help="projector axis to triangulate (default auto: the model's choice)",
        )
        geometry.add_argument(
            "--method",
            dest="triangulation_method",
            choices=["plane", "midpoint"],
            default="plane",
            help="camera ray and light plane (default), or the midpoint of camera and projector rays",
        )
        geometry.add_argument(
            "--match",
            dest="stereo_match",
            choices=["epipolar", "2d"],
            default="epipolar",
            help="stereo rigs: match along epipolar lines (default), or in 2-D when both axes are coded",
        )


def measure_options(args: argparse.Namespace, **settings: Any) -> MeasureOptions:
    """The :class:`~metrology.core.measure.MeasureOptions` of the options :func:`add_measure_options`
    added (and ``settings``: ``gray_only``, ``sigma``, ``max_sigma_mm``)."""
    from metrology.core.decode import GcpsV1Options
    from metrology.core.filters import FilterOptions
    from metrology.core.geometry.base import GeometryOptions
    from metrology.core.measure import MeasureOptions

    return MeasureOptions(
        filters=FilterOptions(
            min_modulation=args.min_modulation,
            discontinuity_codes=args.discontinuity,
            edge_band_px=args.edge_band,
            field_margin_codes=args.field_margin,
        ),
        gcps_v1=GcpsV1Options(consistency_codes=args.consistency, smoothing_px=args.smoothing),
        geometry=GeometryOptions(
            triangulate=getattr(args, "triangulate", "auto"),
            method=getattr(args, "triangulation_method", "plane"),
            match=getattr(args, "stereo_match", "epipolar"),
        ),
        **settings,
    )


def settings_of(args: argparse.Namespace) -> dict[str, Any]:
    """The ``filters``, ``gcps_v1`` and ``geometry`` keyword arguments of an options object that
    measures, from the command's options."""
    options = measure_options(args)
    return {"filters": options.filters, "gcps_v1": options.gcps_v1, "geometry": options.geometry}
