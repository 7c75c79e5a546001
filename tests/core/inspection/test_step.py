"""STEP nominal models through OpenCASCADE (metrology/core/io/step.py), an optional extra: skipped,
saying so, without ``cadquery-ocp``.

A box 40 x 30 x 20 mm and a sphere of radius 10 mm are built with OpenCASCADE and written as STEP,
then read back as nominal models: the box's mesh is closed, outward, of volume 24000 mm^3 exactly;
the sphere's vertices lie on the sphere (to 1e-9 mm) and its triangles' centroids within twice the
recorded linear tolerance of it (BRepMesh's deflection is a target: 1.7 x measured at the worst
triangle), its volume short of 4/3 pi R^3 by less than area x tolerance.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from metrology.core.inspection.nominal import read_nominal
from metrology.core.io.step import LINEAR_TOLERANCE_MM, ocp_installed
from tests.core.inspection.parts import write_step

pytestmark = pytest.mark.skipif(
    not ocp_installed(), reason="STEP needs the optional cadquery-ocp (pip install 'gcps-lab[step]')"
)


def test_step_box_and_sphere(tmp_path: Path) -> None:
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeSphere
    from OCP.gp import gp_Pnt

    box = read_nominal(write_step(BRepPrimAPI_MakeBox(40.0, 30.0, 20.0).Shape(), tmp_path / "box.step"))
    assert box.oriented and not box.flipped, box.summary()
    assert box.signed_volume_mm3 == pytest.approx(24000.0, rel=1e-12)
    assert box.summary()["tessellation"]["linear_tolerance_mm"] == LINEAR_TOLERANCE_MM
    assert box.size_mm == pytest.approx([40.0, 30.0, 20.0], abs=1e-12)

    centre = np.array([5.0, -3.0, 2.0])
    sphere = read_nominal(write_step(BRepPrimAPI_MakeSphere(gp_Pnt(*centre), 10.0).Shape(), tmp_path / "ball.stp"))
    radius = np.linalg.norm(sphere.vertices - centre, axis=1)
    np.testing.assert_allclose(radius, 10.0, atol=1e-9)
    used = np.unique(sphere.faces)
    a, b, c = (sphere.vertices[sphere.faces[:, k]] for k in range(3))
    sag = 10.0 - np.linalg.norm((a + b + c) / 3 - centre, axis=1)  # a triangle's centroid: its deepest point, about
    assert used.size == len(sphere.vertices) and sag.min() > 0 and sag.max() <= 2 * LINEAR_TOLERANCE_MM, sag.max()
    assert np.percentile(sag, 99) <= LINEAR_TOLERANCE_MM
    exact = 4 / 3 * math.pi * 1000.0
    assert 0 < exact - sphere.signed_volume_mm3 < sphere.area_mm2() * LINEAR_TOLERANCE_MM
    assert sphere.signed_volume_mm3 > 0 and not sphere.flipped  # outward


def test_step_refusals(tmp_path: Path) -> None:
    bad = tmp_path / "bad.step"
    bad.write_text("ISO-10303-21;\nnot really\n")
    with pytest.raises(ValueError, match=r"bad\.step"):
        read_nominal(bad)


def test_gcps_inspect_reads_a_step_nominal(tmp_path: Path) -> None:
    """The command line inspects against a STEP box: points on it deviate by 0, the tolerance is recorded."""
    import json

    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

    from metrology.cli import main
    from metrology.core.inspection.alignment import sample_surface
    from metrology.core.inspection.distance import SurfaceDistance
    from tests.core.inspection.parts import write_ply_points

    step = write_step(BRepPrimAPI_MakeBox(40.0, 30.0, 20.0).Shape(), tmp_path / "box.step")
    points, _ = sample_surface(SurfaceDistance(read_nominal(step)), 3000, np.random.default_rng(3))
    write_ply_points(tmp_path / "scan.ply", points)
    out = tmp_path / "report.json"
    args = ["--quiet", "inspect", "--nominal", str(step), "--scan", str(tmp_path / "scan.ply"), "--init", "identity"]
    assert main([*args, "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["provenance"]["nominal"]["tessellation"]["linear_tolerance_mm"] == LINEAR_TOLERANCE_MM
    assert report["deviation"]["points"] == 3000 and report["deviation"]["rms_mm"] < 1e-6
