"""`gcps measure` with a pinhole rig file (the one measure command): captures of any codec -> points,
depth or heights, sigma, mesh. Needs the codec package; skipped, saying so, without it."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import build_parser
from metrology.commands.common import BadInputError, load_model
from metrology.commands.measure import cmd_measure
from tests.pinhole_stacks import CODEC, RIG, cast_scene

codecs = pytest.importorskip("metrology.core.codecs", reason="the codec package (issue 11) is not in this tree")


def _capture(folder: Path, scene: str, **params: float) -> np.ndarray:
    truth = cast_scene(scene, 600.0, **params)
    codec = codecs.codec_from_dict(CODEC)
    images = codecs.render_codec(codec, truth.u, None)
    folder.mkdir()
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"frame_{i:02d}.png"), image)
    (folder / "codec.json").write_text(json.dumps(CODEC))
    return truth.points_mm


def _args(tmp: Path, **extra: object) -> argparse.Namespace:
    """The options of `gcps measure --rig tmp/rig.json` and ``extra`` (``--key value``), as parsed."""
    argv = ["measure", "--rig", str(tmp / "rig.json")]
    for key, value in extra.items():
        argv += [f"--{key.replace('_', '-')}", str(value)]
    return build_parser().parse_args(argv)


@pytest.mark.slow
def test_measure_with_pinhole_rig(tmp_path: Path) -> None:
    (tmp_path / "rig.json").write_text(RIG.to_json())
    assert load_model(str(tmp_path / "rig.json")).model == "pinhole"
    truth = _capture(tmp_path / "sphere", "sphere")
    _capture(tmp_path / "ref", "plane", z_mm=0.0)
    # depth, points, sigma, mesh, stats
    args = _args(
        tmp_path,
        object=tmp_path / "sphere",
        out=tmp_path / "z.npy",
        xyz=tmp_path / "xyz.npy",
        sigma=tmp_path / "s.npy",
        mesh=tmp_path / "m.ply",
        json=tmp_path / "stats.json",
    )
    summary = cmd_measure(args)
    assert summary["triangulate"] == "u" and summary["z"] == "depth (camera Z)"
    xyz = np.load(tmp_path / "xyz.npy")
    z = np.load(tmp_path / "z.npy")
    assert xyz.shape == (120, 160, 3) and xyz.dtype == np.float32
    ok = np.isfinite(z)
    assert ok.mean() > 0.5
    assert np.array_equal(z[ok], xyz[..., 2][ok])
    err = np.linalg.norm(xyz[ok] - truth[ok], axis=-1)
    # noise-free 16-bit: every valid point within 1 um (pixel (97, 88), on the sphere's occluding
    # edge, was once moved by two gray words by the slip repair)
    assert err.max() < 1e-3, err.max()
    sigma = np.load(tmp_path / "s.npy")
    assert np.isfinite(sigma[ok]).all() and np.all(sigma[ok] >= 0)
    # the PLY carries each vertex's sigma_mm (one vertex per measured pixel, row-major)
    raw = (tmp_path / "m.ply").read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    assert b"property float sigma_mm" in head
    n_vertices = int(head.split(b"element vertex ")[1].split(b"\n")[0])
    assert n_vertices == ok.sum()
    # binary little-endian vertices: double x y z, normals nx ny nz (open3d's double, once float),
    # then float sigma_mm; read with the types the header gives
    types = {b"double": "<f8", b"float": "<f4"}
    vertex_head = head.split(b"element vertex ")[1].split(b"element face")[0]
    props = [line.split()[1:] for line in vertex_head.split(b"\n") if line.startswith(b"property")]
    assert [name for _, name in props] == [b"x", b"y", b"z", b"nx", b"ny", b"nz", b"sigma_mm"]
    assert [kind for kind, _ in props][:3] == [b"double"] * 3 and props[-1][0] == b"float"
    vdtype = np.dtype([("xyz", types[props[0][0]], (3,)), ("n", types[props[3][0]], (3,)), ("s", "<f4")])
    vertices = np.frombuffer(body[: n_vertices * vdtype.itemsize], vdtype)
    assert np.array_equal(vertices["s"], sigma[ok])
    assert np.allclose(vertices["xyz"], xyz[ok])
    assert np.median(vertices["n"][:, 2]) < -0.5  # normals face the camera (-Z)
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(mesh.vertices) == n_vertices and len(mesh.triangles) > n_vertices // 2
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["rig"]["model"] == "pinhole"
    # the keys of the pinhole measure's JSON (a contract: commit ac75eb3's, others may be added)
    assert set(stats) >= {
        *("out", "model", "valid_pixels", "valid_fraction", "z", "triangulate", "method"),
        *("dropped_by_max_sigma", "z_mm", "sigma_mm_median", "reference_plane", "decoding", "options"),
        *("software_version", "timings_s", "rig"),
    }
    assert stats["sigma_mm_median"] > 0 and stats["reference_plane"] is None and stats["z_mm"]["min"] > 500
    # heights above the reference plate (Z = 600): the sphere's own heights
    args = _args(tmp_path, object=tmp_path / "sphere", reference=tmp_path / "ref", out=tmp_path / "h.npy")
    assert cmd_measure(args)["z"] == "height above the reference plane"
    h = np.load(tmp_path / "h.npy")
    assert np.abs(h[ok] - (600.0 - truth[..., 2][ok])).max() < 1e-3
    # --max-sigma drops everything above it
    args = _args(tmp_path, object=tmp_path / "sphere", out=tmp_path / "z2.npy", max_sigma=1e-9)
    assert cmd_measure(args)["valid_pixels"] == 0
    with pytest.raises(BadInputError, match="--max-sigma must be a positive number of mm, got -1"):
        cmd_measure(_args(tmp_path, object=tmp_path / "sphere", out=tmp_path / "z3.npy", max_sigma=-1))


def test_gcps_measure_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`gcps measure --rig PINHOLE.json` without --reference: depth, points and sigma; a crossed-axes
    rig still needs --reference (exit 2, one line)."""
    from metrology.cli import main

    (tmp_path / "rig.json").write_text(RIG.to_json())
    truth = _capture(tmp_path / "plane", "plane", z_mm=30.0)
    argv = ["measure", "--rig", str(tmp_path / "rig.json"), "--object", str(tmp_path / "plane")]
    argv += ["--out", str(tmp_path / "z.npy"), "--xyz", str(tmp_path / "xyz.npy"), "--sigma", str(tmp_path / "s.npy")]
    assert main([*argv, "--triangulate", "u", "--method", "midpoint"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["model"] == "pinhole" and summary["method"] == "midpoint"
    z = np.load(tmp_path / "z.npy")
    ok = np.isfinite(z)
    assert np.abs(z[ok] - truth[..., 2][ok]).max() < 1e-3
    # --json without sigma: sigma_mm_median is there, null
    json_argv = ["measure", "--rig", str(tmp_path / "rig.json"), "--object", str(tmp_path / "plane")]
    json_argv += ["--out", str(tmp_path / "z2.npy"), "--json", str(tmp_path / "stats.json")]
    assert main(["--quiet", *json_argv]) == 0
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["sigma_mm_median"] is None and stats["valid_pixels"] == ok.sum()
    crossed = Path(__file__).resolve().parents[2] / "examples" / "rig.json"
    argv = ["measure", "--rig", str(crossed), "--object", str(tmp_path / "plane"), "--out", str(tmp_path / "c.npy")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--reference is required: a crossed-axes rig measures against a capture of the reference plane" in err
