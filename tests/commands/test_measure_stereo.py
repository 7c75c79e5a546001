"""``gcps measure`` with a stereo rig file (issue 24's contract) and the captures of two cameras:
``--xyz`` (H0, W0, 3) float32 mm in camera 0's frame, NaN where not measured; ``--out`` camera 0's
depth, NaN exactly where ``--xyz`` is; bad captures refused naming the camera."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import build_parser
from metrology.commands.common import BadInputError
from metrology.commands.measure import cmd_measure
from metrology.core import local_cache
from metrology.core.codecs.stack import read_camera_stacks, write_camera_stacks
from metrology.core.geometry.stereo import StereoRig
from metrology.core.io.errors import StackError
from metrology.core.measure import measure
from metrology.core.scenes import make_scene
from metrology.core.simulate.stereo import render_stereo_capture
from tests.stereo_rig import CALIBRATED_RIG, PLACEMENT, PROJECTOR, RIG, codec

CODEC = codec("u")


@pytest.fixture(scope="module")
def capture():
    return render_stereo_capture(RIG, make_scene("plane", z_mm=0.0), CODEC, placement=PLACEMENT, projector=PROJECTOR)


def _args(tmp: Path, **extra: object) -> argparse.Namespace:
    argv = ["measure", "--rig", str(tmp / "rig.json")]
    for key, value in extra.items():
        argv += [f"--{key.replace('_', '-')}", str(value)]
    return build_parser().parse_args(argv)


def _written(tmp: Path, rig: StereoRig, capture) -> Path:
    """``rig.json`` and the capture's ``object.zip`` in ``tmp``; the zip's path."""
    (tmp / "rig.json").write_text(rig.to_json())
    return write_camera_stacks(capture.images, tmp / "object.zip", CODEC)


def test_measure_a_stereo_capture(tmp_path: Path, capture) -> None:
    args = _args(
        tmp_path,
        object=_written(tmp_path, RIG, capture),
        xyz=tmp_path / "xyz.npy",
        out=tmp_path / "z.npy",
        sigma=tmp_path / "s.npy",
        mesh=tmp_path / "m.ply",
        json=tmp_path / "stats.json",
    )
    summary = cmd_measure(args)
    assert summary["z"] == "depth (camera Z)"
    xyz, z = np.load(tmp_path / "xyz.npy"), np.load(tmp_path / "z.npy")
    assert xyz.shape == (*RIG.shape, 3) and xyz.dtype == np.float32 and z.dtype == np.float32
    assert np.array_equal(np.isnan(xyz).any(axis=-1), np.isnan(z))
    assert np.array_equal(np.isnan(xyz).all(axis=-1), np.isnan(z))
    measured = np.isfinite(z)
    assert measured.mean() > 0.9
    error = np.linalg.norm(xyz[measured].astype(np.float64) - capture.points_mm[measured], axis=-1)
    assert np.median(error) < 1e-3 and np.percentile(error, 99) < 5e-3
    np.testing.assert_array_equal(z[measured], xyz[measured][:, 2])
    sigma = np.load(tmp_path / "s.npy")
    assert np.array_equal(np.isfinite(sigma), measured)
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["rig"]["model"] == "stereo" and stats["valid_pixels"] == int(measured.sum())
    assert (tmp_path / "m.ply").stat().st_size > 0
    # --xyz alone
    alone = _args(tmp_path, object=tmp_path / "object.zip", xyz=tmp_path / "xyz2.npy")
    cmd_measure(alone)
    np.testing.assert_array_equal(np.load(tmp_path / "xyz2.npy"), xyz)
    with pytest.raises(BadInputError, match="give --out"):
        cmd_measure(_args(tmp_path, object=tmp_path / "object.zip"))


def test_a_calibrated_projector_s_pairs_reach_the_ply_and_the_summary(tmp_path: Path, capture) -> None:
    """With the projector calibrated, ``--json`` counts the points of each combination of pairs and a
    PLY mesh carries each vertex's pairs (a uchar property ``pairs``, docs/stereo.md)."""
    obj = _written(tmp_path, CALIBRATED_RIG, capture)
    summary = cmd_measure(
        _args(tmp_path, object=obj, xyz=tmp_path / "x.npy", mesh=tmp_path / "m.ply", json=tmp_path / "s.json")
    )
    stats = json.loads((tmp_path / "s.json").read_text())
    per_pairs = stats["points_per_pairs"]
    assert summary["points_per_pairs"] == per_pairs
    assert (
        sum(per_pairs.values()) == stats["valid_pixels"] == int(np.isfinite(np.load(tmp_path / "x.npy")[..., 2]).sum())
    )
    assert per_pairs["camera0-camera1+camera0-projector+camera1-projector"] > 0.9 * stats["valid_pixels"]
    assert per_pairs["camera0-projector"] > 0  # the edge of camera 0's field that camera 1 does not see
    header = (tmp_path / "m.ply").read_bytes().partition(b"end_header")[0]
    assert b"property uchar pairs" in header


