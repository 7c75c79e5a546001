"""The ``gcps`` command line (docs/command-line.md): a user-facing tool and the contract of external checks.

Exit status 0 on success, 2 with a one-line message on bad input. Outputs are
written only once everything has been computed, each atomically, so a failed
run leaves no partial file behind. Heavy libraries are imported inside the
subcommands that use them, to keep start-up short.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

EXIT_BAD_INPUT = 2


class BadInputError(Exception):
    """A user error: reported as one line, exit status 2."""


# --------------------------------------------------------------------- helpers
def _load_rig(path: str) -> Any:
    from metrology.core.io import read_rig

    return read_rig(path)


def _load_stack(path: str, rig: Any, what: str) -> Any:
    from metrology.core.io import read_stack

    try:
        return read_stack(path, rig=rig).images
    except FileNotFoundError as exc:
        raise BadInputError(f"{what} stack {path}: not found") from exc
    except ValueError as exc:
        raise BadInputError(f"{what} stack: {exc}") from exc


def _write_json(data: Any, path: str | Path) -> None:
    from metrology.core.io import write_text_atomic

    write_text_atomic(json.dumps(data, indent=2, allow_nan=False) + "\n", path)


def _check_out_suffix(path: str, allowed: Sequence[str], option: str) -> None:
    if Path(path).suffix.lower() not in allowed:
        raise BadInputError(f"{option} {path}: extension must be one of {', '.join(allowed)}")


def _check_parent(path: str, option: str) -> None:
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise BadInputError(f"{option} {path}: folder {parent} does not exist")


def _decode_options(args: argparse.Namespace) -> Any:
    from metrology.core.measure import DecodeOptions

    return DecodeOptions(
        min_modulation=args.min_modulation,
        consistency_codes=args.consistency,
        smoothing_px=args.smoothing,
        discontinuity_codes=args.discontinuity,
        edge_band_px=args.edge_band,
        field_margin_codes=args.field_margin,
    )


def _add_decode_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("decoding")
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
        help="allowed gray/phase disagreement beyond the gray cell, code units (default 0.35)",
    )
    group.add_argument(
        "--smoothing",
        type=float,
        default=0.0,
        metavar="PX",
        help="Gaussian smoothing of square-wave fringes along X, pixels (default 0: sinusoidal)",
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
        help="refuse codes closer than this to 0 or nlp, the coded field's edges (default 0.25)",
    )


# ----------------------------------------------------------------- commands
def cmd_patterns(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.core.io import write_stack
    from metrology.core.patterns import projector_patterns

    if args.codec is not None:
        from metrology.commands.patterns import cmd_codec_patterns

        return cmd_codec_patterns(args)
    if args.width is None or args.height is None:
        raise BadInputError("give --width and --height (gcps-v1) or --codec")
    if args.width <= 0 or args.height <= 0:
        raise BadInputError(f"--width and --height must be positive, got {args.width}x{args.height}")
    images = projector_patterns(args.width, args.height, nlp=args.nlp, square=args.square)
    write_stack(images, args.out)
    return {"out": args.out, "patterns": int(images.shape[0])}


def _stacks_codec(codec_option: str | None, captures: Sequence[tuple[str, str]]) -> Any:
    """The codec of ``gcps measure``'s captures: ``--codec`` (a file or a built-in name), else the
    captures' own ``codec.json`` (they must agree), else None (gcps-v1 named patterns)."""
    from metrology.core.codecs import read_codec
    from metrology.core.codecs.stack import read_capture_codec

    if codec_option:
        return read_codec(codec_option)
    found: dict[str, Any] = {}
    for what, path in captures:
        if Path(path).exists():
            codec = read_capture_codec(path)
            if codec is not None:
                found[what] = codec
    if len({json.dumps(codec.to_dict(), sort_keys=True) for codec in found.values()}) > 1:
        raise BadInputError(f"the {' and '.join(found)} captures hold different codec.json files; give --codec")
    return next(iter(found.values()), None)


def _load_codec_stack(path: str, codec: Any, what: str) -> Any:
    from metrology.core.codecs.stack import read_codec_stack

    if not Path(path).exists():
        raise BadInputError(f"{what} stack {path}: not found")
    try:
        return read_codec_stack(path, codec).images
    except ValueError as exc:
        raise BadInputError(f"{what} stack: {exc}") from exc


