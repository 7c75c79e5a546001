"""Exact ground truth for any geometric model, by ray casting a scene placed in the model frame.

The scenes of :mod:`metrology.core.scenes` are height fields ``h(X, Y)`` over a reference plane.
A :class:`ScenePlacement` puts that plane in a model's frame: scene point ``(X, Y, h)`` sits at
``origin + X e_x + Y e_y + h e_n``, ``e_n`` the plane's normal towards the camera. The model
gives the rest through its seam (:class:`~metrology.core.geometry.base.PreparedGeometry`): the
camera rays (:meth:`~PreparedGeometry.camera_rays`), the projector's centre and the projector
coordinates that light a point (:meth:`~PreparedGeometry.projector_coordinates`). So one caster
serves every model:

1. **First hit.** Each ray ``O + t d`` (``d`` a unit vector) is marched between the scene's top
   and bottom in steps that move it at most :data:`MARCH_STEP_MM` sideways (and at most
   :data:`MAX_HEIGHT_STEP_MM` in height); the first sign change of ``g(t) = s(t) - h(X(t), Y(t))``
   (``s`` the ray point's height above the plane) is refined by 60 bisections (to ~1e-13 mm; at
   a vertical wall of the height field, to the wall; a ray stops once its bracket no longer
   changes). A ray whose trace misses every footprint box (:attr:`~metrology.core.scenes.Scene.footprints_mm`,
   outside which the height is 0) meets only the plane: the same march sample and bisections are
   computed without the height field (:func:`metrology.core.simulate.kernels.plane_hits`), the same bits.
2. **Shadow.** A hit is unlit when a sample of the segment to the projector's centre (samples
   again at most :data:`MARCH_STEP_MM` apart sideways, until the segment rises above the scene's
   top) lies more than 1e-6 mm inside the object.
3. **Projector coordinates** ``(u, v)`` of each lit hit; NaN where the point is shadowed, behind
   the projector or outside its image ``[-0.5, size - 0.5]``.

A triangle mesh (:class:`~metrology.core.scenes.MeshScene`, a nominal part at a pose) is not a
height field: :func:`cast_truth` hands it to :func:`cast_mesh_truth`, which finds the hits and the
shadows with Open3D's ray caster and recomputes each hit in float64 on its triangle.

The result, :class:`CastTruth`, feeds a codec renderer (:func:`~metrology.core.codecs.render.render_codec`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.base import PreparedGeometry
from metrology.core.scenes import FIELD_CENTER_X_MM, MeshScene, Scene

FloatArray = npt.NDArray[np.float64]

MARCH_STEP_MM = 0.25
"""Largest sideways move of a camera or shadow ray between two samples of the height field, mm."""
MAX_HEIGHT_STEP_MM = 2.0
"""Largest height step of the marches, mm (rays nearly along the plane's normal move little sideways)."""
INSIDE_EPS_MM = 1e-6
"""A segment is blocked only where it lies deeper than this inside the object, mm."""
BISECTIONS = 60
"""Bisections of a first hit's bracket (fewer where the bracket stops changing: ~1e-13 mm)."""
BOX_PAD_MM = 1e-3
"""Margin around the footprint boxes within which a ray is cast against the height field, mm (a ray
farther out meets only the plane, whose first hit is found in closed form)."""


@dataclass(frozen=True)
class ScenePlacement:
    """Where a scene's reference plane sits in a model frame (module docstring).

    Attributes
    ----------
    origin_mm : (3,) float64 array
        Model-frame position of the scene's origin ``(X, Y) = (0, 0)`` on its reference plane, mm.
    e_x, e_y : (3,) float64 arrays
        Unit vectors of the scene's X and Y in the model frame.
    e_n : (3,) float64 array
        Unit normal of the reference plane, towards the camera (the direction of the heights).
    """

    origin_mm: np.ndarray
    e_x: np.ndarray
    e_y: np.ndarray
    e_n: np.ndarray

    @classmethod
    def model_plane(cls) -> ScenePlacement:
        """The scene on the model's own plane: its frame is the model frame (the paper's R, Z up)."""
        eye = np.eye(3)
        return cls(origin_mm=np.zeros(3), e_x=eye[0], e_y=eye[1], e_n=eye[2])

    @classmethod
    def facing_camera(cls, distance_mm: float, x0_mm: float = FIELD_CENTER_X_MM, y0_mm: float = 0.0) -> ScenePlacement:
        """The reference plane ``Z = distance_mm`` of a camera frame (OpenCV: Z along the optical
        axis), facing the camera, with scene point ``(x0, y0)`` on the optical axis: scene point
        ``(X, Y, h)`` at camera point ``(X - x0, Y - y0, distance - h)``."""
        if not (math.isfinite(distance_mm) and distance_mm > 0):
            raise ValueError(f"distance_mm must be a positive number, got {distance_mm!r}")
        eye = np.eye(3)
        return cls(origin_mm=np.array([-x0_mm, -y0_mm, distance_mm]), e_x=eye[0], e_y=eye[1], e_n=-eye[2])

    def in_frame(self, R: np.ndarray, T: np.ndarray) -> ScenePlacement:
        """The same placement in another frame, ``X' = R X + T`` (mm): a second camera's."""
        R = np.asarray(R, dtype=np.float64)
        return ScenePlacement(
            origin_mm=R @ self.origin_mm + np.asarray(T, dtype=np.float64),
            e_x=R @ self.e_x,
            e_y=R @ self.e_y,
            e_n=R @ self.e_n,
        )

    def scene_coordinates(self, points_mm: np.ndarray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(X, Y, s)`` of model-frame points ``(..., 3)``: scene coordinates and height above the plane."""
        rel = np.asarray(points_mm, dtype=np.float64) - self.origin_mm
        return rel @ self.e_x, rel @ self.e_y, rel @ self.e_n


@dataclass(frozen=True)
class CastTruth:
    """Ground truth per camera pixel (or sub-pixel) of a cast scene.

    Attributes
    ----------
    points_mm : (H, W, 3) float64
        The surface point each ray hits first, model frame, mm (NaN where the ray misses).
    height_mm : (H, W) float64
        Its height above the scene's reference plane, mm (NaN where the ray misses).
    u, v : (H, W) float64
        Projector coordinates lighting it (projector units); NaN where not lit (shadow, behind
        the projector, outside its image).
    """

    points_mm: FloatArray
    height_mm: FloatArray
    u: FloatArray
    v: FloatArray

    @property
    def lit(self) -> npt.NDArray[np.bool_]:
        """Pixels whose point is lit by the projector (both coordinates finite)."""
        return np.isfinite(self.u) & np.isfinite(self.v)

    def check_sub_rays(self, shape: tuple[int, int], supersample: int) -> None:
        """Raise ValueError unless these are the ``supersample`` x ``supersample`` sub-pixel rays of a
        camera of ``shape`` (H, W): ``(H s, W s)`` of them (a kept cast handed to a render)."""
        expected = (shape[0] * supersample, shape[1] * supersample)
        if self.points_mm.shape[:2] != expected:
            raise ValueError(
                f"the cast's rays are {self.points_mm.shape[:2]}, not {supersample} rays per pixel side of "
                f"the camera's {tuple(shape)} pixels"
            )


def cast_truth(
    prepared: PreparedGeometry,
    scene: Scene,
    placement: ScenePlacement,
    *,
    supersample: int = 1,
    march_step_mm: float = MARCH_STEP_MM,
) -> CastTruth:
    """Ray-cast ``scene`` (placed by ``placement``) through the prepared model (module docstring).

    Parameters
    ----------
    prepared : PreparedGeometry
        The model, prepared with the projector size of the codec to render (``v`` needs it).
    scene : Scene
    placement : ScenePlacement
    supersample : int
        Sub-pixel rays per pixel along each axis (``(H s, W s)`` outputs).

    Raises
    ------
    ValueError
        When the camera's pupil is not above the scene's top (the scene would hide the camera).

    A :class:`~metrology.core.scenes.MeshScene` is cast against its triangles instead
    (:func:`cast_mesh_truth`); ``placement`` then only gives the heights.
    """
    if isinstance(scene, MeshScene):
        return cast_mesh_truth(prepared, scene, placement, supersample=supersample)
    rays = prepared.camera_rays(supersample)
    origin, d = rays.origin_mm, rays.direction
    s_origin = float((origin - placement.origin_mm) @ placement.e_n)
    # the march ends just below the scene's bottom: on a plane placed askew in the model frame,
    # rounding may leave the ray's height a hair above h(X, Y) at the plane itself
    top, bottom = float(scene.z_max_mm), float(scene.z_min_mm) - INSIDE_EPS_MM
    if not s_origin > top:
        raise ValueError(f"the scene's top ({top:g} mm above its plane) reaches the camera ({s_origin:g} mm)")
    rate = d @ placement.e_n  # ds/dt, < 0 on rays going down to the plane
    with np.errstate(divide="ignore", invalid="ignore"):
        t_near = np.where(rate < 0, (top - s_origin) / rate, np.nan)
        t_far = np.where(rate < 0, (bottom - s_origin) / rate, np.nan)
    o_xy = np.array([(origin - placement.origin_mm) @ placement.e_x, (origin - placement.origin_mm) @ placement.e_y])
    d_x, d_y = d @ placement.e_x, d @ placement.e_y

    def g(t: FloatArray, rows: npt.NDArray[np.intp]) -> FloatArray:
        return s_origin + t * rate[rows] - scene.height_mm(o_xy[0] + t * d_x[rows], o_xy[1] + t * d_y[rows])

    flat = rate.size
    rate, d_x, d_y = rate.ravel(), d_x.ravel(), d_y.ravel()
    t_near, t_far = t_near.ravel(), t_far.ravel()
    height_step = _height_step(rate, march_step_mm)
    n_steps = max(1, math.ceil((top - bottom) / height_step))
    # rays whose trace misses every footprint box meet only the plane (h = 0): compiled, same bits
    boxes = scene.footprints_mm
    meets = np.ones(flat, bool)
    if boxes:
        padded = tuple((x0 - BOX_PAD_MM, x1 + BOX_PAD_MM, y0 - BOX_PAD_MM, y1 + BOX_PAD_MM) for x0, x1, y0, y1 in boxes)
        meets = _segments_meet_boxes(padded, o_xy[0], o_xy[1], d_x, d_y, t_near, t_far)
    hi = np.full(flat, np.nan)
    lo = t_near.copy()
    pending = np.flatnonzero(np.isfinite(t_near) & meets)  # rays still marching
    with np.errstate(invalid="ignore"):
        for i in range(n_steps + 1):
            if not pending.size:
                break
            t = t_near[pending] + (t_far[pending] - t_near[pending]) * (i / n_steps)
            hit = g(t, pending) <= 0
            hi[pending[hit]] = t[hit]
            lo[pending[~hit]] = t[~hit]
            pending = pending[~hit]
        found = np.isfinite(hi)
        b = hi.copy()
        refine = np.flatnonzero(found & (lo < hi))
        b[refine] = _bisect(g, refine, lo[refine], hi[refine], BISECTIONS)
    plane = np.flatnonzero(~meets)
    if plane.size:
        from metrology.core.simulate.kernels import plane_hits

        plane_hits(plane, t_near, t_far, rate, s_origin, n_steps, BISECTIONS, b, found)
    found = found.reshape(d.shape[:-1])
    b = b.reshape(d.shape[:-1])
    t_hit = np.where(found, b, np.nan)
    points = origin + t_hit[..., None] * d
    return _truth(
        prepared, placement, points, _shadowed(prepared.projector_centre_mm, scene, placement, points, march_step_mm)
    )


def _truth(
    prepared: PreparedGeometry, placement: ScenePlacement, points: FloatArray, shadowed: npt.NDArray[np.bool_]
) -> CastTruth:
    """The truth of the hit ``points`` ``(H, W, 3)``: heights above the placement's plane, and the
    projector coordinates where lit (inside the projector's image and not ``shadowed``)."""
    _, _, height = placement.scene_coordinates(points)
    u, v = prepared.projector_coordinates(points)
    size = prepared.projector_size
    lit = np.isfinite(u) & np.isfinite(v)
    if size is not None:
        with np.errstate(invalid="ignore"):
            lit &= (u >= -0.5) & (u <= size[0] - 0.5) & (v >= -0.5) & (v <= size[1] - 0.5)
    lit &= ~shadowed
    return CastTruth(points_mm=points, height_mm=height, u=np.where(lit, u, np.nan), v=np.where(lit, v, np.nan))


SHADOW_START_MM = 1e-3
"""A mesh point's shadow ray starts this far towards the projector (clear of its own triangle), mm."""


def cast_mesh_truth(
    prepared: PreparedGeometry, scene: MeshScene, placement: ScenePlacement, *, supersample: int = 1
) -> CastTruth:
    """Ray-cast a triangle mesh placed in the model frame through the prepared model.

    1. **First hit**: Open3D's ``RaycastingScene`` (float32, Embree) finds the triangle each camera
       ray ``O + t d`` meets first; the hit is then recomputed in float64 on that triangle's plane,
       ``t = n . (a - O) / (n . d)`` (``a`` a corner, ``n`` its normal), so the truth is exact to
       float64 rounding, not to float32. The mesh is cast in a frame centred on its vertices (float32
       keeps about 0.01 um there).
    2. **Shadow**: a hit is unlit when the segment from :data:`SHADOW_START_MM` above it to the
       projector's centre meets a triangle.
    3. **Projector coordinates** and heights above ``placement``'s plane, as :func:`cast_truth`.

    Returns a :class:`CastTruth` of ``(H s, W s)`` pixels (``s = supersample``), NaN where a ray misses.
    """
    from metrology.core.mesh import MeshRaycaster

    rays = prepared.camera_rays(supersample)
    d = rays.direction.reshape(-1, 3)
    shape = rays.direction.shape[:-1]
    vertices, faces = scene.model_vertices_mm, scene.faces
    caster = MeshRaycaster(vertices, faces)
    origin = np.broadcast_to(np.asarray(rays.origin_mm, dtype=np.float64), d.shape)
    triangle = caster.first_hits(origin, d)
    hit = triangle >= 0
    corners = vertices[faces[triangle[hit]]]  # (n, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    t = np.einsum("ij,ij->i", normal, corners[:, 0] - origin[hit]) / np.einsum("ij,ij->i", normal, d[hit])
    points = np.full(d.shape, np.nan)
    points[hit] = origin[hit] + t[:, None] * d[hit]
    # shadow: the segment from just above each hit to the projector's centre
    shadowed = np.zeros(len(d), dtype=bool)
    if hit.any():
        towards = np.asarray(prepared.projector_centre_mm, dtype=np.float64) - points[hit]
        unit = towards / np.linalg.norm(towards, axis=1, keepdims=True)
        shadowed[hit] = caster.blocked(points[hit] + SHADOW_START_MM * unit, towards - SHADOW_START_MM * unit)
    points = points.reshape(*shape, 3)
    return _truth(prepared, placement, points, shadowed.reshape(shape))


def _height_step(rate: FloatArray, sideways_mm: float) -> float:
    """The height step of a march whose rays (height rate ``ds/dt`` per unit length, ``rate``)
    move at most ``sideways_mm`` sideways per step: ``sideways * min |rate| / sqrt(1 - rate^2)``,
    at most :data:`MAX_HEIGHT_STEP_MM`."""
    r = np.abs(rate[np.isfinite(rate)])
    if not r.size:
        return MAX_HEIGHT_STEP_MM
    tangent = np.sqrt(np.maximum(1.0 - r * r, 0.0)) / np.maximum(r, 1e-12)
    return float(min(MAX_HEIGHT_STEP_MM, sideways_mm / max(float(tangent.max()), 1e-12)))


def _may_pass_over_the_object(
    scene: Scene, x0: FloatArray, y0: FloatArray, dx: FloatArray, dy: FloatArray, ds: FloatArray, s_top: FloatArray
) -> npt.NDArray[np.bool_]:
    """False for rising segments ``(x0 + t dx, y0 + t dy)``, ``t`` in ``[0, s_top]``, whose trace on
    the plane meets none of the scene's footprint boxes (:attr:`Scene.footprints_mm`): the height is
    0 all along them while they rise from a point on or above the plane, so nothing blocks them.
    True elsewhere (descending segments, scenes without footprint boxes). Slab test per box:
    ``t`` in ``[(b0 - x0) / dx, (b1 - x0) / dx]`` (sorted) for each axis, intersected with ``[0, s_top]``."""
    boxes = scene.footprints_mm
    if not boxes:
        return np.ones(x0.shape, bool)
    return _segments_meet_boxes(boxes, x0, y0, dx, dy, np.zeros_like(x0), s_top) | (ds <= 0)


def _segments_meet_boxes(
    boxes: tuple[tuple[float, float, float, float], ...],
    x0: FloatArray | float,
    y0: FloatArray | float,
    dx: FloatArray,
    dy: FloatArray,
    t_start: FloatArray,
    t_stop: FloatArray,
) -> npt.NDArray[np.bool_]:
    """Whether each segment ``(x0 + t dx, y0 + t dy)``, ``t`` in ``[t_start, t_stop]``, meets one of
    the boxes ``(x0, x1, y0, y1)`` (False where an end is NaN). Slab test per box: ``t`` in
    ``[(b0 - x0) / dx, (b1 - x0) / dx]`` (sorted) for each axis, intersected with the segment's."""
    meets = np.zeros(dx.shape, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for bx0, bx1, by0, by1 in boxes:
            lo, hi = t_start.copy(), t_stop.copy()
            for start, step, b0, b1 in ((x0, dx, bx0, bx1), (y0, dy, by0, by1)):
                t0, t1 = (b0 - start) / step, (b1 - start) / step
                parallel = step == 0  # inside the slab for every t, or for none
                outside = parallel & ((start < b0) | (start > b1))
                t0 = np.where(parallel, np.where(outside, np.inf, -np.inf), t0)
                t1 = np.where(parallel, np.where(outside, -np.inf, np.inf), t1)
                np.maximum(lo, np.minimum(t0, t1), out=lo)
                np.minimum(hi, np.maximum(t0, t1), out=hi)
            meets |= lo <= hi
    return meets


def _bisect(
    g: Callable[[FloatArray, npt.NDArray[np.intp]], FloatArray],
    rows: npt.NDArray[np.intp],
    a: FloatArray,
    b: FloatArray,
    iterations: int,
) -> FloatArray:
    """``iterations`` bisections of the brackets ``[a, b]`` (``g(a) > 0 >= g(b)``) of the rays ``rows``
    on ``g(mid, rows) <= 0``, ``mid = 0.5 (a + b)``; returns ``b``. A ray leaves once ``mid`` is ``a`` or
    ``b``: its bracket would not change any more, so the result is that of every iteration."""
    out = b.copy()
    active = np.arange(rows.size)
    aa, bb = a.copy(), b.copy()
    for _ in range(iterations):
        mid = 0.5 * (aa + bb)
        moving = (mid != aa) & (mid != bb)
        if not moving.all():
            out[active[~moving]] = bb[~moving]
            active, aa, bb, mid = active[moving], aa[moving], bb[moving], mid[moving]
            if not active.size:
                return out
        down = g(mid, rows[active]) <= 0
        bb = np.where(down, mid, bb)
        aa = np.where(down, aa, mid)
    out[active] = bb
    return out


def _shadowed(
    centre_mm: np.ndarray, scene: Scene, placement: ScenePlacement, points: FloatArray, sideways_mm: float
) -> npt.NDArray[np.bool_]:
    """Pixels whose segment to the projector's centre passes inside the object: samples at most
    ``sideways_mm`` apart sideways, from the point up to the scene's top."""
    p = points.reshape(-1, 3)
    finite = np.isfinite(p).all(axis=1)
    out = np.zeros(len(p), dtype=bool)
    if scene.z_max_mm == scene.z_min_mm or not finite.any():
        return out.reshape(points.shape[:2])  # a plane shadows nothing
    q0 = p[finite]
    direction = centre_mm - q0
    x0, y0, s0 = placement.scene_coordinates(q0)
    dx, dy, ds = direction @ placement.e_x, direction @ placement.e_y, direction @ placement.e_n
    norms = np.linalg.norm(direction, axis=1)
    rate = ds / norms  # height per unit length along the segment
    # the part of the segment below the scene's top, as a fraction of it (capped at the centre)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_top = np.clip(np.where(ds > 0, (scene.z_max_mm - s0) / ds, 1.0), 0.0, 1.0)
    # each segment sampled at its own count of steps, at most one height step apart
    rise = np.where(ds > 0, scene.z_max_mm - s0, np.abs(ds))
    steps = np.maximum(2, np.ceil(rise / _height_step(rate, sideways_mm))).astype(np.int64)
    blocked = np.zeros(len(q0), dtype=bool)
    pending = np.flatnonzero((s_top > 0) & _may_pass_over_the_object(scene, x0, y0, dx, dy, ds, s_top))
    i = 0
    while pending.size:
        i += 1
        frac = s_top[pending] * (i / steps[pending])
        X = x0[pending] + frac * dx[pending]
        Y = y0[pending] + frac * dy[pending]
        s = s0[pending] + frac * ds[pending]
        inside = (s < scene.height_mm(X, Y) - INSIDE_EPS_MM) & (frac * norms[pending] > INSIDE_EPS_MM)
        blocked[pending[inside]] = True
        pending = pending[~inside & (steps[pending] > i)]
    out[np.flatnonzero(finite)] = blocked
    return out.reshape(points.shape[:2])
