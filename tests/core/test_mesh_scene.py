"""The virtual rig renders a nominal mesh (MeshScene) with planted defects, on every rig model.

- A box meshed as 12 triangles standing on a meshed plane, cast through the pinhole rig of the
  pinhole tests and through the paper's crossed-axes rig, gives the same truth as the analytic
  block scene (points and projector coordinates to 1e-9 mm / units, the same lit pixels: the
  shadow rays agree with the height-field caster's marches), and its noise-free 16-bit capture is
  measured back to well under 1 um (median; the tolerance pattern of the other scenes).
- A dent of depth d and width w planted in the box's top: the defect map is -d at the centre
  vertex (exactly), the cast truth (a narrow camera, 0.1 mm between pixels) is the
  cos^2 profile within the tessellation's bound (``d 2 pi^2 / (8 * 32^2)``, 0.24 % of d), and the
  deepest truth point is d deep within 1 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict
from metrology.core.codecs.decode import decode_codec
from metrology.core.geometry.base import triangulate_frame
from metrology.core.geometry.crossed_axes import PAPER_RIG
from metrology.core.geometry.pinhole import PinholeCamera, look_at_rig
from metrology.core.measure import MeasureOptions, measure
from metrology.core.scenes import MeshScene, make_scene
from metrology.core.simulate import ScenePlacement, SimulationOptions, cast_truth, render_capture, render_stack
from metrology.core.simulate.parts import REFINE_DIVISIONS, Defect, box_mesh, plant_defects
from tests.pinhole_stacks import CODEC, PROJ_H, PROJ_W, PROJECTOR, RIG

BOX = {"size_x_mm": 160.0, "size_y_mm": 110.0, "top_mm": 30.0}
CENTRE_X = 352.0
CLOSE_UP = look_at_rig(
    PinholeCamera(64, 64, ((6000.0, 0.0, 31.5), (0.0, 6000.0, 31.5), (0.0, 0.0, 1.0)), (0.0, 0.0, 0.0, 0.0, 0.0)),
    PROJECTOR,
    (-220.0, 6.0, 15.0),
    (0.0, 0.0, 600.0),
)
"""A narrow camera (0.1 mm between pixels at 600 mm) with the pinhole tests' projector."""


def _box_on_plane(plane_half_mm: float = 2000.0) -> tuple[np.ndarray, np.ndarray]:
    """The block scene's box (scene coordinates: X, Y, height) and the reference plane as two triangles."""
    vertices, faces = box_mesh((BOX["size_x_mm"], BOX["size_y_mm"], BOX["top_mm"]), (CENTRE_X, 0.0, BOX["top_mm"] / 2))
    h = plane_half_mm
    plane = np.array([[CENTRE_X - h, -h, 0], [CENTRE_X + h, -h, 0], [CENTRE_X + h, h, 0], [CENTRE_X - h, h, 0]], float)
    return np.vstack([vertices, plane]), np.vstack([faces, np.array([[8, 9, 10], [8, 10, 11]])])


def _same_truth(mesh, block, interior):
    """Mesh and block truths agree on the pixels away from the box's walls."""
    assert interior.sum() > 1000
    np.testing.assert_array_equal(mesh.lit[interior], block.lit[interior])
    both = interior & block.lit
    assert np.abs(mesh.points_mm[both] - block.points_mm[both]).max() < 1e-9
    assert np.abs(mesh.u[both] - block.u[both]).max() < 1e-9
    return both


