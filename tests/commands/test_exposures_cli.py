"""``gcps decode`` and ``gcps measure`` on multi-exposure captures (issue 26, docs/exposures.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.exposures import NO_EXPOSURE, decode_exposures
from metrology.core.codecs.stack import read_exposure_stack, write_exposure_stack
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.io import write_stack
from metrology.core.io.exposures import Exposure
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, SimulationOptions
from metrology.core.simulate.exposures import render_exposures
from tests.pinhole_stacks import CODEC, RIG

EXPOSURES = (Exposure("exp0", 1000.0), Exposure("exp1", 10000.0), Exposure("exp2", 100000.0))
SMALL_PAPER_RIG = PAPER_RIG.with_parameters(width_px=160, height_px=120, fw_mm=160 * 0.78125)


def run(*args: str) -> int:
    return main(["--quiet", *args])


@pytest.fixture(scope="module")
def hdr_capture(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """The pinhole test rig's HDR plane (a specular patch on a dark matte part), three exposures, as a zip."""
    codec = codec_from_dict(CODEC)
    rendered = render_exposures(
        RIG,
        make_scene("plane"),
        EXPOSURES,
        codec,
        SimulationOptions(),
        placement=ScenePlacement.facing_camera(600.0),
    )
    root = tmp_path_factory.mktemp("hdr")
    return write_exposure_stack(rendered.stack, root / "hdr.zip", codec), rendered


def test_decode_quality_has_exposure_maps_and_the_summary_counts_them(
    hdr_capture: tuple[Path, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    archive, rendered = hdr_capture
    out, quality = tmp_path / "uv.npy", tmp_path / "q.npz"
    assert main(["decode", "--stack", str(archive), "--out", str(out), "--quality", str(quality)]) == 0
    summary = json.loads(capsys.readouterr().out)
    q = np.load(quality)
    assert q["exposure_u"].dtype == np.uint8 and q["exposure_u"].shape == (120, 160)
    read = read_exposure_stack(archive)
    fused = decode_exposures(read.stack, read.codec)
    np.testing.assert_array_equal(q["exposure_u"], fused.exposure["u"])
    np.testing.assert_array_equal(np.load(out)[..., 0], fused.axes["u"].coordinate)
    pixels = summary["exposures"]["pixels"]["u"]
    assert summary["exposures"]["names"] == ["exp0", "exp1", "exp2"]
    for index, name in enumerate(summary["exposures"]["names"]):
        assert pixels[name] == int(np.count_nonzero(q["exposure_u"] == index)) > 0
    assert pixels["none"] == int(np.count_nonzero(q["exposure_u"] == NO_EXPOSURE))
    lit = rendered.truth.lit
    assert np.isfinite(np.load(out)[..., 0])[lit].mean() > 0.99


def test_measure_multi_exposure_object_with_a_pinhole_rig(hdr_capture: tuple[Path, Any], tmp_path: Path) -> None:
    archive, rendered = hdr_capture
    (tmp_path / "rig.json").write_text(RIG.to_json())
    xyz, stats = tmp_path / "xyz.npy", tmp_path / "stats.json"
    argv = ["measure", "--rig", str(tmp_path / "rig.json"), "--object", str(archive), "--out", str(tmp_path / "z.npy")]
    mesh = tmp_path / "mesh.ply"
    assert run(*argv, "--xyz", str(xyz), "--json", str(stats), "--mesh", str(mesh)) == 0
    points = np.load(xyz).astype(np.float64)
    ok = np.isfinite(points[..., 2]) & rendered.truth.lit
    assert ok.mean() > 0.9
    assert np.linalg.norm(points - rendered.truth.points_mm, axis=-1)[ok].max() < 1e-3
    report = json.loads(stats.read_text())
    assert report["exposures"]["names"] == ["exp0", "exp1", "exp2"]
    assert report["decoding"]["exposures"]["pixels"]["u"]["exp2"] > 0
    # the measured points per exposure: every measured point counted once, each exposure measures some
    per_exposure = report["points_per_exposure"]
    assert sum(per_exposure.values()) == report["valid_pixels"] == int(np.isfinite(points[..., 2]).sum())
    assert min(per_exposure.values()) > 0
    header = mesh.read_bytes().partition(b"end_header")[0]
    assert b"property uchar exposure" in header  # the PLY carries each vertex's exposure


@pytest.mark.parametrize("multi", ["object", "reference"])
def test_measure_gcps_v1_multi_and_single_exposure_on_a_crossed_axes_rig(tmp_path: Path, multi: str) -> None:
    """Either capture may be single-exposure; the heights equal the single stacks' (fused kernel)."""
    exposures = (Exposure("short", 1000.0), Exposure("long", 2000.0))
    rig = SMALL_PAPER_RIG
    (tmp_path / "rig.json").write_text(json.dumps(rig.to_dict()))
    captures = {}
    for what, scene in (("object", "sphere"), ("reference", "reference")):
        rendered = render_exposures(rig, make_scene(scene, rig), exposures, None, SimulationOptions())
        write_stack(rendered.stack.images[0], tmp_path / f"{what}-single")
        write_exposure_stack(rendered.stack, tmp_path / f"{what}-multi")
        captures[what] = tmp_path / f"{what}-{'multi' if what == multi else 'single'}"

    def heights(obj: Path, ref: Path, out: Path) -> np.ndarray:
        argv = ["measure", "--rig", str(tmp_path / "rig.json"), "--object", str(obj), "--reference", str(ref)]
        assert run(*argv, "--out", str(out)) == 0
        return np.load(out)

    mixed = heights(captures["object"], captures["reference"], tmp_path / "mixed.npy")
    single = heights(tmp_path / "object-single", tmp_path / "reference-single", tmp_path / "single.npy")
    both = np.isfinite(mixed) & np.isfinite(single)
    assert both.sum() > 0.8 * np.isfinite(single).sum()
    assert np.abs(mixed[both] - single[both]).max() < 1e-3


def test_decode_refuses_a_bad_manifest_naming_it(
    hdr_capture: tuple[Path, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    archive, _ = hdr_capture
    folder = tmp_path / "cap"
    read = read_exposure_stack(archive)
    write_exposure_stack(read.stack, folder, read.codec)
    doc = json.loads((folder / "exposures.json").read_text())
    doc["exposures"][1]["iso"] = 100
    (folder / "exposures.json").write_text(json.dumps(doc))
    assert run("decode", "--stack", str(folder), "--out", str(tmp_path / "uv.npy")) == 2
    err = capsys.readouterr().err
    assert "exposures.json exposure 'exp1' has unknown key(s) iso" in err
    assert not (tmp_path / "uv.npy").exists()
