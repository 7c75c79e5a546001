"""``gcps measure`` with a pinhole rig file (docs/pinhole.md).

::

    gcps measure --rig PINHOLE.json --object OBJ [--reference REF] [--codec C] --out Z.npy
                 [--xyz XYZ.npy] [--sigma SIGMA.npy] [--mesh MESH.ply|.stl|.obj] [--json STATS.json]
                 [--triangulate auto|u|v] [--method plane|midpoint] [--max-sigma MM]

The ``measure`` command calls :func:`cmd_measure_pinhole` when :func:`is_pinhole_rig` says the
rig file is a pinhole one, and :func:`add_pinhole_measure_arguments` adds the options above
that it does not have yet (``--reference`` is optional for pinhole rigs). Captures are read and
decoded with their codec (``--codec``, else the capture's ``codec.json``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any


def add_pinhole_measure_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``gcps measure`` for pinhole rigs: --xyz, --sigma, --triangulate, --method, --max-sigma."""
    group = parser.add_argument_group("pinhole rigs (docs/pinhole.md)")
    group.add_argument(
        "--xyz",
        help="points (H, W, 3) float32 mm, NaN where not measured (.npy): camera frame (pinhole), "
        "the paper's frame X_H, Y_H, z (crossed axes)",
    )
    group.add_argument("--sigma", help="per-point standard uncertainty (H, W) float32 mm (.npy)")
    group.add_argument(
        "--triangulate", choices=["auto", "u", "v"], default="auto", help="projector axis to triangulate (default auto)"
    )
    group.add_argument(
        "--method", dest="triangulation_method", choices=["plane", "midpoint"], default="plane", help="default plane"
    )
    group.add_argument("--max-sigma", type=float, metavar="MM", help="drop points whose sigma exceeds this, mm")
    if "--codec" not in parser._option_string_actions:  # the codec commands may add it already
        group.add_argument(
            "--codec", help="codec file (gcps-codec/1) or built-in name; default: the capture's codec.json"
        )


