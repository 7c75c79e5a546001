"""``gcps measure``: heights or depths, points, sigma and a mesh of an object capture, for a rig file
of any model and captures of any codec (docs/command-line.md, docs/pinhole.md).

::

    gcps measure --rig RIG.json --object OBJ [--reference REF] [--codec C] [--out Z.npy]
                 [--xyz XYZ.npy] [--sigma SIGMA.npy] [--mesh MESH.ply|.stl|.obj] [--json STATS.json]
                 [--max-sigma MM] [--triangulate auto|u|v] [--method plane|midpoint] [--match epipolar|2d]
                 [decoding options]

``--reference`` is required by a model that measures against the reference plane (the
crossed-axes rig); without one a pinhole or stereo rig gives depths (camera Z). A stereo rig's
captures hold one stack per camera (``cam0/``, ``cam1/``; docs/stereo.md). At least one of
``--out`` and ``--xyz`` is given. The captures' codec is
``--codec``, else their ``codec.json``, else gcps-v1 (the eleven named patterns). The command
reads its inputs, calls the pipeline's :func:`~metrology.pipeline.measure.measure` (as the
measurement job does) and writes its outputs, each atomically, only once all are computed.
"""

from __future__ import annotations

import argparse
import contextlib
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from metrology.commands.common import (
    BadInputError,
    add_measure_options,
    captures_codec,
    check_output,
    load_model,
    measure_options,
    read_capture,
    write_json,
)

if TYPE_CHECKING:
    from metrology.core.codecs.model import Codec
    from metrology.core.geometry.base import GeometryModel, GeometryOptions
    from metrology.core.measure import MeasureOptions, Reference

T = TypeVar("T")

MESH_SUFFIXES = (".ply", ".stl", ".obj")
READER = "gcps-measure/read_capture/1"
"""The reader of a kept reference's key (:func:`~metrology.core.reference_cache.files_reference_key`):
how ``gcps measure`` turns a capture's files into frames (:func:`read_capture`)."""


