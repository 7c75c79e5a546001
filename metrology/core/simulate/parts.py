"""Nominal parts for the virtual rig and defects planted in them.

A mesh is ``(vertices (V, 3) float64 mm, faces (F, 3) int64)``, faces counter-clockwise seen
from outside (outward normals, as STL). :func:`box_mesh` builds a box; :func:`plant_defects`
displaces a mesh's vertices along their outward normals and returns the new mesh with the true
displacement of every vertex (the defect map), which a :class:`~metrology.core.scenes.MeshScene`
then renders.

Defects (:class:`Defect`):

- ``dent`` / ``bump``: ``delta(r) = -/+ depth_mm cos^2(pi r / width_mm)`` for ``r < width_mm / 2``,
  0 beyond (``r`` the distance from ``centre_mm``, mm): a smooth cup ``width_mm`` across at its
  rim, ``depth_mm`` deep (high) at its centre, displaced along the vertex normals. The triangles
  within ``width_mm / 2`` of the centre are first split, 1 into 4 at their edges' midpoints, until
  their longest edge is at most ``width_mm / REFINE_DIVISIONS``; then the small triangle under the
  centre is split into three at the centre (so a vertex sits at the deepest point and the map there
  is exactly ``-depth_mm``). Triangles out of reach keep their edges, which are outside the cup, so
  the displaced surface has no crack (the mesh has T-junctions there: closed in space, though not
  edge-watertight in its connectivity).
  Piecewise-linear over that mesh, the surface departs from the cos^2 profile by at most
  ``depth * 2 pi^2 / (8 REFINE_DIVISIONS^2)`` (about 0.24 % of the depth at 32 divisions).
- ``scale``: every vertex within ``radius_mm`` of ``centre_mm`` moved to ``c + factor (x - c)``: a
  feature (a sphere, a boss) scaled about its centre; the map is that move along the normal.

The map is the displacement along the *nominal* outward normal (area-weighted vertex normals of
the refined nominal mesh, exact on flat faces), positive outwards: the deviation an inspection
should find at that vertex.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.mesh import MeshRaycaster

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

DEFECT_KINDS = ("dent", "bump", "scale")
"""The kinds of :class:`Defect`."""
REFINE_DIVISIONS = 32
"""A dent or bump's triangles are split until their longest edge is at most width / this."""


def box_mesh(size_mm: Sequence[float], centre_mm: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[FloatArray, IntArray]:
    """A box of sides ``size_mm`` ``(x, y, z)`` centred at ``centre_mm``: 8 vertices, 12 triangles,
    outward normals.

    Examples
    --------
    >>> v, f = box_mesh((2.0, 2.0, 2.0))
    >>> v.shape, f.shape, float(v[:, 2].max())
    ((8, 3), (12, 3), 1.0)
    """
    half = np.asarray(size_mm, dtype=np.float64) / 2
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=np.float64)
    vertices = corners * half + np.asarray(centre_mm, dtype=np.float64)
    # corner index = x + 2 y + 4 z (each 0 or 1); two triangles per face, counter-clockwise from outside
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # z = -1
            [4, 5, 6], [5, 7, 6],  # z = +1
            [0, 1, 4], [1, 5, 4],  # y = -1
            [2, 6, 3], [3, 6, 7],  # y = +1
            [0, 4, 2], [2, 4, 6],  # x = -1
            [1, 3, 5], [3, 7, 5],  # x = +1
        ],
        dtype=np.int64,
    )  # fmt: skip
    return vertices, faces