def _interior(block_truth) -> np.ndarray:
    """Pixels whose 3 x 3 neighbourhood shows one surface (no wall, no shadow edge, no miss)."""
    h = np.nan_to_num(block_truth.height_mm, nan=-1.0)
    lit = block_truth.lit
    ok = np.ones(h.shape, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            shifted_h = np.roll(np.roll(h, dy, axis=0), dx, axis=1)
            shifted_lit = np.roll(np.roll(lit, dy, axis=0), dx, axis=1)
            ok &= (np.abs(shifted_h - h) < 1e-6) & (shifted_lit == lit)
    ok[[0, -1], :] = ok[:, [0, -1]] = False
    return ok


def test_pinhole_rig_mesh_equals_block_and_is_measured_back():
    placement = ScenePlacement.facing_camera(600.0)
    mesh = MeshScene.on_plane(*_box_on_plane(), placement)
    prepared = RIG.prepare(RIG.shape, (PROJ_W, PROJ_H))
    block_truth = cast_truth(prepared, make_scene("block", **BOX), placement)
    mesh_truth = cast_truth(prepared, mesh, placement)
    interior = _interior(block_truth)
    _same_truth(mesh_truth, block_truth, interior)
    assert (~block_truth.lit[interior]).sum() > 50  # the block's shadow is in the view, and the same
    codec = codec_from_dict(CODEC)
    rendered = render_capture(RIG, mesh, codec, placement=placement)
    decoded = decode_codec(rendered.images, codec)
    points = triangulate_frame(prepared, decoded.axes["u"].coordinate, None, heights=False).points_mm
    assert points is not None
    valid = decoded.axes["u"].valid & rendered.lit & ~rendered.edges
    assert valid.mean() > 0.5
    error = np.linalg.norm(points.astype(np.float64) - rendered.points_mm, axis=-1)[valid]
    print(f"pinhole mesh: {valid.sum()} px, median {np.median(error) * 1e3:.4f} um, max {error.max() * 1e3:.3f} um")
    assert np.median(error) < 1e-3 and np.percentile(error, 99) < 1e-3


def test_crossed_axes_rig_mesh_equals_papers_block_and_is_measured_back():
    """The paper's rig takes a mesh through the cast path (its own renderer is for height fields):
    heights equal the paper renderer's of the block, and the gcps-v1 capture measures back."""
    options = SimulationOptions.noise_free_16bit()
    mesh = MeshScene.on_plane(*_box_on_plane(), ScenePlacement.model_plane())
    rendered = render_capture(PAPER_RIG, mesh, None, options)
    paper = render_stack(PAPER_RIG, make_scene("block", **BOX), options)
    both = np.isfinite(paper.truth_mm) & np.isfinite(rendered.truth_mm) & ~paper.edges & ~rendered.edges
    assert both.mean() > 0.8
    assert np.abs(rendered.truth_mm[both] - paper.truth_mm[both]).max() < 1e-5  # float32 heights
    np.testing.assert_array_equal(np.isfinite(rendered.truth_mm)[both], np.isfinite(paper.truth_mm)[both])
    reference = render_stack(PAPER_RIG, make_scene("reference"), options).images
    measured = measure(PAPER_RIG, rendered.images, reference=reference, options=MeasureOptions(gray_only=False))
    ok = np.isfinite(measured.z_mm) & rendered.lit & ~rendered.edges
    assert ok.mean() > 0.8
    error = np.abs(measured.z_mm[ok].astype(np.float64) - rendered.truth_mm[ok])
    median, p99 = np.median(error) * 1e3, np.percentile(error, 99) * 1e3
    print(f"crossed-axes mesh: {ok.sum()} px, median {median:.4f} um, 99 % {p99:.3f} um")
    assert np.median(error) < 1e-3 and np.percentile(error, 99) < 1e-3


DENT = Defect("dent", (CENTRE_X + 20.0, 10.0, BOX["top_mm"]), width_mm=4.0, depth_mm=0.1)


def test_dent_map_and_cast_truth():
    vertices, faces = _box_on_plane()
    planted = plant_defects(vertices, faces, [DENT])
    centre = np.array(DENT.centre_mm)
    at_centre = np.flatnonzero(np.linalg.norm(planted.nominal_vertices_mm - centre, axis=1) < 1e-9)
    assert len(at_centre) == 1
    assert planted.displacement_mm[at_centre[0]] == pytest.approx(-0.1, abs=1e-12)
    assert planted.vertices_mm[at_centre[0]] == pytest.approx(centre - [0, 0, 0.1], abs=1e-12)
    # the map is the profile at every vertex, along the top's normal (+Z in scene coordinates)
    r = np.linalg.norm(planted.nominal_vertices_mm - centre, axis=1)
    np.testing.assert_allclose(planted.displacement_mm, DENT.profile_mm(r), atol=1e-12)
    top = np.abs(planted.nominal_vertices_mm[:, 2] - BOX["top_mm"]) < 1e-9
    np.testing.assert_allclose(planted.vertices_mm[top, 2] - BOX["top_mm"], planted.displacement_mm[top], atol=1e-12)
    # cast through a narrow pinhole camera looking at the dent: 0.1 mm between pixels on the top
    placement = ScenePlacement.facing_camera(600.0, x0_mm=centre[0], y0_mm=centre[1])
    mesh = MeshScene.on_plane(planted.vertices_mm, planted.faces, placement)
    truth = cast_truth(CLOSE_UP.prepare(CLOSE_UP.shape, (PROJ_W, PROJ_H)), mesh, placement)
    X, Y, height = placement.scene_coordinates(truth.points_mm)
    assert np.isfinite(height).all()
    depth = height.ravel() - BOX["top_mm"]
    rho = np.hypot(X - centre[0], Y - centre[1]).ravel()
    bound = 0.1 * 2 * math.pi**2 / (8 * REFINE_DIVISIONS**2)
    assert np.abs(depth - DENT.profile_mm(rho)).max() < bound + 1e-9
    assert -depth.min() == pytest.approx(0.1, rel=0.01)


def test_bump_and_scaled_feature():
    """A bump rises along the outward normal of a side face; a scaled sphere's map is (f - 1) R."""
    vertices, faces = box_mesh((40.0, 40.0, 40.0))
    bump = Defect("bump", (20.0, 3.0, -4.0), width_mm=6.0, depth_mm=0.05)  # on the +X face
    planted = plant_defects(vertices, faces, [bump])
    peak = int(np.argmax(planted.displacement_mm))
    assert planted.displacement_mm[peak] == pytest.approx(0.05, abs=1e-12)
    assert planted.vertices_mm[peak] == pytest.approx([20.05, 3.0, -4.0], abs=1e-12)
    # a sphere (vertices on it) scaled by 1.002 about its centre: every vertex moves (f - 1) R outwards
    theta, phi = np.meshgrid(np.linspace(0.2, np.pi - 0.2, 12), np.linspace(0, 2 * np.pi, 24, endpoint=False))
    ring = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    from scipy.spatial import ConvexHull

    hull = ConvexHull(ring)
    sphere_faces = hull.simplices.copy()
    a, b, c = (ring[sphere_faces[:, i]] for i in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    sphere_faces[inward] = sphere_faces[inward][:, ::-1]
    scaled = plant_defects(10.0 * ring, sphere_faces, [Defect("scale", (0, 0, 0), radius_mm=11.0, factor=1.002)])
    np.testing.assert_allclose(np.linalg.norm(scaled.vertices_mm, axis=1), 10.02, atol=1e-12)
    normal_dot = np.einsum("ij,ij->i", scaled.normals, ring)  # tessellated normals are nearly radial
    np.testing.assert_allclose(scaled.displacement_mm, 0.02 * normal_dot, atol=1e-12)
    assert normal_dot.min() > 0.95


def test_mesh_scene_validation():
    vertices, faces = box_mesh((1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="faces indexes vertices"):
        MeshScene(vertices_mm=vertices, faces=faces + 8)
    with pytest.raises(ValueError, match="proper rotation"):
        MeshScene(vertices_mm=vertices, faces=faces, rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(TypeError, match="not a height field"):
        MeshScene(vertices_mm=vertices, faces=faces).height_mm(0.0, 0.0)
    with pytest.raises(ValueError, match="positive depth_mm"):
        Defect("dent", (0, 0, 0), width_mm=1.0)
    params = MeshScene(vertices_mm=vertices, faces=faces, translation_mm=(0, 0, 5)).params()
    assert params["faces"] == 12 and params["translation_mm"] == [0.0, 0.0, 5.0] and len(params["sha256"]) == 64