def register(subparsers: Any) -> None:
    """Add ``measure`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("measure", help="heights or depths, points and a mesh of an object")
    p.add_argument("--rig", required=True, help="rig file of any model (docs/file-formats.md, docs/pinhole.md)")
    p.add_argument(
        "--reference",
        help="capture of the reference plane (folder or .zip); required where the rig's model needs one",
    )
    p.add_argument("--object", required=True, help="capture of the object (folder or .zip)")
    p.add_argument("--out", help="heights (or depths), float32 mm, NaN where not measured (.npy)")
    p.add_argument(
        "--xyz",
        help="points (H, W, 3) float32 mm in the model frame (a stereo rig: camera 0's), NaN where not measured (.npy)",
    )
    p.add_argument("--sigma", help="per-point standard uncertainty (H, W) float32 mm (.npy)")
    p.add_argument("--max-sigma", type=float, metavar="MM", help="drop points whose sigma exceeds this, mm")
    p.add_argument("--mesh", help="mesh output (.ply, .stl or .obj); a PLY carries sigma_mm per vertex when known")
    p.add_argument("--json", help="statistics, options and timings (.json)")
    p.add_argument(
        "--codec",
        help="codec file (gcps-codec/1) or built-in name of both captures (default: their codec.json, else gcps-v1)",
    )
    p.add_argument(
        "--allow-inconsistent-codec",
        action="store_true",
        help="measure even when the codec self-check finds the object inconsistent with its codec (docs/codecs.md)",
    )
    add_measure_options(p)
    p.set_defaults(func=cmd_measure)


def prepare_while_reading(
    model: GeometryModel, projector_size: tuple[float, float] | None, geometry: GeometryOptions
) -> threading.Thread:
    """Prepare ``model`` (its per-pixel tables: a distorted rig's undistortion, its epipolar table)
    on a thread, while the caller reads the captures: both wait mostly outside the GIL (OpenCV's
    image decoding, numpy), so on two cores the first measurement of a rig costs about the longer
    of the two instead of their sum. The caller joins the thread before measuring, so the
    pipeline's own ``prepare`` finds the prepared model in the model's cache. A failure here is
    left for the pipeline to raise, with its message, in the caller's thread."""

    def run() -> None:
        with contextlib.suppress(Exception):
            model.prepare(model.shape, projector_size, geometry)

    thread = threading.Thread(target=run, name="gcps-prepare", daemon=True)
    thread.start()
    return thread


def keyed_by_files(path: str, model: GeometryModel) -> bool:
    """Whether the reference capture at ``path`` is kept by its files' digest: any capture that
    exists, but a multi-exposure one on a one-camera rig (whose frames decide how the object is
    measured: read first, kept by its frames' digest)."""
    if not Path(path).exists():
        return False  # read_capture says so
    return model.cameras > 1 or not is_exposures(path, model)


def is_exposures(path: str, model: GeometryModel) -> bool:
    """Whether :func:`read_capture` reads the capture at ``path`` as a multi-exposure capture (a
    one-camera rig, ``exposures.json`` at its top); False where it would fail (it says why)."""
    from metrology.core.codecs.stack import is_exposure_capture

    if model.cameras > 1 or not Path(path).exists():
        return False
    try:
        return is_exposure_capture(path)
    except ValueError:
        return False


def on_thread(name: str, func: Callable[..., T], *args: Any) -> Future[T]:
    """``func(*args)`` started now on a thread of its own, named ``name``, while the caller goes on
    (a one-thread pool that ends with the call): what ``gcps measure`` reads and hashes beside its
    imports and beside each other."""
    pool = ThreadPoolExecutor(1, thread_name_prefix=name)
    try:
        return pool.submit(func, *args)
    finally:
        pool.shutdown(wait=False)


def read_early(path: str) -> Future[Any] | None:
    """The capture at ``path`` read as a gcps-v1 stack (:func:`~metrology.core.io.read_stack`, no
    rig: any frame size), started now on a thread, before the rig and the codec are known: its
    PNGs are decoded outside the GIL while the caller's thread imports the geometric models and
    reads the rig. :func:`read_object` takes it where it is what :func:`read_capture` would read,
    and reads the capture again otherwise (its errors then raised by :func:`read_capture`, as
    before). None where ``path`` does not exist."""
    if not Path(path).exists():
        return None

    def read() -> Any:
        from metrology.core.io.stacks import read_stack

        return read_stack(path).images

    return on_thread("gcps-early", read)


def digest_early(path: str | None) -> Future[str] | None:
    """The files digest of the reference capture at ``path``
    (:func:`~metrology.core.io.digests.capture_files_digest`: the kept reference's key), started now
    on a thread, so that the files are hashed (outside the GIL) while the caller's thread imports
    the measurement's modules; its errors are raised where it is taken. None where there is no
    reference or nothing at ``path`` (read_capture then says so)."""
    if path is None or not Path(path).exists():
        return None

    def digest() -> str:
        from metrology.core.io.digests import capture_files_digest

        return capture_files_digest(path)

    return on_thread("gcps-digest", digest)


def read_object(
    early: Future[Any] | None, path: str, codec: Codec | None, model: GeometryModel, exposures: bool
) -> Any:
    """The object's frames, as :func:`read_capture` reads them: the early read (:func:`read_early`)
    where the capture is a one-camera gcps-v1 stack of the rig's frame size, not a multi-exposure
    capture (``exposures``: :func:`is_exposures` of ``path``; :func:`read_capture` then reads
    :func:`~metrology.core.io.read_stack` with the rig's shape checked); else, or where the early
    read failed, :func:`read_capture`."""
    from metrology.core.codecs.model import is_gcps_v1

    if early is not None and model.cameras == 1 and is_gcps_v1(codec) and not exposures:
        try:
            images = early.result()
        except Exception:
            images = None
        if images is not None and tuple(images.shape[1:]) == tuple(model.shape):
            return images
    return read_capture(path, codec, model, "object")


def cmd_measure(args: argparse.Namespace) -> dict[str, Any]:
    """Read the rig and the captures, measure (the pipeline), write the outputs; the summary."""
    from metrology.version import software_version_soon

    software_version_soon()  # the kept reference's key and the result carry it: git runs beside the imports
    if not (args.out or args.xyz):
        raise BadInputError("give --out (heights or depths) or --xyz (points), or both")
    check_output(args.out, (".npy",), "--out")
    check_output(args.xyz, (".npy",), "--xyz")
    check_output(args.sigma, (".npy",), "--sigma")
    check_output(args.mesh, MESH_SUFFIXES, "--mesh")
    check_output(args.json, (".json",), "--json")
    if args.max_sigma is not None and not (0 < args.max_sigma < float("inf")):
        raise BadInputError(f"--max-sigma must be a positive number of mm, got {args.max_sigma!r}")
    asked_sigma = bool(args.sigma) or args.max_sigma is not None
    ply_mesh = bool(args.mesh) and args.mesh.lower().endswith(".ply")
    early_object = read_early(args.object)
    early_digest = digest_early(args.reference)
    started = time.perf_counter()
    model = load_model(args.rig)
    if args.reference is None and model.requires_reference:
        raise BadInputError(
            f"--reference is required: a {model.short_label} rig measures against a capture of the reference plane"
        )
    codec = captures_codec(args.codec, [("reference", args.reference), ("object", args.object)])
    # the object's PNGs are decoded (outside the GIL) while this thread imports the measurement's
    # modules below: on two cores the imports cost little wall time beside the reading; a read error
    # is raised where the object is taken, as before. A gcps-v1 stack has been read since the start
    # (read_early), while this thread imported the models and read the rig.
    object_exposures = is_exposures(args.object, model)
    object_read = on_thread("gcps-object", read_object, early_object, args.object, codec, model, object_exposures)

    import numpy as np

    from metrology.core.codecs.check import summary_of
    from metrology.core.io import atomic_path, write_height_npy
    from metrology.core.measure import exposure_inputs, uses_fused_gcps_v1
    from metrology.core.reference_cache import cached_reference, cached_reference_of_files
    from metrology.core.tiling import run_beside
    from metrology.pipeline.measure import measure

    options = measure_options(
        args,
        gray_only=bool(args.json),
        sigma=asked_sigma,
        max_sigma_mm=args.max_sigma,
        allow_inconsistent_codec=args.allow_inconsistent_codec,
    )
    preparing = None
    if uses_fused_gcps_v1(model, codec):  # the fused kernel takes light codes: no projector size
        preparing = prepare_while_reading(model, None, options.geometry)
    elif codec is not None:
        preparing = prepare_while_reading(model, (codec.projector_width, codec.projector_height), options.geometry)
    reference_path = args.reference
    by_files = reference_path is not None and keyed_by_files(reference_path, model)
    reference_cache: dict[str, Any] | None = None
    captured: list[Any] = []  # the object as read
    read_frames: list[Any] = []

    def read_reference() -> Any:
        """The reference's frames as the measurement takes them (read once, on a miss of the cache)."""
        if not read_frames:
            images = read_capture(str(reference_path), codec, model, "reference")
            read_frames.append(exposure_inputs(captured[0] if captured else None, images, codec)[1])
        return read_frames[0]

    def reference_for(opts: MeasureOptions, measure_codec: Codec | None) -> Reference | None:
        """The decoded reference, from the local cache when a process decoded it before
        (docs/command-line.md, "Kept references"): keyed by the capture's files, so that a hit
        reads no image."""
        nonlocal reference_cache
        if reference_path is None:
            return None
        if by_files:
            reader = {
                "reader": READER,
                "codec": None if codec is None else codec.to_dict(),
                "object_exposures": object_exposures,
            }
            kept, reference_cache = cached_reference_of_files(
                model,
                reference_path,
                read_reference,
                reader,
                measure_codec,
                opts,
                digest=None if early_digest is None else early_digest.result,
            )
        else:
            assert reference_images is not None
            kept, reference_cache = cached_reference(model, reference_images, measure_codec, opts)
        return kept

    # the kept reference is loaded (or read and decoded) on a thread while the object is read, when
    # neither is a multi-exposure capture (the codec is then the captures')
    early = by_files and not object_exposures and not (ply_mesh and not asked_sigma)
    kept_early = on_thread("gcps-reference", reference_for, options, codec) if early else None
    obj = object_read.result()
    captured.append(obj)
    reference_images = None
    if reference_path is not None and not by_files:
        reference_images = read_capture(reference_path, codec, model, "reference")
    if preparing is not None:
        preparing.join()  # the prepared model is in the model's cache: measure() finds it there
    # a multi-exposure capture takes both through the codec path: the kept reference too
    obj, reference_images, measure_codec = exposure_inputs(obj, reference_images, codec)
    read_s = time.perf_counter() - started
    if kept_early is not None:
        assert measure_codec is codec
        kept = kept_early.result()
        read_s = time.perf_counter() - started  # the reference's too, read beside the object's

    result = None
    if ply_mesh and not asked_sigma:  # a PLY mesh carries sigma_mm per vertex when the codec gives it
        try:
            reference = reference_for(options.with_sigma(), measure_codec)
            result = measure(model, reference, obj, options.with_sigma(), codec=measure_codec)
        except ValueError as exc:
            if "uncertainty" not in str(exc):
                raise
    if result is None:
        reference = kept if kept_early is not None else reference_for(options, measure_codec)
        result = measure(model, reference, obj, options, codec=measure_codec)
    measurement = result.measurement
    z = result.z_mm
    pending_stats = run_beside(result.statistics)  # on a pool thread while the outputs are written
    points = measurement.points_mm() if (args.xyz or args.mesh) else None
    mesh = None
    if args.mesh:
        from metrology.core.mesh import surface_mesh, write_mesh_file

        reference_surface = None if measurement.reference is None else measurement.reference.surface
        mesh = surface_mesh(model, z, points_mm=points, reference=reference_surface)
        if ply_mesh and result.sigma_mm is not None:
            assert points is not None
            mesh = mesh.with_sigma(result.sigma_mm, np.isfinite(z) & np.isfinite(points).all(axis=-1))
        exposure = measurement.exposure_map()
        if ply_mesh and exposure is not None:  # a multi-exposure object: the exposure of each vertex
            assert points is not None
            mesh = mesh.with_exposure(exposure, np.isfinite(z) & np.isfinite(points).all(axis=-1))
        pairs = measurement.pairs_map()
        if ply_mesh and pairs is not None:  # a stereo rig: the pairs that measured each vertex
            assert points is not None
            mesh = mesh.with_pairs(pairs, np.isfinite(z) & np.isfinite(points).all(axis=-1))

    if args.out:
        write_height_npy(z, args.out)
    if args.xyz:
        assert points is not None
        points[~np.isfinite(z)] = np.nan  # NaN exactly where z is
        with atomic_path(args.xyz) as tmp:
            np.save(tmp, points)
    if args.sigma and result.sigma_mm is not None:
        with atomic_path(args.sigma) as tmp:
            np.save(tmp, result.sigma_mm)
    if mesh is not None:
        write_mesh_file(mesh, args.mesh)
    stats = pending_stats()
    summary: dict[str, Any] = {
        "out": args.out,
        "xyz": args.xyz,
        **{key: value for key, value in stats.items() if key != "gray_only" and not key.endswith("_mm")},
    }
    if asked_sigma or result.sigma_mm is not None:
        summary["sigma_mm_median"] = stats.get("sigma_mm_median")
    summary["codec_check"] = summary_of(measurement.codec_check)
    exposures = None if measurement.decoding is None else measurement.decoding.exposure_summary()
    if exposures is not None:  # a multi-exposure object: the pixels each exposure measured
        summary["exposures"] = exposures
    if args.json:
        data = result.to_dict()
        gray = stats.get("gray_only") or {}
        finite = z[np.isfinite(z)]
        report = {
            **summary,
            **{key: value for key, value in stats.items() if key != "gray_only"},
            "sigma_mm_median": stats.get("sigma_mm_median"),  # null when sigma was not computed
            "z_mm": {
                "min": float(finite.min()) if finite.size else None,
                "max": float(finite.max()) if finite.size else None,
                "mean": float(finite.mean()) if finite.size else None,
            },
            "gray_only_valid_pixels": gray.get("valid_pixels"),
            "gray_only": gray or None,
            "reference_plane": data["reference_plane"],
            "timings_s": {
                "read_s": read_s + (reference_cache or {}).get("read_s", 0.0),  # a missed reference's read too
                **result.timings_s,
                **_reference_timings(reference_cache),
            },
            "reference_cache": reference_cache,
            "options": options.to_dict(),  # as asked (a PLY mesh's sigma is computed beside them)
            "software_version": result.software_version,
            "rig": model.to_dict(),
            "codec": result.codec_name if measure_codec is None else measure_codec.to_dict(),
            "codec_check": summary["codec_check"],
        }
        if "decoding" in data:
            report["decoding"] = data["decoding"]
        write_json(report, args.json)
    return summary


def _reference_timings(report: dict[str, Any] | None) -> dict[str, float]:
    """The reference's share of the timings: its decode (``measure.reference_decode_s``, as when the
    measurement decodes it) on a miss of the local cache, the read of the kept one on a hit."""
    if report is None:
        return {}
    if report["hit"]:
        return {"reference_cache_s": report["hash_s"] + report["load_s"]}
    return {"measure.reference_decode_s": report["decode_s"], "reference_cache_s": report["hash_s"]}