@dataclass(frozen=True)
class Defect:
    """A defect to plant (module docstring).

    Attributes
    ----------
    kind : {'dent', 'bump', 'scale'}
    centre_mm : (3,) tuple of float
        A point of the mesh's surface (dent, bump; it is projected onto the nearest triangle), or the
        centre of the scaling, mesh frame, mm.
    width_mm : float
        Dent or bump: diameter of the cup at its rim, mm, > 0.
    depth_mm : float
        Dent: depth, bump: height, at the centre, mm, > 0.
    radius_mm : float
        Scale: the vertices within this distance of the centre are scaled, mm, > 0.
    factor : float
        Scale: the scale factor, > 0.
    """

    kind: str
    centre_mm: tuple[float, float, float]
    width_mm: float = 0.0
    depth_mm: float = 0.0
    radius_mm: float = 0.0
    factor: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in DEFECT_KINDS:
            raise ValueError(f"defect kind must be one of {', '.join(DEFECT_KINDS)}, got {self.kind!r}")
        centre = tuple(float(c) for c in self.centre_mm)
        if len(centre) != 3 or not all(math.isfinite(c) for c in centre):
            raise ValueError(f"defect centre_mm must be 3 finite numbers, got {self.centre_mm!r}")
        object.__setattr__(self, "centre_mm", centre)
        needed = ("width_mm", "depth_mm") if self.kind != "scale" else ("radius_mm", "factor")
        for name in needed:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"a {self.kind} needs a positive {name}, got {value!r}")

    def profile_mm(self, r_mm: npt.ArrayLike) -> FloatArray:
        """Dent or bump: the displacement along the outward normal at distance ``r_mm`` from the centre, mm."""
        r = np.asarray(r_mm, dtype=np.float64)
        sign = -1.0 if self.kind == "dent" else 1.0
        inside = r < self.width_mm / 2
        return np.where(inside, sign * self.depth_mm * np.cos(np.pi * r / self.width_mm) ** 2, 0.0)

    def to_dict(self) -> dict[str, object]:
        """The defect's fields (JSON types)."""
        return {
            "kind": self.kind,
            "centre_mm": list(self.centre_mm),
            "width_mm": self.width_mm,
            "depth_mm": self.depth_mm,
            "radius_mm": self.radius_mm,
            "factor": self.factor,
        }


@dataclass(frozen=True, eq=False)
class DefectedMesh:
    """A mesh with planted defects and its truth.

    Attributes
    ----------
    vertices_mm : (V', 3) float64
        The displaced vertices, mesh frame, mm. The first V are the input's vertices (moved).
    faces : (F', 3) int64
    nominal_vertices_mm : (V', 3) float64
        The same vertices before displacement: on the nominal surface.
    normals : (V', 3) float64
        The nominal outward unit normal at each vertex.
    displacement_mm : (V',) float64
        The defect map: each vertex's displacement along its nominal outward normal, mm (0 away
        from the defects).
    defects : tuple of Defect
    """

    vertices_mm: FloatArray
    faces: IntArray
    nominal_vertices_mm: FloatArray
    normals: FloatArray
    displacement_mm: FloatArray
    defects: tuple[Defect, ...]


