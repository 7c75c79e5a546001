"""Signed distances against answers worked out by hand: a cube's faces, edges and corners (outside
and inside), an open square of two triangles, an L-shaped prism's reflex edge and a sharp wedge's
apex (where the closest triangle's own normal gives the wrong sign)."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.inspection.distance import (
    BLOCK_POINTS,
    EDGE,
    FACE,
    ORDER_MIN_POINTS,
    VERTEX,
    SurfaceDistance,
    spatial_order,
)
from metrology.core.inspection.nominal import nominal_from_arrays
from metrology.core.tiling import map_threads
from tests.core.inspection.parts import asymmetric_part, cube

EXACT = 1e-12  # mm: float64 recomputation of the closest feature


def prism(profile: list[tuple[float, float]], triangles: list[tuple[int, int, int]], height: float = 1.0):
    """A closed prism over a counter-clockwise polygon ``profile`` triangulated by ``triangles``."""
    n = len(profile)
    vertices = [(x, y, 0.0) for x, y in profile] + [(x, y, height) for x, y in profile]
    faces = [(c, b, a) for a, b, c in triangles] + [(a + n, b + n, c + n) for a, b, c in triangles]
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, j + n), (i, j + n, i + n)]
    return nominal_from_arrays(np.array(vertices), np.array(faces), name="prism")


def test_cube_faces_edges_corners_outside_and_inside() -> None:
    surface = SurfaceDistance(cube())
    cases = [  # point, signed distance, feature
        ((0.3, 0.6, 1.3), 0.3, FACE),
        ((0.3, 0.6, 0.8), -0.2, FACE),
        ((1.3, 0.6, 1.4), 0.5, EDGE),  # beyond the edge x = 1, z = 1: (0.3, 0, 0.4) from it
        ((-0.4, 0.3, -0.3), 0.5, EDGE),
        ((1.2, 1.3, -0.4), np.sqrt(0.29), VERTEX),  # beyond the corner (1, 1, 0)
        ((2.0, 2.0, 2.0), np.sqrt(3.0), VERTEX),
        ((0.9, 0.6, 0.95), -0.05, FACE),  # inside, nearer to z = 1 than to x = 1
        ((0.9, 0.95, 0.92), -0.05, FACE),  # inside near the corner (1, 1, 1)
        ((0.5, 0.3, 0.5), -0.3, FACE),
        ((1.0, 0.6, 1.0), 0.0, EDGE),  # on the edge
    ]
    points = np.array([c[0] for c in cases])
    found = surface.deviations(points)
    np.testing.assert_allclose(found.distance_mm, [c[1] for c in cases], atol=EXACT)
    outside = np.array([c[1] for c in cases]) > 0
    np.testing.assert_array_equal(found.feature[outside], [c[2] for c in cases if c[1] > 0])
    # the closest points and the gradient: p = c + d * direction
    np.testing.assert_allclose(found.closest_mm + found.distance_mm[:, None] * found.direction, points, atol=EXACT)
    assert not found.boundary.any()


def test_cube_random_points_match_the_box_distance() -> None:
    """Random points around the unit cube against the analytic signed distance of a box."""
    rng = np.random.default_rng(7)
    points = rng.uniform(-0.5, 1.5, (20000, 3))
    q = np.abs(points - 0.5) - 0.5
    truth = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    found = SurfaceDistance(cube()).deviations(points).distance_mm
    np.testing.assert_allclose(found, truth, atol=1e-9)


def test_open_square_sign_rule_beyond_its_boundary() -> None:
    vertices = np.array([(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 1.0, 0.0)])
    square = nominal_from_arrays(vertices, np.array([(0, 1, 2), (0, 2, 3)]), name="square")
    assert not square.closed and square.warnings and "right-hand normal" in square.warnings[0]
    surface = SurfaceDistance(square)
    cases = [  # point, signed distance, feature, closest feature on the boundary
        ((0.3, 0.6, 0.25), 0.25, FACE, False),
        ((0.3, 0.6, -0.25), -0.25, FACE, False),
        ((0.5, 0.5, 0.1), 0.1, EDGE, False),  # the inner diagonal edge
        ((1.5, 0.6, 0.5), np.sqrt(0.5), EDGE, True),  # beyond the edge x = 1, above the plane
        ((1.5, 0.6, -0.5), -np.sqrt(0.5), EDGE, True),
        ((1.3, 1.4, -0.2), -np.sqrt(0.29), VERTEX, True),  # beyond the corner (1, 1, 0), below
        ((1.5, 0.6, 0.0), 0.5, EDGE, True),  # in the plane: positive (the stated rule)
    ]
    found = surface.deviations(np.array([c[0] for c in cases]))
    np.testing.assert_allclose(found.distance_mm, [c[1] for c in cases], atol=EXACT)
    np.testing.assert_array_equal(found.feature, [c[2] for c in cases])
    np.testing.assert_array_equal(found.boundary, [c[3] for c in cases])


def test_l_shape_reflex_edge() -> None:
    """The L profile (0,0) (2,0) (2,1) (1,1) (1,2) (0,2): its reflex edge is x = y = 1."""
    shape = prism([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)], [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)])
    assert shape.oriented and shape.signed_volume_mm3 == pytest.approx(3.0)
    cases = [
        ((0.8, 0.8, 0.5), -np.sqrt(0.08)),  # inside, closest to the reflex edge
        ((0.7, 0.9, 0.5), -np.sqrt(0.1)),
        ((1.5, 1.5, 0.5), 0.5),  # outside, in the notch
        ((1.2, 0.8, 0.5), -0.2),
        ((1.2, 1.2, 1.1), np.sqrt(0.05)),  # above the notch: the top edge of the face y = 1
        ((0.9, 0.9, 1.1), 0.1),
        ((1.0, 1.0, 0.5), 0.0),
    ]
    found = SurfaceDistance(shape).deviations(np.array([c[0] for c in cases]))
    np.testing.assert_allclose(found.distance_mm, [c[1] for c in cases], atol=EXACT)
    assert found.feature[0] == EDGE and found.feature[1] == EDGE


def test_sharp_wedge_apex_needs_the_edge_pseudo_normal() -> None:
    """A 14 degree wedge (0,0) (4,0) (0,1): beyond its apex edge at (4, 0) the offset (1, 0.1) has
    a negative dot product with the bottom face's normal (0, -1, 0), yet the point is outside."""
    wedge = prism([(0, 0), (4, 0), (0, 1)], [(0, 1, 2)])
    found = SurfaceDistance(wedge).deviations(np.array([(5.0, 0.1, 0.5), (3.9, 0.01, 0.5)]))
    np.testing.assert_allclose(found.distance_mm[0], np.sqrt(1.01), atol=EXACT)
    assert found.feature[0] == EDGE
    np.testing.assert_allclose(found.distance_mm[1], -0.01, atol=EXACT)  # inside, under the bottom face


