"""``gcps inspect`` (docs/inspection.md): the report's contract, the deviation map in the input's
order with its sign, decisions worked by hand, point pairs, and every bad input (exit 2, one
line, no output)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.inspection import alignment
from metrology.core.inspection.distance import SurfaceDistance
from tests.core.inspection.parts import asymmetric_part, pose_error, random_pose, write_binary_stl, write_ply_points

BUMP_MM = 0.2


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The asymmetric part as a binary STL; 30k noise-free points on it, in a random pose, 300 of
    them moved 0.2 mm outward along the normal (a bump), as a binary PLY with sigma_mm."""
    root = tmp_path_factory.mktemp("inspect")
    nominal = asymmetric_part()
    write_binary_stl(root / "part.stl", nominal.vertices, nominal.faces)
    from metrology.core.inspection.nominal import read_nominal

    surface = SurfaceDistance(read_nominal(root / "part.stl"))  # the STL's float32 corners
    rng = np.random.default_rng(21)
    points, normals = alignment.sample_surface(surface, 30_000, rng)
    bump = np.zeros(points.shape[0], bool)
    block_only = np.flatnonzero(points[:, 2] < 19.0)  # the block's sides and bottom: no other primitive near
    bump[rng.choice(block_only, 300, replace=False)] = True
    points = points + np.where(bump, BUMP_MM, 0.0)[:, None] * surface.deviations(points).direction
    truth = random_pose(rng)
    scan = alignment.apply(np.linalg.inv(truth), points)
    write_ply_points(root / "scan.ply", scan, np.full(points.shape[0], 0.002))
    del normals
    return {"root": root, "truth": truth, "points": points, "bump": bump, "scan": scan}


def run(*args: str) -> int:
    return main(["--quiet", "inspect", *args])


def test_report_contract_and_deviations_in_input_order(files: dict, tmp_path: Path) -> None:
    root = files["root"]
    out, dev, aligned = tmp_path / "report.json", tmp_path / "dev.npy", tmp_path / "aligned.ply"
    code = run(
        "--nominal", str(root / "part.stl"), "--scan", str(root / "scan.ply"), "--tolerance", "0.05",
        "--out", str(out), "--deviations", str(dev), "--aligned", str(aligned),
    )  # fmt: skip
    assert code == 0
    report = json.loads(out.read_text())
    assert list(report) == [
        "format", "transform", "alignment", "deviation", "tolerance_mm", "k", "conformance", "provenance",
    ]  # fmt: skip
    assert report["format"] == "gcps-inspection/1"
    transform = np.array(report["transform"])
    assert transform.shape == (4, 4) and transform[3].tolist() == [0, 0, 0, 1]
    rotation, displacement = pose_error(transform, files["truth"], files["points"])
    assert rotation < 1e-4 and displacement < 1e-4  # float32 PLY coordinates
    fit = report["alignment"]
    assert set(fit) == {"method", "rms_mm", "points_used", "iterations", "converged", "symmetric_dof", "std"}
    assert fit["method"] == "auto" and fit["converged"] and fit["symmetric_dof"] == []
    assert fit["points_used"] <= 30_000 - 300  # the bump is trimmed from the fit
    assert len(fit["std"]["rotation_deg"]) == 3 and len(fit["std"]["translation_mm"]) == 3
    assert set(report["deviation"]) == {"points", "mean_mm", "std_mm", "rms_mm", "min_mm", "max_mm", "p01_mm", "p99_mm"}
    assert report["deviation"]["points"] == 30_000
    assert report["tolerance_mm"] == 0.05 and report["k"] == 2.0
    assert report["conformance"] == {"conforming": 30_000 - 300, "nonconforming": 300, "undecided": 0}
    provenance = report["provenance"]
    assert provenance["nominal"]["units"] == "mm" and len(provenance["nominal"]["sha256"]) == 64
    assert len(provenance["scan"]["sha256"]) == 64 and provenance["seed"] == 0
    assert provenance["software_version"].startswith("gcps-lab") and provenance["options"]["init"] == "auto"
    deviation = np.load(dev)
    assert deviation.dtype == np.float32 and deviation.shape == (30_000,)
    bump = files["bump"]
    np.testing.assert_allclose(deviation[bump], BUMP_MM, atol=2e-5)  # positive: outside the material
    assert np.abs(deviation[~bump]).max() < 2e-5
    from metrology.core.io.meshes import read_ply_vertices

    columns = read_ply_vertices(aligned.read_bytes())
    np.testing.assert_allclose(np.stack([columns[k] for k in "xyz"], axis=1), files["points"], atol=1e-4)
    np.testing.assert_allclose(columns["deviation_mm"], deviation, atol=1e-7)