def is_pinhole_rig(path: str) -> bool:
    """True when the rig file at ``path`` is a JSON object with ``"model": "pinhole"``."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and data.get("model") == "pinhole"


def _check_out(path: str | None, suffixes: tuple[str, ...], option: str) -> None:
    if path is None:
        return
    if Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"{option} {path}: extension must be {' or '.join(suffixes)}")
    if not Path(path).resolve().parent.is_dir():
        raise ValueError(f"{option} {path}: folder {Path(path).resolve().parent} does not exist")


def final_stage_sigma(codec: Any, axis: str, noise: Any, modulation: Any) -> Any:
    """:func:`metrology.pipeline.measure_pinhole.final_stage_sigma` (kept here for its callers)."""
    from metrology.pipeline.measure_pinhole import final_stage_sigma as pipeline_sigma

    return pipeline_sigma(codec, axis, noise, modulation)


def cmd_measure_pinhole(args: argparse.Namespace) -> dict[str, Any]:
    """Read the captures, call the pipeline's :func:`~metrology.pipeline.measure_pinhole.measure_pinhole_stacks`
    (shared with the measurement job), write the outputs of a pinhole ``gcps measure``; the summary."""
    import numpy as np

    from metrology.core.codecs import builtin_codec, read_codec
    from metrology.core.codecs.stack import read_codec_stack
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.core.io import atomic_path
    from metrology.pipeline.measure_pinhole import PinholeMeasureOptions, measure_pinhole_stacks

    _check_out(args.out, (".npy",), "--out")
    _check_out(getattr(args, "xyz", None), (".npy",), "--xyz")
    _check_out(getattr(args, "sigma", None), (".npy",), "--sigma")
    _check_out(getattr(args, "mesh", None), (".ply", ".stl", ".obj"), "--mesh")
    _check_out(getattr(args, "json", None), (".json",), "--json")
    max_sigma = getattr(args, "max_sigma", None)
    if max_sigma is not None and not max_sigma > 0:
        raise ValueError(f"--max-sigma must be > 0 mm, got {max_sigma!r}")
    asked_sigma = bool(getattr(args, "sigma", None)) or max_sigma is not None
    ply_mesh = bool(getattr(args, "mesh", None)) and Path(args.mesh).suffix.lower() == ".ply"
    options = PinholeMeasureOptions(
        triangulate=getattr(args, "triangulate", "auto"),
        method=getattr(args, "triangulation_method", "plane"),
        sigma=asked_sigma,
        max_sigma_mm=max_sigma,
    )
    started = time.perf_counter()
    rig = PinholeRig.from_json(Path(args.rig).read_text(encoding="utf-8"))
    codec = None
    if getattr(args, "codec", None):
        codec = read_codec(args.codec) if Path(args.codec).is_file() else builtin_codec(args.codec)
    obj = read_codec_stack(args.object, codec)
    ref = read_codec_stack(args.reference, obj.codec) if getattr(args, "reference", None) else None
    read_s = time.perf_counter() - started
    result = None
    if ply_mesh and not asked_sigma:  # a PLY mesh carries sigma_mm per vertex when it can
        try:
            result = measure_pinhole_stacks(
                rig,
                None if ref is None else ref.images,
                obj.images,
                obj.codec,
                PinholeMeasureOptions(triangulate=options.triangulate, method=options.method, sigma=True),
            )
        except ValueError as exc:
            if "sigma needs" not in str(exc):
                raise
    if result is None:
        result = measure_pinhole_stacks(rig, None if ref is None else ref.images, obj.images, obj.codec, options)
    points, z, sigma_mm = result.points_mm, result.z_mm, result.sigma_mm
    mesh = _mesh(points) if getattr(args, "mesh", None) else None
    sigma_ply = mesh is not None and sigma_mm is not None and ply_mesh
    with atomic_path(args.out) as tmp:
        np.save(tmp, z)
    if getattr(args, "xyz", None):
        with atomic_path(args.xyz) as tmp:
            np.save(tmp, points)
    if getattr(args, "sigma", None) and sigma_mm is not None:
        with atomic_path(args.sigma) as tmp:
            np.save(tmp, sigma_mm)
    if mesh is not None and sigma_ply:
        assert sigma_mm is not None
        with atomic_path(args.mesh) as tmp:
            write_ply_with_sigma(mesh, sigma_mm[np.isfinite(points[..., 2])], tmp)
    elif mesh is not None:
        from metrology.core.mesh import write_mesh

        write_mesh(mesh, args.mesh)
    valid = int(np.isfinite(z).sum())
    stats: dict[str, Any] = {
        "out": args.out,
        "model": "pinhole",
        "valid_pixels": valid,
        "valid_fraction": valid / z.size,
        "z": result.z_meaning,
        "triangulate": result.axis,
        "method": result.method,
        "dropped_by_max_sigma": result.dropped_by_max_sigma,
    }
    if getattr(args, "json", None):
        finite = z[np.isfinite(z)]
        data = result.to_dict()
        details = {
            **stats,
            "z_mm": {
                "min": float(finite.min()) if finite.size else None,
                "max": float(finite.max()) if finite.size else None,
                "mean": float(finite.mean()) if finite.size else None,
            },
            "sigma_mm_median": data["statistics"].get("sigma_mm_median"),
            "reference_plane": data["reference_plane"],
            "decoding": data["decoding"],
            "options": data["options"],
            "software_version": data["software_version"],
            "timings_s": {"read": read_s, **{k: round(v, 6) for k, v in result.timings_s.items()}},
            "rig": rig.to_dict(),
        }
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(details, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return stats


def write_ply_with_sigma(mesh: Any, sigma_mm: Any, path: Path) -> None:
    """Binary little-endian PLY of ``mesh`` with a per-vertex ``sigma_mm`` float property.

    Vertices: ``double x y z``, ``float nx ny nz``, ``float sigma_mm`` (the point's standard
    uncertainty, mm, NaN where unknown); faces: ``list uchar int vertex_indices``.
    """
    import numpy as np

    vertices = np.asarray(mesh.vertices)
    normals = np.asarray(mesh.vertex_normals) if mesh.has_vertex_normals() else np.zeros_like(vertices)
    triangles = np.asarray(mesh.triangles, dtype=np.int32)
    sigma = np.asarray(sigma_mm, dtype=np.float32).ravel()
    if sigma.size != len(vertices):
        raise ValueError(f"sigma_mm has {sigma.size} values for {len(vertices)} vertices")
    vdtype = np.dtype(
        [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"), ("s", "<f4")]
    )
    vrec = np.empty(len(vertices), vdtype)
    vrec["x"], vrec["y"], vrec["z"] = vertices.T
    vrec["nx"], vrec["ny"], vrec["nz"] = normals.T
    vrec["s"] = sigma
    frec = np.empty(len(triangles), np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    frec["n"] = 3
    frec["i"] = triangles
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment gcps-lab pinhole measurement, camera frame, mm\n"
        f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
        "property float nx\nproperty float ny\nproperty float nz\nproperty float sigma_mm\n"
        f"element face {len(triangles)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vrec.tobytes())
        f.write(frec.tobytes())


def _mesh(points: Any) -> Any:
    """Triangle mesh of a grid of camera-frame points: neighbouring valid pixels joined (no
    triangle across a depth step of more than 20 pixel footprints), normals towards the camera."""
    import numpy as np
    import open3d as o3d

    from metrology.core.mesh import grid_triangles

    z = points[..., 2].astype(np.float64)
    valid = np.isfinite(z)
    if not valid.any():
        raise ValueError("nothing was measured: no mesh to write")
    footprint = float(np.nanmedian(np.linalg.norm(np.diff(points, axis=1), axis=-1)))
    triangles = grid_triangles(valid, z, 20 * footprint if np.isfinite(footprint) else np.inf)
    triangles = np.ascontiguousarray(triangles[:, ::-1])  # camera frame: Y down, so reverse to face the camera
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(points[valid].astype(np.float64)), o3d.utility.Vector3iVector(triangles)
    )
    mesh.compute_triangle_normals()
    mesh.compute_vertex_normals()
    return mesh