def test_bad_stereo_captures_name_the_camera(tmp_path: Path, capture) -> None:
    (tmp_path / "rig.json").write_text(RIG.to_json())
    good = write_camera_stacks(capture.images, tmp_path / "good", CODEC)
    stacks = read_camera_stacks(good)
    assert stacks.codec == CODEC and len(stacks.stacks) == 2
    np.testing.assert_array_equal(stacks.stacks[1], capture.images[1])

    missing = tmp_path / "missing"
    shutil.copytree(good, missing)
    shutil.rmtree(missing / "cam1")
    with pytest.raises(StackError, match=r"no folder cam1/ for camera 1"):
        read_camera_stacks(missing)
    with pytest.raises(BadInputError, match=r"object stack: .*no folder cam1/ for camera 1"):
        cmd_measure(_args(tmp_path, object=missing, xyz=tmp_path / "x.npy"))

    short = tmp_path / "short"
    shutil.copytree(good, short)
    sorted((short / "cam1").glob("*.png"))[-1].unlink()
    with pytest.raises(StackError, match=r"^camera 1: "):
        read_camera_stacks(short)

    small = tmp_path / "small"
    write_camera_stacks((capture.images[0], capture.images[1][:, :200, :300]), small, CODEC)
    with pytest.raises(BadInputError, match=r"camera 1's frames are 300x200 px but the rig's camera 1 is 320x256 px"):
        cmd_measure(_args(tmp_path, object=small, xyz=tmp_path / "x.npy"))
    with pytest.raises(ValueError, match=r"camera 1's object frames are 300x200 px"):
        measure(RIG, (capture.images[0], capture.images[1][:, :200, :300]), CODEC)
    with pytest.raises(ValueError, match=r"one stack per camera \(2, camera 0 first\)"):
        measure(RIG, capture.images[0], CODEC)


def test_a_reference_plane_turns_depths_into_heights(tmp_path: Path, capture) -> None:
    """``--reference``: the plane fitted to a stereo capture of the reference plane, as for pinhole
    rigs (kept in the local cache: the second run reads it back); a plane 10 mm above it measures
    10 mm."""
    (tmp_path / "rig.json").write_text(RIG.to_json())
    write_camera_stacks(capture.images, tmp_path / "ref.zip", CODEC)
    raised = render_stereo_capture(RIG, make_scene("plane", z_mm=10.0), CODEC, placement=PLACEMENT, projector=PROJECTOR)
    write_camera_stacks(raised.images, tmp_path / "obj.zip", CODEC)
    for run in ("decoded", "kept"):
        out, stats = tmp_path / f"z_{run}.npy", tmp_path / f"{run}.json"
        args = _args(tmp_path, object=tmp_path / "obj.zip", reference=tmp_path / "ref.zip", out=out, json=stats)
        summary = cmd_measure(args)
        assert summary["z"] == "height above the reference plane"
        assert json.loads(stats.read_text())["reference_cache"]["hit"] is (run == "kept")
        local_cache.wait()  # the kept reference is written on a background thread
        z = np.load(out)
        assert np.isfinite(z).mean() > 0.9
        assert np.nanmax(np.abs(z - 10.0)) < 1e-3, run