def test_point_map_with_ray_sigma_decisions_worked_by_hand(tmp_path: Path) -> None:
    """A block's near face z = 190 seen from the origin as an (H, W, 3) point map with holes,
    x from 0 to 70 mm (rays up to 20 degrees off the normal); every third row 0.03 mm in front of
    the face (trimmed from the fit: deviation +0.03), the rest on it. Sigma 0.01 along the rays,
    systematic 0.002, T = 0.05, k = 2: u = sqrt((0.01 cos)^2 + 0.002^2) with cos = z / |p|; a
    raised point conforms where 0.03 + 2 u <= 0.05 (cos <= 0.98), else is undecided."""
    import open3d

    box = open3d.geometry.TriangleMesh.create_box(90, 40, 10).translate((-10, -20, 190))
    write_binary_stl(tmp_path / "block.stl", np.asarray(box.vertices), np.asarray(box.triangles))
    y, x = np.mgrid[-15:15:48j, 0:70:64j]
    raised = np.zeros(x.shape, bool)
    raised[::3] = True
    z = np.where(raised, 190.0 - 0.03, 190.0)
    xyz = np.stack([x, y, z], axis=-1).astype(np.float32)
    xyz[4:8, 10:20] = np.nan
    np.save(tmp_path / "xyz.npy", xyz)
    np.save(tmp_path / "sigma.npy", np.full(x.shape, 0.01, np.float32))
    out, dev = tmp_path / "r.json", tmp_path / "d.npy"
    code = run(
        "--nominal", str(tmp_path / "block.stl"), "--scan", str(tmp_path / "xyz.npy"),
        "--sigma", str(tmp_path / "sigma.npy"), "--init", "identity", "--tolerance", "0.05",
        "--systematic-mm", "0.002", "--out", str(out), "--deviations", str(dev),
    )  # fmt: skip
    assert code == 0
    report = json.loads(out.read_text())
    deviation = np.load(dev)
    assert deviation.shape == (48, 64) and np.isnan(deviation[4:8, 10:20]).all()
    valid = np.isfinite(deviation)
    assert valid.sum() == 48 * 64 - 40
    np.testing.assert_allclose(deviation[valid & raised], 0.03, atol=1e-5)  # positive: in front of the face
    np.testing.assert_allclose(deviation[valid & ~raised], 0.0, atol=1e-5)
    # one plane fixes 3 of the 6 degrees of freedom: translation in it and rotation about its normal are free
    kinds = sorted(d["kind"] for d in report["alignment"]["symmetric_dof"])
    assert kinds == ["rotation", "translation", "translation"]
    points = xyz.reshape(-1, 3).astype(np.float64)[(valid & raised).reshape(-1)]
    u = np.sqrt((0.01 * points[:, 2] / np.linalg.norm(points, axis=1)) ** 2 + 0.002**2)
    conforming = int(np.count_nonzero(0.03 + 2 * u <= 0.05)) + int(np.count_nonzero(valid & ~raised))
    undecided = int(np.count_nonzero(0.03 + 2 * u > 0.05))
    assert undecided > 100 and conforming > 2000  # the threshold crosses the field of view
    assert report["conformance"] == {"conforming": conforming, "nonconforming": 0, "undecided": undecided}
    assert report["provenance"]["scan"]["sigma"]["sha256"]


def test_point_pairs_start(files: dict, tmp_path: Path) -> None:
    points, scan = files["points"], files["scan"]
    pairs = [{"scan": scan[i].tolist(), "nominal": points[i].tolist()} for i in (0, 1000, 2000, 3000)]
    (tmp_path / "pairs.json").write_text(json.dumps(pairs))
    out = tmp_path / "r.json"
    assert run("--nominal", str(files["root"] / "part.stl"), "--scan", str(files["root"] / "scan.ply"),
               "--init", str(tmp_path / "pairs.json"), "--out", str(out)) == 0  # fmt: skip
    report = json.loads(out.read_text())
    assert report["alignment"]["method"] == "pairs" and report["conformance"] is None
    assert report["provenance"]["seed"] is None
    rotation, displacement = pose_error(np.array(report["transform"]), files["truth"], points)
    assert rotation < 1e-4 and displacement < 1e-4


def test_bad_inputs_exit_2_with_one_line_and_no_output(
    files: dict, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    root = files["root"]
    (tmp_path / "empty.stl").write_bytes(b"")
    np.save(tmp_path / "nan.npy", np.full((4, 5, 3), np.nan, np.float32))
    np.save(tmp_path / "xyz.npy", np.zeros((4, 5, 3), np.float32))
    np.save(tmp_path / "sigma.npy", np.zeros((5, 4), np.float32))
    (tmp_path / "two.json").write_text(json.dumps([{"scan": [0, 0, 0], "nominal": [0, 0, 0]}] * 2))
    nominal, scan = str(root / "part.stl"), str(root / "scan.ply")
    cases = [
        (["--nominal", str(tmp_path / "empty.stl"), "--scan", scan], "not an STL"),
        (["--nominal", str(tmp_path / "missing.stl"), "--scan", scan], "no such file"),
        (["--nominal", nominal, "--scan", str(tmp_path / "nan.npy")], "no points"),
        (
            ["--nominal", nominal, "--scan", str(tmp_path / "xyz.npy"), "--sigma", str(tmp_path / "sigma.npy")],
            "--sigma has shape",
        ),
        (["--nominal", nominal, "--scan", scan, "--init", str(tmp_path / "two.json")], "at least 3"),
        (["--nominal", nominal, "--scan", scan, "--sigma", str(tmp_path / "sigma.npy")], "--sigma goes with an .npy"),
        (["--nominal", nominal, "--scan", scan, "--tolerance", "-1"], "tolerance_mm must be a positive"),
    ]
    for args, words in cases:
        outputs = [tmp_path / "r.json", tmp_path / "d.npy", tmp_path / "a.ply"]
        code = run(*args, "--out", str(outputs[0]), "--deviations", str(outputs[1]), "--aligned", str(outputs[2]))
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, (args, err)
        assert not any(path.exists() for path in outputs)
        assert not list(tmp_path.glob(".*tmp*"))
