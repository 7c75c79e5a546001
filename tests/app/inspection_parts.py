"""The block with a square pit in its top, and its nominal model without the pit, shared by the
inspection tests of the application and of the browser (tests/app/test_inspections.py explains the
scene)."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np

from metrology.core.geometry.crossed_axes import Rig
from tests.app.stacks import SMALL_RIG, block_heights
from tests.core.inspection.parts import polygon_faces_shape, write_step

PIT = (slice(55, 65), slice(75, 85))
PIT_DEPTH_MM = 0.1
TOP_FEATURE = {"name": "top", "kind": "plane", "region": {"near_faces": [2, 3], "within_mm": 0.5}}
"""The block's top (faces 2 and 3 of :func:`block_nominal`): flat but for the pit, whose depth is its flatness."""


def stl_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A binary STL of the triangles ``vertices[faces]`` (normals written as zero: readers recompute)."""
    out = io.BytesIO()
    out.write(b"GCPS test nominal".ljust(80, b" "))
    out.write(struct.pack("<I", len(faces)))
    for face in faces:
        out.write(struct.pack("<3f", 0.0, 0.0, 0.0))
        for index in face:
            out.write(struct.pack("<3f", *vertices[index]))
        out.write(b"\0\0")
    return out.getvalue()


def _corners(points: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
    """The outer corners (X, Y, Z) of the pixel block ``rows x cols`` (inclusive centres), half a pixel
    beyond the outermost centres, counter-clockwise seen from above (+Z): (r0, c0), (r0, c1), (r1, c1), (r1, c0)."""
    (r0, r1), (c0, c1) = rows, cols
    out = []
    for r, c, dr, dc in ((r0, c0, -1, -1), (r0, c1, -1, 1), (r1, c1, 1, 1), (r1, c0, 1, -1)):
        centre = points[r, c]
        step_r = points[r, c] - points[r - dr, c]  # away from the block
        step_c = points[r, c] - points[r, c - dc]
        out.append(centre + 0.5 * step_r + 0.5 * step_c)
    corners = np.array(out)
    # counter-clockwise seen from +Z (X right, Y up): order by angle about the centre
    centre = corners.mean(axis=0)
    angles = np.arctan2(corners[:, 1] - centre[1], corners[:, 0] - centre[0])
    return corners[np.argsort(angles)]


def block_nominal() -> tuple[np.ndarray, np.ndarray]:
    """The block without its pit as a triangle mesh in the paper's frame (module docstring)."""
    prepared = Rig.from_dict(SMALL_RIG).prepare()
    shape = (SMALL_RIG["height_px"], SMALL_RIG["width_px"])
    top = _corners(prepared.points_from_heights(np.full(shape, 25.0)), (30, 89), (40, 119))
    foot = _corners(prepared.points_from_heights(np.zeros(shape)), (30, 89), (40, 119))
    ground = np.array([[0.0, -400.0, 0.0], [800.0, -400.0, 0.0], [800.0, 400.0, 0.0], [0.0, 400.0, 0.0]])
    vertices = np.vstack([ground, top, foot])
    faces = [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)]  # ground and top, normals +Z
    for i in range(4):  # walls: top edge i -> i+1 and the footprint below it, normal outward
        a, b = 4 + i, 4 + (i + 1) % 4
        fa, fb = a + 4, b + 4
        faces += [(a, fa, fb), (a, fb, b)]
    return vertices, np.array(faces)


def block_step(path: Path) -> Path:
    """The block without its pit as a STEP file (needs ``cadquery-ocp``): :func:`block_nominal`'s
    vertices as six planar faces, the ground, the top and the four walls, outward; tessellated, they
    are the same twelve triangles (an open surface: the ground is one face under the block)."""
    vertices, _ = block_nominal()
    walls = [(4 + i, 8 + i, 8 + (i + 1) % 4, 4 + (i + 1) % 4) for i in range(4)]
    return write_step(polygon_faces_shape(vertices, [(0, 1, 2, 3), (4, 5, 6, 7), *walls]), path)


def pitted_block_heights() -> np.ndarray:
    z = block_heights()
    z[PIT] -= PIT_DEPTH_MM
    return z
