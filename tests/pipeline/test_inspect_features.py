"""Features in an inspection (metrology/core/inspection/feature_regions.py) against analytic truth.

The part: a 40 x 40 x 20 mm box (top face at Z = 20) and, above it, a sphere of radius 10 mm
centred at (0, 0, 40), tessellated with its vertices exactly on the sphere. The scan: the box's top
and sides sampled on grids (exactly on the nominal planes) and the vertices of the sphere after
``plant_defects`` scaled it by 1.01 about its centre (every vertex exactly 10.1 mm from the centre),
moved by a known rigid pose. After alignment the sphere is found 0.1 mm larger than the nominal
(the vertices are exact: to 1e-6 mm), with no sphericity; the top plane has offset 0 and no
flatness (to the alignment's micrometre); a region that holds no point is reported, not fatal.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.inspection import alignment
from metrology.core.inspection.feature_regions import FeatureSpec, Region, parse_features
from metrology.core.inspection.nominal import nominal_from_arrays
from metrology.core.inspection.scan import Scan
from metrology.core.simulate.parts import Defect, box_mesh, plant_defects
from metrology.pipeline.inspect import InspectOptions, inspect
from tests.core.inspection.parts import write_binary_stl, write_ply_points

SPHERE_CENTRE = np.array([0.0, 0.0, 40.0])
RADIUS_MM = 10.0
FACTOR = 1.01
FEATURES = [
    {"name": "top", "kind": "plane", "region": {"box_mm": [[-18.5, -18.5, 19.5], [18.5, 18.5, 20.5]]}},
    {"name": "ball", "kind": "sphere", "region": {"near_faces": "SPHERE", "within_mm": 0.5}},
    {"name": "nothing", "kind": "plane", "region": {"box_mm": [[100, 100, 100], [101, 101, 101]]}},
]


def _sphere_mesh(count: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    """Unit-sphere Fibonacci points and their convex hull, faces outward."""
    from scipy.spatial import ConvexHull

    i = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * i / count)
    azimuth = np.pi * (1 + 5**0.5) * i
    unit = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    faces = ConvexHull(unit).simplices.copy()
    a, b, c = (unit[faces[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    faces[inward] = faces[inward][:, ::-1]
    return unit, faces


@pytest.fixture(scope="module")
def part() -> dict:
    box_v, box_f = box_mesh((40.0, 40.0, 20.0), (0.0, 0.0, 10.0))
    unit, sphere_f = _sphere_mesh()
    vertices = np.vstack([box_v, SPHERE_CENTRE + RADIUS_MM * unit])
    faces = np.vstack([box_f, sphere_f + len(box_v)])
    nominal = nominal_from_arrays(vertices, faces, name="box and ball")
    sphere_faces = list(range(len(box_f), len(faces)))
    planted = plant_defects(
        vertices, faces, [Defect("scale", tuple(SPHERE_CENTRE), radius_mm=RADIUS_MM + 1, factor=FACTOR)]
    )
    ball = planted.vertices_mm[len(box_v) :]
    g = np.linspace(-19.0, 19.0, 39)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    top = np.column_stack([u, v, np.full(u.size, 20.0)])
    h = np.linspace(1.0, 19.0, 10)
    s, z = (a.ravel() for a in np.meshgrid(g, h))
    sides = np.vstack(
        [
            np.column_stack([s, np.full(s.size, -20.0), z]),
            np.column_stack([s, np.full(s.size, 20.0), z]),
            np.column_stack([np.full(s.size, -20.0), s, z]),
            np.column_stack([np.full(s.size, 20.0), s, z]),
        ]
    )
    truth = alignment.rigid_transform(alignment.rotation_matrix(np.array([0.002, -0.001, 0.003])), [0.3, -0.2, 0.1])
    points = np.vstack([top, sides, ball])
    scan = alignment.apply(np.linalg.inv(truth), points)
    features = [dict(f, region={**f["region"]}) for f in FEATURES]
    features[1]["region"]["near_faces"] = sphere_faces
    return {"nominal": nominal, "vertices": vertices, "faces": faces, "scan": scan, "features": features}


def test_region_and_spec_validation() -> None:
    specs = parse_features(FEATURES[:1])
    assert specs[0] == FeatureSpec("top", "plane", Region(box_mm=((-18.5, -18.5, 19.5), (18.5, 18.5, 20.5))))
    assert parse_features([s.to_dict() for s in specs]) == specs
    for bad, words in [
        ([{"name": "a", "kind": "cone", "region": {"within_mm": 1}}], "kind must be one of"),
        ([{"name": "a", "kind": "plane", "region": {}}], "at least one of"),
        ([{"name": "a", "kind": "plane", "region": {"box_mm": [[1, 0, 0], [0, 1, 1]]}}], "x0 <= x1"),
        ([{"name": "a", "kind": "plane", "region": {"near_faces": [-1]}}], "face indices"),
        ([{"name": "a", "kind": "plane", "region": {"within_mm": 0}}], "within_mm must be a positive"),
        ([{"name": "a", "kind": "plane", "region": {"colour": 1}}], "unknown keys colour"),
        ([{"name": "a", "kind": "plane", "region": {"within_mm": 1}}] * 2, "names must differ"),
        ({"name": "a"}, "JSON list"),
    ]:
        with pytest.raises(ValueError, match=words):
            parse_features(bad)
    with pytest.raises(ValueError, match="region"):
        InspectOptions.from_dict({"features": [{"name": "a", "kind": "plane", "region": {}}]})
    # the box, face and distance selectors intersect
    region = Region(box_mm=((0, 0, 0), (1, 1, 1)), near_faces=(3,), within_mm=0.1)
    points = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [2.0, 0.5, 0.5]])
    mask = region.mask(points, np.array([0.05, 0.05, 0.2, 0.0]), np.array([3, 4, 3, 3]))
    assert mask.tolist() == [True, False, False, False]


def test_scaled_sphere_found_as_its_radius_difference(part: dict) -> None:
    options = InspectOptions(init="identity", features=parse_features(part["features"]))
    scan = Scan(points_mm=part["scan"], shape=(len(part["scan"]),))
    result = inspect(part["nominal"], scan, options)
    report = result.report({})
    assert list(report)[-2:] == ["features", "provenance"] and report["format"] == "gcps-inspection/1"
    top, ball, nothing = report["features"]
    assert top["error"] is None and top["points"] == 37 * 37
    assert abs(top["difference"]["offset_mm"]) < 1e-4 and top["form_mm"] < 1e-4
    assert top["difference"]["tilt_deg"] < 1e-3
    assert top["nominal"]["geometry"]["normal"][2] == pytest.approx(1, abs=1e-9)
    assert ball["error"] is None and ball["points"] == 1500
    assert ball["geometry"]["radius_mm"] == pytest.approx(RADIUS_MM * FACTOR, abs=1e-6)
    assert ball["nominal"]["geometry"]["radius_mm"] == pytest.approx(RADIUS_MM, abs=1e-6)
    assert ball["difference"]["radius_mm"] == pytest.approx(RADIUS_MM * (FACTOR - 1), abs=1e-6)
    assert ball["form"]["name"] == "sphericity" and ball["form_mm"] < 1e-6
    assert ball["difference"]["centre_offset_mm"] < 1e-3  # the alignment's micrometre
    assert ball["std"]["radius_mm"] < 1e-6  # no residual: no scatter
    assert nothing["points"] == 0 and "holds 0 points" in nothing["error"] and nothing["geometry"] is None
    json.dumps(report, allow_nan=False)  # JSON as it is
    # without features the report is the one it was (no features key)
    plain = inspect(part["nominal"], scan, InspectOptions(init="identity")).report({})
    assert "features" not in plain and plain["format"] == "gcps-inspection/1"


def test_command_line_features(part: dict, tmp_path: Path) -> None:
    write_binary_stl(tmp_path / "part.stl", part["vertices"], part["faces"])
    write_ply_points(tmp_path / "scan.ply", part["scan"], np.full(len(part["scan"]), 0.002))
    features = tmp_path / "features.json"
    features.write_text(json.dumps(part["features"][:2]))
    out = tmp_path / "report.json"
    args = ["--quiet", "inspect", "--nominal", str(tmp_path / "part.stl"), "--scan", str(tmp_path / "scan.ply")]
    assert main([*args, "--init", "identity", "--features", str(features), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    ball = {f["name"]: f for f in report["features"]}["ball"]
    assert ball["sigma_given"] is True
    # the STL's float32 corners: the nominal radius to float32 rounding of 40 mm coordinates
    assert ball["difference"]["radius_mm"] == pytest.approx(0.1, abs=1e-5)
    assert report["provenance"]["options"]["features"][1]["name"] == "ball"
    bad = tmp_path / "bad.json"
    bad.write_text('[{"name": "x", "kind": "cone", "region": {"within_mm": 1}}]')
    out2 = tmp_path / "refused.json"
    assert main([*args, "--features", str(bad), "--out", str(out2)]) == 2
    assert not out2.exists()