def cmd_measure(args: argparse.Namespace) -> dict[str, Any]:
    import numpy as np

    from metrology.commands.measure_pinhole import cmd_measure_pinhole, is_pinhole_rig
    from metrology.core.codec_measure import is_gcps_v1
    from metrology.pipeline import MeasureOptions, measure

    if is_pinhole_rig(args.rig):
        return cmd_measure_pinhole(args)
    if args.reference is None:
        raise BadInputError("--reference is required for a crossed-axes rig (a pinhole rig measures without one)")
    _check_parent(args.out, "--out")
    _check_out_suffix(args.out, (".npy",), "--out")
    if args.mesh:
        _check_out_suffix(args.mesh, (".ply", ".stl", ".obj"), "--mesh")
        _check_parent(args.mesh, "--mesh")
    if args.json:
        _check_parent(args.json, "--json")
    for option, path in (("--xyz", args.xyz), ("--sigma", args.sigma)):
        if path:
            _check_out_suffix(path, (".npy",), option)
            _check_parent(path, option)
    if args.max_sigma is not None and not (args.max_sigma > 0 and args.max_sigma < float("inf")):
        raise BadInputError(f"--max-sigma must be a positive number of mm, got {args.max_sigma!r}")
    want_sigma = bool(args.sigma) or args.max_sigma is not None
    options = MeasureOptions(decode=_decode_options(args), gray_only=bool(args.json), sigma=want_sigma)
    started = time.perf_counter()
    rig = _load_rig(args.rig)
    codec = _stacks_codec(args.codec, [("reference", args.reference), ("object", args.object)])
    if is_gcps_v1(codec):  # the paper's eleven named patterns: today's path
        codec = None
        reference = _load_stack(args.reference, rig, "reference")
        obj = _load_stack(args.object, rig, "object")
    else:
        reference = _load_codec_stack(args.reference, codec, "reference")
        obj = _load_codec_stack(args.object, codec, "object")
    read_s = time.perf_counter() - started
    result = measure(rig, reference, obj, options, codec=codec)
    dropped = 0
    if args.max_sigma is not None and result.sigma_mm is not None:
        drop = np.isfinite(result.z_mm) & ~(result.sigma_mm <= np.float32(args.max_sigma))
        dropped = int(drop.sum())
        result.z_mm[drop] = np.nan
        result.sigma_mm[drop] = np.nan
    mesh = None
    if args.mesh:
        from metrology.core.mesh import mesh_from_heights

        mesh = mesh_from_heights(rig, result.z_mm)

    from metrology.core.io import atomic_path, write_height_npy

    write_height_npy(result.z_mm, args.out)
    if args.xyz:
        with atomic_path(args.xyz) as tmp:
            np.save(tmp, result.points_mm(rig))
    if args.sigma and result.sigma_mm is not None:
        with atomic_path(args.sigma) as tmp:
            np.save(tmp, result.sigma_mm)
    if mesh is not None:
        from metrology.core.mesh import write_mesh

        write_mesh(mesh, args.mesh)
    stats = result.statistics()
    if result.sigma_mm is not None:
        finite = result.sigma_mm[np.isfinite(result.sigma_mm)]
        stats["sigma_mm_median"] = float(np.median(finite)) if finite.size else None
        stats["dropped_by_max_sigma"] = dropped
    if args.json:
        gray = stats.get("gray_only") or {}
        report = {
            **{key: value for key, value in stats.items() if key != "gray_only"},
            "gray_only_valid_pixels": gray.get("valid_pixels"),
            "gray_only": gray or None,
            "timings_s": {"read_s": read_s, **result.timings_s},
            "options": result.options.to_dict(),
            "software_version": result.software_version,
            "rig": rig.to_dict(),
            "codec": result.codec if codec is None else codec.to_dict(),
        }
        if result.decoding is not None:
            report["decoding"] = result.decoding.summary()
        _write_json(report, args.json)
    keep = ("pixels", "fraction", "sigma_mm_median", "dropped_by_max_sigma")
    return {"out": args.out, **{k: v for k, v in stats.items() if k.endswith(keep)}}


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
    import numpy as np

    from metrology.core.io import series_capture_name, write_series, write_stack
    from metrology.core.scenes import make_scene
    from metrology.core.simulate import render_series, render_stack

    rig = _load_rig(args.rig)
    options = _simulation_options(args)
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
        render_series(rig, positions, args.repeats, options)  # validates before anything is written
        out.mkdir(parents=True, exist_ok=True)
        captures: dict[float, list[str]] = {}
        for z_in, repeat, rendered in render_series(rig, positions, args.repeats, options):
            name = series_capture_name(z_in, repeat)
            write_stack(rendered.images, out / name)
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
        scene = make_scene(args.scene, rig, **params)
    except TypeError as exc:
        raise BadInputError(f"scene {args.scene!r}: {exc}") from exc
    if args.truth:
        _check_out_suffix(args.truth, (".npy",), "--truth")
        _check_parent(args.truth, "--truth")
    rendered = render_stack(rig, scene, options)
    write_stack(rendered.images, args.out)
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


