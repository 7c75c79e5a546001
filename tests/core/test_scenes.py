"""Scenes of the virtual rig: analytic heights, parameters, registry and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG, Rig
from metrology.core.scenes import (
    SCENES,
    BlockScene,
    FlowerpotScene,
    SphereScene,
    StaircaseScene,
    TwoSpheresScene,
    make_scene,
    scene_parameters,
)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_scene_is_zero_outside_its_footprint_and_bounded(name: str) -> None:
    scene = make_scene(name)
    rng = np.random.default_rng(1)
    X = rng.uniform(50.0, 650.0, 20000)
    Y = rng.uniform(-250.0, 250.0, 20000)
    z = scene.height_mm(X, Y)
    assert z.shape == X.shape and z.dtype == np.float64
    assert np.all(z <= scene.z_max_mm + 1e-9) and np.all(z >= scene.z_min_mm - 1e-9)
    boxes = scene.footprints_mm
    if boxes:
        inside = np.zeros(X.shape, dtype=bool)
        for x0, x1, y0, y1 in boxes:
            inside |= (x0 <= X) & (x1 >= X) & (y0 <= Y) & (y1 >= Y)
        assert np.all(z[~inside] == 0.0)
    albedo = scene.albedo(X, Y)
    assert albedo.shape == X.shape and np.all((albedo >= 0) & (albedo <= 1))
    assert scene.params()["scene"] == name


def test_plane_and_stage_are_flat() -> None:
    assert np.all(make_scene("plane", z_mm=12.5).height_mm([100.0, 600.0], [0.0, 200.0]) == 12.5)
    stage = make_scene("stage", z_in_mm=8.0)
    assert stage.z_max_mm == stage.z_min_mm == 8.0
    assert stage.params() == {"scene": "stage", "reflectance": 1.0, "z_in_mm": 8.0}


def test_block_known_values() -> None:
    block = make_scene("block", size_x_mm=100.0, size_y_mm=50.0, top_mm=40.0)
    assert isinstance(block, BlockScene)
    assert block.x_range_mm == (302.0, 402.0)
    assert block.height_mm(352.0, 0.0) == 40.0
    assert block.height_mm(402.0, 25.0) == 40.0  # faces belong to the block
    assert block.height_mm(402.001, 0.0) == 0.0


def test_sphere_defaults_rest_on_the_plane() -> None:
    sphere = make_scene("sphere")
    assert isinstance(sphere, SphereScene)
    assert sphere.center_mm == (PAPER_RIG.d_mm, 0.0, 50.0)
    assert sphere.z_max_mm == 100.0
    assert sphere.height_mm(352.0 + 30.0, 39.0) == pytest.approx(50.0 + math.sqrt(50.0**2 - 30.0**2 - 39.0**2))
    assert sphere.height_mm(352.0 + 30.0, 0.0) == pytest.approx(50.0 + 40.0)
    lifted = make_scene("sphere", radius_mm=20.0, center_z_mm=-10.0)
    assert lifted.height_mm(352.0, 0.0) == pytest.approx(10.0)
    assert lifted.height_mm(352.0 + 19.0, 0.0) == 0.0  # below R: clipped


def test_two_spheres_centres_are_spaced() -> None:
    scene = make_scene("two_spheres", spacing_mm=200.0, angle_rad=0.3)
    assert isinstance(scene, TwoSpheresScene)
    a, b = scene.centers_mm
    assert math.dist(a, b) == pytest.approx(200.0)
    for c in (a, b):
        assert scene.height_mm(c[0], c[1]) == pytest.approx(c[2] + scene.radius_mm)


def test_staircase_levels_and_edges() -> None:
    up = make_scene("staircase")
    assert isinstance(up, StaircaseScene)
    assert up.levels_mm == (10.0, 20.0, 30.0, 40.0)
    mids = [0.5 * (a + b) for a, b in zip(up.edges_x_mm, up.edges_x_mm[1:], strict=False)]
    assert up.height_mm(np.array(mids), 0.0).tolist() == [10.0, 20.0, 30.0, 40.0]
    down = make_scene("staircase", ascending=False)
    assert down.height_mm(np.array(mids), 0.0).tolist() == [40.0, 30.0, 20.0, 10.0]


def test_face_is_smooth_and_about_a_face_high() -> None:
    face = make_scene("face")
    assert 95.0 < face.z_max_mm < 150.0
    assert face.max_slope < 2.0
    assert face.height_mm(352.0, 10.0) > face.height_mm(352.0 - 38.0, -28.0)  # nose above eyes


def test_flowerpot_decoration_is_sub_millimetre() -> None:
    pot = make_scene("flowerpot")
    assert isinstance(pot, FlowerpotScene)
    y = np.linspace(-20.0, 20.0, 401)
    deco = pot.decoration_mm(352.0, y)
    assert deco.max() == pytest.approx(0.4, abs=1e-3) and deco.min() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(pot.height_mm(352.0, y), pot.base_height_mm(352.0, y) + deco, atol=1e-12)


def test_make_scene_centres_on_the_rig() -> None:
    rig = Rig(L_mm=1000.0, d_mm=300.0, alpha_rad=0.3, fw_mm=400.0, nlp=128, width_px=64, height_px=48)
    assert make_scene("block", rig=rig).center_x_mm == 300.0
    assert make_scene("block", rig=rig, center_x_mm=310.0).center_x_mm == 310.0
    assert "top_mm" in scene_parameters("block")


@pytest.mark.parametrize(
    ("name", "params", "match"),
    [
        ("teapot", {}, "unknown scene 'teapot'"),
        ("block", {"radius_mm": 3.0}, "no parameter 'radius_mm'"),
        ("block", {"top_mm": -1.0}, "top_mm"),
        ("sphere", {"radius_mm": 0.0}, "radius_mm"),
        ("sphere", {"radius_mm": float("nan")}, "radius_mm"),
        ("two_spheres", {"spacing_mm": 50.0}, "spacing_mm"),
        ("staircase", {"n_steps": 0}, "n_steps"),
        ("staircase", {"n_steps": 2.5}, "n_steps"),
        ("face", {"scale": "big"}, "scale"),
        ("flowerpot", {"ridge_period_mm": 0.0}, "ridge_period_mm"),
        ("plane", {"reflectance": 1.5}, "reflectance"),
        ("stage", {"z_mm": 3.0}, "no parameter 'z_mm'"),
    ],
)
def test_bad_scene_parameters_are_named(name: str, params: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make_scene(name, **params)
