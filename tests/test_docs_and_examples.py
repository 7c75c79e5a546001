"""The user documentation and example files: the examples load, and nothing points users at a
document that is not in the repository."""

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.geometry import model_from_dict
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.io import read_model, read_rig, read_series

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DOCS = ROOT / "docs"


def test_example_rig_is_the_papers_rig():
    rig = read_rig(EXAMPLES / "rig.json")
    assert rig == PAPER_RIG and rig.extra["name"].startswith("paper rig")
    assert read_model(EXAMPLES / "rig.json") == rig
    assert model_from_dict(rig.to_dict()) == rig


def test_example_series_lists_three_positions():
    series = read_series(EXAMPLES / "series.json", check_exists=False)
    assert list(series.z_in_mm) == [0.0, 4.0, 8.0]
    assert [len(p.captures) for p in series.positions] == [2, 2, 2]
    assert series.positions[1].captures[0] == (EXAMPLES / "z004" / "r00").resolve()


def test_example_rig_simulates_and_measures(tmp_path):
    """The example rig works end to end (at a reduced size to keep the test short)."""
    small = {**read_rig(EXAMPLES / "rig.json").to_dict(), "width_px": 160, "height_px": 120}
    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps(small))
    base = ["--quiet", "simulate", "--rig", str(rig_file), "--preset", "noise-free"]
    assert main([*base, "--scene", "reference", "--out", str(tmp_path / "ref")]) == 0
    assert main([*base, "--scene", "plane", "--z-mm", "20", "--out", str(tmp_path / "obj")]) == 0
    args = ["--rig", str(rig_file), "--reference", str(tmp_path / "ref"), "--object", str(tmp_path / "obj")]
    assert main(["--quiet", "measure", *args, "--out", str(tmp_path / "z.npy")]) == 0
    z = np.load(tmp_path / "z.npy")
    assert np.nanmedian(z) == pytest.approx(20.0, abs=1e-3)


@pytest.mark.parametrize("page", ["README.md", "conventions.md", "file-formats.md", "command-line.md", "inspection.md"])
def test_docs_links_resolve(page):
    text = (DOCS / page).read_text()
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if not target.startswith("http"):
            assert (DOCS / target).resolve().exists(), f"{page} links to missing {target}"


def test_no_reference_to_a_document_outside_the_repository():
    tracked = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files"], capture_output=True, text=True, check=False
    ).stdout.split()
    if not tracked:
        pytest.skip(f"{ROOT} is not a git checkout")
    offenders = []
    for name in tracked:
        path = ROOT / name
        if path.suffix not in {".py", ".md", ".html", ".sh", ".toml", ".yml"} or not path.is_file():
            continue
        if "DESIGN.md" in path.read_text(errors="replace") and path.name != Path(__file__).name:
            offenders.append(name)
    assert not offenders, f"these files point users at DESIGN.md, which is not in the repository: {offenders}"


def test_help_points_at_docs():
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert "docs/file-formats.md" in out.getvalue()


def test_example_inspection_runs_as_documented(tmp_path):
    """docs/inspection.md's example: a scan of the example block taken 100 mm away in x, its top
    raised 0.1 mm, placed by the example point pairs; the report finds the shift and the bump."""
    from metrology.core.inspection.alignment import sample_surface
    from metrology.core.inspection.distance import SurfaceDistance
    from metrology.core.inspection.nominal import read_nominal
    from metrology.core.io.meshes import ply_points_bytes

    nominal = read_nominal(EXAMPLES / "inspection-step-block.stl")
    assert nominal.oriented and nominal.triangle_count == 20 and nominal.signed_volume_mm3 == pytest.approx(45750.0)
    surface = SurfaceDistance(nominal)
    points, normals = sample_surface(surface, 5000, np.random.default_rng(0))
    raised = points[:, 2] >= 40.0 - 1e-9  # the top of the step, z = 40
    points = points + np.where(raised, 0.1, 0.0)[:, None] * normals
    scan = points - [100.0, -20.0, 5.0]
    (tmp_path / "scan.ply").write_bytes(ply_points_bytes({k: scan[:, i] for i, k in enumerate("xyz")}))
    args = ["--nominal", str(EXAMPLES / "inspection-step-block.stl"), "--scan", str(tmp_path / "scan.ply")]
    args += ["--init", str(EXAMPLES / "inspection-pairs.json"), "--tolerance", "0.05"]
    args += ["--features", str(EXAMPLES / "inspection-features.json")]
    assert (
        main(
            [
                "--quiet",
                "inspect",
                *args,
                "--out",
                str(tmp_path / "report.json"),
                "--deviations",
                str(tmp_path / "dev.npy"),
            ]
        )
        == 0
    )
    report = json.loads((tmp_path / "report.json").read_text())
    np.testing.assert_allclose(np.array(report["transform"])[:3, 3], [100.0, -20.0, 5.0], atol=1e-4)
    deviation = np.load(tmp_path / "dev.npy")
    np.testing.assert_allclose(deviation[raised], 0.1, atol=1e-4)
    assert report["conformance"]["nonconforming"] == int(raised.sum())
    top, shelf = report["features"]  # the raised top is 0.1 mm off its nominal plane, the shelf is not
    assert top["name"] == "step-top" and top["difference"]["offset_mm"] == pytest.approx(0.1, abs=1e-4)
    assert abs(shelf["difference"]["offset_mm"]) < 1e-4 and shelf["form_mm"] < 1e-4