def _parse_roi(text: str | None) -> tuple[slice, slice] | None:
    if not text:
        return None
    try:
        rows, cols = text.split(",")
        r0, r1 = (int(v) for v in rows.split(":"))
        c0, c1 = (int(v) for v in cols.split(":"))
    except ValueError as exc:
        raise BadInputError(f"--roi {text!r}: expected 'row0:row1,col0:col1'") from exc
    if r1 <= r0 or c1 <= c0 or r0 < 0 or c0 < 0:
        raise BadInputError(f"--roi {text!r}: empty or negative range")
    return slice(r0, r1), slice(c0, c1)


def _calibrate_options(args: argparse.Namespace) -> Any:
    from metrology.pipeline import CalibrateOptions

    roi = _parse_roi(args.roi)
    return CalibrateOptions(
        master_height_mm=args.master_height,
        method=args.method,
        decode=_decode_options(args),
        roi=None if roi is None else ((roi[0].start, roi[0].stop), (roi[1].start, roi[1].stop)),
        fit_d=args.fit_d,
        max_iterations=args.max_iterations or None,
        delta_z_mm=args.delta_z,
        m_hat=args.m_hat,
    )


def cmd_calibrate(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.pipeline import calibrate

    if not args.master_height > 0:
        raise BadInputError(f"--master-height must be positive, got {args.master_height}")
    if args.method == "paper" and len(args.master) > 1:
        raise BadInputError("--method paper takes one --master capture")
    _check_parent(args.out, "--out")
    options = _calibrate_options(args)
    rig = _load_rig(args.rig)
    reference = _load_stack(args.reference, rig, "reference")
    masters = [_load_stack(path, rig, "master") for path in args.master]
    result = calibrate(rig, reference, masters, options)
    report = {**result.calibration.to_dict(), "options": options.to_dict(), "software_version": result.software_version}
    _write_json({**result.rig.to_dict(), "calibration": report}, args.out)
    return {
        "out": args.out,
        "method": report["method"],
        "iterations": report["iterations"],
        "converged": report["converged"],
        "L_mm": report["L_mm"],
        "alpha_rad": report["alpha_rad"],
    }


def _add_pinhole_codec_options(p: argparse.ArgumentParser) -> None:
    """``--codec`` and ``--triangulate`` of the pinhole-rig paths (docs/pinhole.md)."""
    p.add_argument("--codec", help="pinhole rigs: codec file (gcps-codec/1) or built-in name; default: codec.json")
    p.add_argument(
        "--triangulate", choices=["auto", "u", "v"], default="auto", help="pinhole rigs: projector axis (default auto)"
    )


def cmd_characterize(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.core.io import read_series
    from metrology.pipeline import CharacterizeOptions, characterize

    _check_parent(args.out, "--out")
    rows = None
    if args.rows:
        try:
            rows = tuple(int(v) for v in args.rows.split(","))
        except ValueError as exc:
            raise BadInputError(f"--rows {args.rows!r}: expected comma-separated row indices") from exc
    from metrology.commands.measure_pinhole import is_pinhole_rig

    if is_pinhole_rig(args.rig):
        from metrology.commands.pinhole_acceptance import cmd_characterize_pinhole

        return cmd_characterize_pinhole(args, rows)
    if args.codec is not None:
        raise BadInputError("--codec applies to pinhole rigs only (a crossed-axes characterization reads gcps-v1)")
    options = CharacterizeOptions(decode=_decode_options(args), n_points=args.points, rows=rows, patch_px=args.patch)
    rig = _load_rig(args.rig)
    series = read_series(args.series)
    reference = _load_stack(args.reference, rig, "reference")

    def stacks() -> Any:  # streamed: a bad capture stops the run before any output is written
        for position in series.positions:
            for repeat, capture in enumerate(position.captures):
                yield position.z_in_mm, repeat, _load_stack(str(capture), rig, f"series capture {capture}")

    result = characterize(rig, reference, stacks(), options)
    report = {**result.to_dict(), "rig": rig.to_dict()}
    _write_json(report, args.out)
    overall = report["overall"]
    return {"out": args.out, "positions": len(series.positions), **overall}


def cmd_acceptance(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.pipeline import AcceptanceOptions, acceptance

    needs = {"probing": "diameter", "spacing": "spacing"}
    if args.test in needs and getattr(args, needs[args.test]) is None:
        raise BadInputError(f"--test {args.test} needs --{needs[args.test]}")
    _check_parent(args.out, "--out")
    from metrology.commands.measure_pinhole import is_pinhole_rig

    if is_pinhole_rig(args.rig):
        from metrology.commands.pinhole_acceptance import cmd_acceptance_pinhole

        return cmd_acceptance_pinhole(args)
    if args.codec is not None:
        raise BadInputError("--codec applies to pinhole rigs only (a crossed-axes acceptance reads gcps-v1)")
    if args.reference is None:
        raise BadInputError("--reference is required for a crossed-axes rig (a pinhole rig's flatness needs none)")
    options = AcceptanceOptions(
        test=args.test,
        diameter_mm=args.diameter,
        spacing_mm=args.spacing,
        min_height_mm=args.min_height,
        decode=_decode_options(args),
    )
    rig = _load_rig(args.rig)
    reference = _load_stack(args.reference, rig, "reference")
    obj = _load_stack(args.object, rig, "object")
    result = acceptance(rig, reference, obj, options)
    _write_json({**result.to_dict(), "rig": rig.to_dict()}, args.out)
    return {"out": args.out, "test": args.test}


def cmd_sensitivity(args: argparse.Namespace) -> dict[str, Any]:
    from metrology.core.sensitivity import sensitivity_curves

    rig = _load_rig(args.rig)
    params: list[Literal["L", "d", "alpha"]] = [args.param] if args.param else ["L", "d", "alpha"]
    curves = {param: sensitivity_curves(rig, param, z_mm=args.z_mm) for param in params}
    _check_parent(args.out, "--out")
    from metrology.version import software_version

    report = {"rig": rig.to_dict(), "z_mm": args.z_mm, "curves": curves, "software_version": software_version()}
    _write_json(report, args.out)
    return {"out": args.out, "params": params}


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    from metrology.commands.decode import register as decode_command
    from metrology.commands.patterns import add_codec_option as codec_patterns_option

    parser = argparse.ArgumentParser(
        prog="gcps",
        description="Gray-code + phase-shift fringe-projection profilometer (gcps-v1 conventions).",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing on success")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("patterns", help="write the eleven projector images (or a codec's) as PNG")
    p.add_argument("--width", type=int, help="projector width, px (gcps-v1)")
    p.add_argument("--height", type=int, help="projector height, px (gcps-v1)")
    p.add_argument("--nlp", type=int, default=128, help="light codes across the width (default 128)")
    p.add_argument("--square", action="store_true", help="square-wave phase patterns (smooth on decoding)")
    p.add_argument("--out", required=True, help="output folder or .zip")
    codec_patterns_option(p)
    p.set_defaults(func=cmd_patterns)
    decode_command(sub)

    p = sub.add_parser("simulate", help="render a capture stack with the virtual rig")
    p.add_argument("--rig", required=True, help="rig JSON (docs/file-formats.md)")
    p.add_argument(
        "--scene",
        required=True,
        help="reference, plane, block, sphere, two_spheres, staircase, face, flowerpot or stage",
    )
    p.add_argument("--out", required=True, help="output folder or .zip (a folder for --scene stage)")
    p.add_argument("--truth", help="write the true height map here (.npy)")
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

    p = sub.add_parser("measure", help="height map (and mesh) of an object")
    p.add_argument("--rig", required=True)
    p.add_argument(
        "--reference", help="capture stack of the reference plane (folder or .zip); optional for pinhole rigs"
    )
    p.add_argument("--object", required=True, help="capture stack of the object (folder or .zip)")
    p.add_argument("--out", required=True, help="height map, float32 mm, NaN where not measured (.npy)")
    p.add_argument("--mesh", help="mesh output (.ply, .stl or .obj)")
    p.add_argument("--json", help="statistics and timings (.json)")
    p.add_argument(
        "--codec",
        help="codec file (gcps-codec/1) or built-in name of both captures (default: their codec.json, else gcps-v1); "
        "a crossed-axes rig needs it to code the u axis",
    )
    _add_decode_options(p)
    from metrology.commands.measure_pinhole import add_pinhole_measure_arguments

    add_pinhole_measure_arguments(p)
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser("calibrate", help="calibrate L and alpha on a master block")
    p.add_argument("--rig", required=True, help="rig JSON with the rough starting values")
    p.add_argument("--reference", required=True)
    p.add_argument(
        "--master",
        required=True,
        action="append",
        help="capture stack of the master block (repeatable for --method lsq)",
    )
    p.add_argument("--master-height", type=float, required=True, help="master block height, mm")
    p.add_argument("--method", choices=["paper", "lsq"], default="lsq", help="calibration method (default lsq)")
    p.add_argument("--delta-z", type=float, default=0.025, help="paper: required accuracy, mm (default 0.025)")
    p.add_argument("--m-hat", type=float, default=0.0001, help="paper: slope threshold (default 0.0001)")
    p.add_argument("--max-iterations", type=int, default=None, help="iteration cap")
    p.add_argument("--fit-d", action="store_true", help="lsq: also fit d")
    p.add_argument("--roi", help="top-face region 'row0:row1,col0:col1' (default: found automatically)")
    p.add_argument("--out", required=True, help="calibrated rig JSON")
    _add_decode_options(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("characterize", help="linearity and accuracy from a stage series")
    p.add_argument("--rig", required=True)
    p.add_argument("--reference", required=True)
    p.add_argument("--series", required=True, help="SERIES.json listing stage positions and captures")
    p.add_argument("--out", required=True, help="report JSON")
    p.add_argument("--patch", type=int, default=5, help="test-point patch size, px (default 5)")
    p.add_argument("--points", type=int, default=21, help="test points along X (default 21)")
    p.add_argument("--rows", help="rows of the test points, comma-separated (default: middle row)")
    _add_pinhole_codec_options(p)
    _add_decode_options(p)
    p.set_defaults(func=cmd_characterize)

    p = sub.add_parser("acceptance", help="VDI/VDE 2634-2 quantities from a capture of a plane, sphere or ball bar")
    p.add_argument("--rig", required=True)
    p.add_argument("--reference", help="capture of the reference plane (optional for flatness on a pinhole rig)")
    p.add_argument("--object", required=True, help="capture of the plane, the sphere or the two spheres")
    p.add_argument(
        "--test",
        required=True,
        choices=["flatness", "probing", "spacing"],
        help="flatness of a plane; probing error (form, size) of a sphere; spacing of two spheres",
    )
    p.add_argument("--diameter", type=float, help="probing: calibrated sphere diameter, mm")
    p.add_argument("--spacing", type=float, help="spacing: calibrated centre distance, mm")
    p.add_argument(
        "--min-height",
        type=float,
        default=1.0,
        help="probing/spacing: pixels this high above R belong to the spheres, mm (default 1)",
    )
    p.add_argument("--out", required=True, help="result JSON (with and without the 0.3 %% outlier rejection)")
    _add_pinhole_codec_options(p)
    _add_decode_options(p)
    p.set_defaults(func=cmd_acceptance)

    p = sub.add_parser("sensitivity", help="systematic-error curves of Eqs. 22-25 and Fig. 6")
    p.add_argument("--rig", required=True)
    p.add_argument("--param", choices=["L", "d", "alpha"], help="one parameter (default: all three)")
    p.add_argument("--z-mm", type=float, default=40.0, help="constant height of the study, mm (default 40)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_sensitivity)
    from metrology.commands import rig as rig_command
    from metrology.commands.agent import register as acquisition_commands

    acquisition_commands(sub)
    rig_command.register(sub)
    from metrology.commands import procam as procam_command

    procam_command.register(sub)
    from metrology.commands import gamma as gamma_command

    gamma_command.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from metrology.core.allocation import retain_freed_memory

    retain_freed_memory()  # frame-sized temporaries are reused instead of page-faulting again
    func: Callable[[argparse.Namespace], dict[str, Any]] = args.func
    try:
        summary = func(args)
    except BadInputError as exc:
        return _fail(str(exc))
    except (ValueError, OSError) as exc:  # RigError, StackError and file errors are ValueError/OSError
        return _fail(str(exc))
    if not args.quiet:
        print(json.dumps(summary))
    return 0


def _fail(message: str) -> int:
    line = " ".join(message.split())
    print(f"gcps: error: {line}", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