def vertex_normals(vertices: FloatArray, faces: IntArray) -> FloatArray:
    """``(V, 3)`` area-weighted unit vertex normals, ``normalise(sum (b - a) x (c - a))`` over the
    faces around each vertex; ``(0, 0, 0)`` for a vertex in no face."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    cross = np.cross(b - a, c - a)
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], cross)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)


def _nearest_on_mesh(vertices: FloatArray, faces: IntArray, point: FloatArray) -> tuple[int, FloatArray]:
    """The triangle nearest ``point`` (Open3D, float32) and the point's float64 projection on its plane."""
    triangle = int(MeshRaycaster(vertices, faces).nearest_triangles(point[None])[0])
    a, b, c = vertices[faces[triangle]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    return triangle, point - ((point - a) @ n) * n


def _barycentric(corners: FloatArray, point: FloatArray) -> FloatArray:
    """``(3,)`` barycentric coordinates of ``point`` (in the triangle's plane) in ``corners`` ``(3, 3)``."""
    a, b, c = corners
    m = np.column_stack([b - a, c - a])
    (s, t), *_ = np.linalg.lstsq(m, point - a, rcond=None)
    return np.array([1.0 - s - t, s, t])


def _refine(
    state: FloatArray, faces: IntArray, centre: FloatArray, reach: float, max_edge: float
) -> tuple[FloatArray, IntArray]:
    """Split every triangle that may come within ``reach`` of ``centre`` 1 into 4 (shared midpoints),
    round after round, until none of them has an edge longer than ``max_edge``. ``state`` ``(V, k)``
    holds each vertex's nominal position in its first three columns; every column is interpolated
    linearly to the midpoints."""
    while True:
        corners = state[faces, :3]  # (F, 3, 3)
        middle = corners.mean(axis=1)
        bound = np.linalg.norm(corners - middle[:, None], axis=2).max(axis=1)
        near = np.linalg.norm(middle - centre, axis=1) - bound < reach
        edges = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2).max(axis=1)
        if not near.any() or edges[near].max() <= max_edge:
            return state, faces
        split = faces[near]
        pairs = np.sort(np.stack([split, np.roll(split, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        unique, index = np.unique(pairs, axis=0, return_inverse=True)
        mid = len(state) + index.reshape(-1, 3)  # midpoints of edges ab, bc, ca
        state = np.vstack([state, state[unique].mean(axis=1)])
        a, b, c = split.T
        ab, bc, ca = mid.T
        children = [np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
        faces = np.vstack([faces[~near], *children])


def plant_defects(vertices_mm: npt.ArrayLike, faces: npt.ArrayLike, defects: Sequence[Defect]) -> DefectedMesh:
    """Plant ``defects`` in the mesh, one after the other (module docstring).

    Parameters
    ----------
    vertices_mm : (V, 3) array_like of float
    faces : (F, 3) array_like of int
        Outward normals (counter-clockwise seen from outside).
    defects : sequence of Defect

    Returns
    -------
    DefectedMesh
        The new mesh and the defect map (the sum of the defects' displacements at each vertex).
    """
    vertices = np.array(vertices_mm, dtype=np.float64)
    tri = np.array(faces, dtype=np.int64)
    # per vertex: nominal position (0:3), displacement along the normal so far (3), current position (4:7)
    state = np.column_stack([vertices, np.zeros(len(vertices)), vertices])
    for defect in defects:
        centre = np.array(defect.centre_mm)
        if defect.kind == "scale":
            normals = vertex_normals(state[:, :3], tri)
            inside = np.linalg.norm(state[:, :3] - centre, axis=1) <= defect.radius_mm
            move = np.where(inside[:, None], (defect.factor - 1.0) * (state[:, 4:] - centre), 0.0)
            state[:, 4:] += move
            state[:, 3] += np.einsum("ij,ij->i", move, normals)
            continue
        _, point = _nearest_on_mesh(state[:, :3], tri, centre)
        state, tri = _refine(state, tri, point, defect.width_mm / 2, defect.width_mm / REFINE_DIVISIONS)
        triangle, point = _nearest_on_mesh(state[:, :3], tri, point)  # now a small triangle: split it there
        corners = tri[triangle]
        state = np.vstack([state, _barycentric(state[corners, :3], point) @ state[corners]])
        k = len(state) - 1
        a, b, c = corners
        tri = np.vstack([np.delete(tri, triangle, axis=0), [[a, b, k], [b, c, k], [c, a, k]]])
        normals = vertex_normals(state[:, :3], tri)
        delta = defect.profile_mm(np.linalg.norm(state[:, :3] - point, axis=1))
        state[:, 4:] += delta[:, None] * normals
        state[:, 3] += delta
    nominal = np.ascontiguousarray(state[:, :3])
    return DefectedMesh(
        vertices_mm=np.ascontiguousarray(state[:, 4:]),
        faces=tri,
        nominal_vertices_mm=nominal,
        normals=vertex_normals(nominal, tri),
        displacement_mm=state[:, 3].copy(),
        defects=tuple(defects),
    )
