"""``gcps measure`` on a stereo rig's multi-exposure capture (issues 24 and 26, docs/exposures.md
"Stereo rigs"): ``exposures.json`` at the top and ``cam0/exp0/`` ... ``cam1/exp2/``, written and
read back exactly; measured through the command as the core measures it; errors name the camera
and the exposure."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs.stack import ExposureStack, read_camera_stacks, write_camera_stacks
from metrology.core.io.errors import StackError
from metrology.core.measure import measure
from metrology.core.scenes import make_scene
from metrology.core.simulate.exposures import render_stereo_exposures
from tests.core.exposure_scene import EXPOSURES
from tests.stereo_rig import PLACEMENT, PROJECTOR, RIG, codec

CODEC = codec("u")


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    """The noise-free 16-bit HDR plane seen by both cameras at three exposures, as a folder and a zip."""
    rendered = render_stereo_exposures(
        RIG, make_scene("plane", z_mm=0.0), EXPOSURES, CODEC, placement=PLACEMENT, projector=PROJECTOR
    )
    root = tmp_path_factory.mktemp("stereo-hdr")
    (root / "rig.json").write_text(RIG.to_json())
    write_camera_stacks(rendered.stacks, root / "object", CODEC)
    write_camera_stacks(rendered.stacks, root / "object.zip", CODEC)
    return root, rendered


def test_the_layout_reads_back_exactly(written: tuple[Path, Any]) -> None:
    root, rendered = written
    assert (root / "object" / "exposures.json").is_file() and (root / "object" / "cam1" / "exp2").is_dir()
    for source in (root / "object", root / "object.zip"):
        read = read_camera_stacks(source)
        assert read.exposures == rendered.stacks[0].exposures and read.bit_depth == 16
        assert read.frame_shapes == RIG.camera_shapes
        for got, want in zip(read.stacks, rendered.stacks, strict=True):
            assert isinstance(got, ExposureStack)
            for a, b in zip(got.images, want.images, strict=True):
                np.testing.assert_array_equal(a, b)


def test_gcps_measure_reads_and_measures_it(
    written: tuple[Path, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root, rendered = written
    xyz, stats = tmp_path / "xyz.npy", tmp_path / "stats.json"
    argv = ["measure", "--rig", str(root / "rig.json"), "--object", str(root / "object.zip")]
    assert main([*argv, "--xyz", str(xyz), "--mesh", str(tmp_path / "m.ply"), "--json", str(stats)]) == 0
    summary = json.loads(capsys.readouterr().out)
    core = measure(RIG, rendered.stacks, CODEC)
    np.testing.assert_array_equal(np.load(xyz), np.where(np.isfinite(core.z_mm)[..., None], core.points_mm(), np.nan))
    assert summary["exposures"]["names"] == ["exp0", "exp1", "exp2"]
    report = json.loads(stats.read_text())
    assert report["points_per_exposure"] == core.points_per_exposure()
    assert sum(report["points_per_exposure"].values()) == report["valid_pixels"]
    assert report["camera_pixels_per_exposure"]["cam1"] == core.camera_pixels_per_exposure(1)
    assert b"exposure" in (tmp_path / "m.ply").read_bytes()[:2000]  # the PLY's per-vertex exposure


def test_an_exposure_missing_in_one_camera_is_named(written: tuple[Path, Any], tmp_path: Path) -> None:
    root, _ = written
    broken = tmp_path / "broken"
    shutil.copytree(root / "object", broken)
    shutil.rmtree(broken / "cam1" / "exp1")
    with pytest.raises(StackError, match=r"camera 1: capture 'broken'/cam1 has no folder exp1/ for exposure 'exp1'"):
        read_camera_stacks(broken)
    (tmp_path / "rig.json").write_text(RIG.to_json())
    code = main(
        [
            "--quiet",
            "measure",
            "--rig",
            str(tmp_path / "rig.json"),
            "--object",
            str(broken),
            "--xyz",
            str(tmp_path / "x.npy"),
        ]
    )
    assert code == 2


def test_cameras_of_different_exposures_are_not_written(written: tuple[Path, Any], tmp_path: Path) -> None:
    _, rendered = written
    with pytest.raises(ValueError, match="same exposures for every camera"):
        write_camera_stacks((rendered.stacks[0], rendered.stacks[1].images[0]), tmp_path / "mixed.zip", CODEC)