def test_magnitude_agrees_with_open3d_distance() -> None:
    import open3d

    sphere = open3d.geometry.TriangleMesh.create_sphere(30.0, resolution=40)
    nominal = nominal_from_arrays(np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    surface = SurfaceDistance(nominal)
    rng = np.random.default_rng(3)
    points = rng.normal(size=(20000, 3))
    points *= rng.uniform(25, 35, (20000, 1)) / np.linalg.norm(points, axis=1, keepdims=True)
    found = surface.deviations(points).distance_mm
    query = open3d.core.Tensor((points - surface.centre).astype(np.float32))
    reference = surface.scene.compute_distance(query).numpy()
    np.testing.assert_allclose(np.abs(found), reference, atol=2e-5)  # float32 at 35 mm
    radius = np.linalg.norm(points, axis=1)
    assert (np.sign(found) == np.sign(radius - 30.0))[np.abs(radius - 30.0) > 0.5].all()


def test_spatial_order_of_a_query_changes_no_answer() -> None:
    """A large query is passed to Open3D in Z order; its answers, back in the points' order, are
    those of the same points asked a few at a time (each in its own order). Points beyond the
    bounding box are ordered too (clamped to its border cells)."""
    surface = SurfaceDistance(asymmetric_part())
    rng = np.random.default_rng(5)
    points = rng.uniform(-20.0, 80.0, (3 * ORDER_MIN_POINTS, 3))
    order = spatial_order((points - surface.centre).astype(np.float32), surface.half_size)
    assert np.array_equal(np.sort(order), np.arange(points.shape[0])) and not np.array_equal(order, np.sort(order))
    face, uv = surface.closest_faces(points)
    pieces = [surface.closest_faces(points[i : i + 1000]) for i in range(0, points.shape[0], 1000)]
    np.testing.assert_array_equal(face, np.concatenate([p[0] for p in pieces]))
    np.testing.assert_array_equal(uv, np.concatenate([p[1] for p in pieces]))


def test_deviations_in_blocks_on_threads_equal_one_thread_and_nest_in_the_pool() -> None:
    """The float64 step's blocks on two threads give the one-thread numbers, and a call from a
    thread of the pool (which then takes one thread) does not wait for itself."""
    surface = SurfaceDistance(cube())
    points = np.random.default_rng(9).uniform(-0.5, 1.5, (2 * BLOCK_POINTS + 17, 3))
    alone = surface.deviations(points, threads=1)
    together = surface.deviations(points, threads=2)
    nested = map_threads(lambda half: surface.deviations(half, threads=2), np.array_split(points, 2), threads=2)
    for name in ("distance_mm", "closest_mm", "direction", "face", "feature", "boundary"):
        np.testing.assert_array_equal(getattr(together, name), getattr(alone, name))
        np.testing.assert_array_equal(np.concatenate([getattr(d, name) for d in nested]), getattr(alone, name))
