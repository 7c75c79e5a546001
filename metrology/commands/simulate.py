"""``gcps simulate``: captures of the virtual rig, for a rig file of any model and any codec.

::

    gcps simulate --rig RIG.json --scene SCENE [--codec C] [--z-mm Z] [--preset realistic|noise-free]
                  --out DIR_OR_ZIP [--truth Z.npy] [--distance-mm D] [radiometry options]

The one entry :func:`metrology.core.simulate.render_capture` renders it (the paper's exact model
on a crossed-axes rig, ray casting through the model's seam otherwise). A gcps-v1 capture is
written as the eleven named images; a codec's as its frames with ``codec.json`` beside them.
``--scene stage`` writes a stage series (one capture folder per position and repeat, and
``series.json``). ``--truth``: the true heights above the scene's reference plane (float32 mm,
NaN where not lit).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from metrology.commands.common import BadInputError, check_output, codec_option, load_model


def register(subparsers: Any) -> None:
    """Add ``simulate`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("simulate", help="render a capture stack with the virtual rig")
    p.add_argument("--rig", required=True, help="rig file of any model (docs/file-formats.md, docs/pinhole.md)")
    p.add_argument(
        "--codec", help="codec file (gcps-codec/1) or built-in name to render (default gcps-v1: the eleven patterns)"
    )
    p.add_argument(
        "--distance-mm",
        type=float,
        help="a rig without a plane of its own (pinhole): the scene's reference plane at this camera Z, mm "
        "(default: where the scene's 500 mm field fills the image's width)",
    )
    p.add_argument(
        "--scene",
        required=True,
        help="reference, plane, block, sphere, two_spheres, staircase, face, flowerpot or stage",
    )
    p.add_argument("--out", required=True, help="output folder or .zip (a folder for --scene stage)")
    p.add_argument("--truth", help="write the true heights above the scene's reference plane here (.npy)")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scene parameter, e.g. --param z_mm=40 --param height_mm=30 (repeatable)",
    )
    p.add_argument("--z-mm", type=float, help="height of plane/block scenes, mm")
    p.add_argument("--z-in", help="stage positions, mm: a list '0,4,8' or a range 'START:STOP:STEP' (inclusive)")
    p.add_argument("--repeats", type=int, default=1, help="captures per stage position (default 1)")
    p.add_argument(
        "--preset",
        choices=["realistic", "noise-free"],
        default="realistic",
        help="realistic: 8-bit, 1.5 grey levels noise, slight defocus; noise-free: exact 16-bit",
    )
    p.add_argument("--bits", type=int, choices=[8, 16], help="bit depth (overrides the preset)")
    p.add_argument("--noise", type=float, help="camera noise, grey levels (overrides the preset)")
    p.add_argument("--camera-defocus", type=float, help="camera blur sigma, px")
    p.add_argument("--projector-defocus", type=float, help="projector blur sigma, code units")
    p.add_argument("--gamma", type=float, help="projector gamma")
    p.add_argument("--ambient", type=float, help="ambient light, fraction of full scale")
    p.add_argument("--square", action="store_true", help="square-wave phase patterns")
    p.add_argument("--supersample", type=int, help="sub-pixel samples per axis")
    p.add_argument(
        "--camera-sampling",
        metavar="area|centre",
        help="area: a pixel averages its sub-rays (default); centre: it takes its centre ray, then the Gaussian blur",
    )
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.set_defaults(func=cmd_simulate)


Z_PARAMETER = {"plane": "z_mm", "stage": "z_in_mm", "block": "top_mm"}
"""The scene parameter that ``--z-mm`` sets."""


def _parse_scene_params(items: Sequence[str]) -> dict[str, Any]:
    params: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise BadInputError(f"--param {item!r}: expected KEY=VALUE")
        value: Any
        if text.lower() in ("true", "false"):
            value = text.lower() == "true"
        else:
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError as exc:
                    raise BadInputError(f"--param {item!r}: value must be a number or true/false") from exc
        params[key] = value
    return params


def _parse_positions(text: str) -> list[float]:
    from metrology.core.simulate import stage_positions

    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            return stage_positions(start, stop, step)
        return [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise BadInputError(
            f"--z-in {text!r}: expected '0,4,8' or 'START:STOP:STEP' (inclusive stop) with STEP > 0"
        ) from exc


def _simulation_options(args: argparse.Namespace) -> Any:
    from metrology.core.simulate import SimulationOptions

    base = SimulationOptions.realistic_8bit() if args.preset == "realistic" else SimulationOptions.noise_free_16bit()
    overrides = {
        "bit_depth": args.bits,
        "noise_grey": args.noise,
        "camera_defocus_px": args.camera_defocus,
        "projector_defocus_codes": args.projector_defocus,
        "projector_gamma": args.gamma,
        "ambient": args.ambient,
        "supersample": args.supersample,
        "camera_sampling": args.camera_sampling,
        "seed": args.seed,
    }
    changes = {key: value for key, value in overrides.items() if value is not None}
    if args.square:
        changes["square"] = True
    return base.with_changes(**changes)


def cmd_simulate(args: argparse.Namespace) -> dict[str, Any]:
    """Render the scene (or stage series) through the rig and write it; the summary."""
    import numpy as np

    from metrology.core.codecs.stack import write_cameras_capture
    from metrology.core.io import series_capture_name, write_series
    from metrology.core.scenes import make_scene
    from metrology.core.simulate import ScenePlacement, render_capture, render_series

    model = load_model(args.rig)
    codec = codec_option(args.codec)
    options = _simulation_options(args)
    placement = None
    if args.distance_mm is not None:
        if model.scene_centre_x_mm is not None:
            raise BadInputError("--distance-mm places a scene before a camera; this rig has a plane of its own")
        placement = ScenePlacement.facing_camera(args.distance_mm)
    params = _parse_scene_params(args.param)
    if args.z_mm is not None:
        if args.scene not in Z_PARAMETER:
            raise BadInputError(f"--z-mm applies to scenes {', '.join(Z_PARAMETER)}, not {args.scene!r}")
        params[Z_PARAMETER[args.scene]] = args.z_mm

    if args.scene == "stage":
        if args.z_in is None:
            raise BadInputError("--scene stage needs --z-in (e.g. 0:80:4)")
        if args.repeats < 1:
            raise BadInputError(f"--repeats must be >= 1, got {args.repeats}")
        positions = _parse_positions(args.z_in)
        out = Path(args.out)
        if out.suffix.lower() == ".zip":
            raise BadInputError("--scene stage writes a folder (one capture folder per position and repeat)")
        if out.exists() and any(out.iterdir()):
            raise BadInputError(f"--out {out}: folder exists and is not empty")
        series = render_series(model, positions, args.repeats, options, codec=codec, placement=placement)
        out.mkdir(parents=True, exist_ok=True)  # render_series validated its arguments
        captures: dict[float, list[str]] = {}
        for z_in, repeat, rendered in series:
            name = series_capture_name(z_in, repeat)
            write_cameras_capture(rendered.camera_stacks, out / name, codec)
            captures.setdefault(z_in, []).append(name)
        write_series(captures, out / "series.json")
        return {
            "out": str(out),
            "series": str(out / "series.json"),
            "positions": len(positions),
            "repeats": args.repeats,
            "options": options.to_dict(),
        }

    if args.z_in is not None:
        raise BadInputError("--z-in applies to --scene stage only")
    try:
        scene = make_scene(args.scene, model, **params)
    except TypeError as exc:
        raise BadInputError(f"scene {args.scene!r}: {exc}") from exc
    check_output(args.truth, (".npy",), "--truth")
    rendered = render_capture(model, scene, codec, options, placement=placement)
    write_cameras_capture(rendered.camera_stacks, args.out, codec)
    if args.truth:
        from metrology.core.io import write_height_npy

        write_height_npy(rendered.truth_mm, args.truth)
    valid = int(np.isfinite(rendered.truth_mm).sum())
    return {
        "out": args.out,
        "scene": args.scene,
        "bit_depth": options.bit_depth,
        "truth_valid_pixels": valid,
        "options": options.to_dict(),
    }
