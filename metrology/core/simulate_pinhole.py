"""The virtual rig for pinhole rigs: exact ground truth by ray casting the existing scenes.

The scenes of :mod:`metrology.core.scenes` are height fields ``h(X, Y)`` over the paper's
reference plane. A :class:`PlacedScene` puts one in a pinhole rig's camera frame facing the
camera: scene point ``(X, Y, h)`` sits at camera point ``(X - x0, Y - y0, Z0 - h)``, so the
reference plane is the plane ``Z = Z0`` and heights grow towards the camera. :func:`cast_truth`
then gives, per camera pixel, the true 3D point (the first intersection of the pixel's
undistorted ray with the surface) and the true projector coordinates ``(u, v)`` of that
point (projected through the projector's distortion), NaN where the projector does not reach
the point (outside its image, or the segment to its centre passes through the object: a
shadow). These maps feed a codec renderer, or the triangulation directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.distortion import project_normalized, undistort_pixels
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig
from metrology.core.scenes import FIELD_CENTER_X_MM, Scene

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PlacedScene:
    """A scene in the camera frame: ``Z = distance_mm - h(X + x0, Y + y0)`` (mm).

    Parameters
    ----------
    scene : Scene
    distance_mm : float
        ``Z0``: camera Z of the scene's reference plane, mm, > the scene's highest point.
    x0_mm, y0_mm : float
        Scene coordinates on the camera's optical axis, mm (default: the scenes' field centre).
    """

    scene: Scene
    distance_mm: float
    x0_mm: float = FIELD_CENTER_X_MM
    y0_mm: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.distance_mm) and self.distance_mm > self.scene.z_max_mm):
            raise ValueError(
                f"distance_mm must exceed the scene's highest point ({self.scene.z_max_mm} mm), "
                f"got {self.distance_mm!r}"
            )

    def surface_z(self, X: FloatArray, Y: FloatArray) -> FloatArray:
        """Camera Z of the surface above camera-frame ``(X, Y)``, mm."""
        return self.distance_mm - self.scene.height_mm(X + self.x0_mm, Y + self.y0_mm)


@dataclass(frozen=True)
class PinholeTruth:
    """Ground truth per camera pixel.

    Attributes
    ----------
    points_mm : (H, W, 3) float64
        True surface point seen by each pixel, camera frame, mm (NaN where the ray misses).
    u, v : (H, W) float64
        True projector coordinates (projector units, distorted as the projector sees them),
        NaN where the projector does not light the point.
    """

    points_mm: FloatArray
    u: FloatArray
    v: FloatArray

    @property
    def valid(self) -> npt.NDArray[np.bool_]:
        """Pixels with a point lit by the projector."""
        return np.isfinite(self.u) & np.isfinite(self.v) & np.isfinite(self.points_mm).all(axis=-1)


def look_at_rig(
    camera: PinholeCamera,
    projector: PinholeProjector,
    projector_center_mm: tuple[float, float, float],
    target_mm: tuple[float, float, float],
) -> PinholeRig:
    """A rig whose projector sits at ``projector_center_mm`` (camera frame) and looks at
    ``target_mm``, its x axis as close to the camera's as the direction allows.

    ``R`` has rows ``(r1, r2, r3)``: ``r3`` the unit direction to the target,
    ``r1 = e_y x r3 / |e_y x r3|``, ``r2 = r3 x r1``; ``T = -R C_p``.
    """
    c = np.asarray(projector_center_mm, dtype=np.float64)
    r3 = np.asarray(target_mm, dtype=np.float64) - c
    r3 /= np.linalg.norm(r3)
    r1 = np.cross([0.0, 1.0, 0.0], r3)
    r1 /= np.linalg.norm(r1)
    r2 = np.cross(r3, r1)
    R = np.stack([r1, r2, r3])
    T = -R @ c
    return PinholeRig(
        camera=camera,
        projector=projector,
        R=(_triple(R[0]), _triple(R[1]), _triple(R[2])),
        T=_triple(T),
    )


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    """The three entries of a length-3 vector as Python floats."""
    return (float(values[0]), float(values[1]), float(values[2]))


def cast_truth(
    rig: PinholeRig,
    placed: PlacedScene,
    march_step_mm: float = 0.25,
    shadow_step_mm: float = 0.1,
) -> PinholeTruth:
    """Ray-cast ``placed`` through ``rig``: true points and projector coordinates per pixel.

    Each pixel's ray ``t d`` (``d`` from the camera's undistortion, Newton to 1e-6 px) is
    marched in steps of ``march_step_mm`` of depth between the scene's bounds; the first sign
    change of ``f(t) = t - Z_surface(t d)`` is refined by 60 bisections (to ~1e-13 mm). A
    point is shadowed when a sample of the segment to the projector centre (one every
    ``shadow_step_mm`` of path, up to the scene's top) lies more than 1e-6 mm inside the
    object. Points outside the projector image ``[-0.5, w - 0.5] x [-0.5, h - 0.5]`` or
    behind it get NaN coordinates.
    """
    cam = rig.camera
    h, w = cam.height_px, cam.width_px
    jj, kk = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    und = undistort_pixels(np.asarray(cam.K), cam.distortion, jj, kk)
    xn, yn = und.x, und.y
    z_near = placed.distance_mm - placed.scene.z_max_mm
    z_far = placed.distance_mm - placed.scene.z_min_mm

    def f(t: FloatArray) -> FloatArray:
        return t - placed.surface_z(t * xn, t * yn)

    n_steps = max(1, math.ceil((z_far - z_near) / march_step_mm))
    lo = np.full(xn.shape, z_near)
    hi = np.full(xn.shape, np.nan)
    f_lo = f(lo)
    found = f_lo >= 0
    hi[found] = lo[found]
    for i in range(1, n_steps + 1):
        t = np.full(xn.shape, z_near + (z_far - z_near) * i / n_steps)
        ft = f(t)
        hit = ~found & (ft >= 0)
        hi[hit] = t[hit]
        found |= hit
        lo = np.where(found, lo, t)
        if found.all():
            break
    a, b = lo.copy(), hi.copy()
    pending = found & (a < b)
    for _ in range(60):
        mid = 0.5 * (a + b)
        fm = f(mid)
        up = pending & (fm >= 0)
        b = np.where(up, mid, b)
        a = np.where(pending & ~up, mid, a)
    t_hit = np.where(found, b, np.nan)
    points = np.stack([t_hit * xn, t_hit * yn, t_hit], axis=-1)

    # projector coordinates
    R = np.asarray(rig.R)
    T = np.asarray(rig.T)
    xp = points @ R.T + T
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = project_normalized(
            np.asarray(rig.projector.K), rig.projector.distortion, xp[..., 0] / xp[..., 2], xp[..., 1] / xp[..., 2]
        )
    pw, ph = rig.projector.width, rig.projector.height
    lit = (xp[..., 2] > 0) & (u >= -0.5) & (u <= pw - 0.5) & (v >= -0.5) & (v <= ph - 0.5)
    lit &= ~_shadowed(rig, placed, points, shadow_step_mm)
    u = np.where(lit, u, np.nan)
    v = np.where(lit, v, np.nan)
    return PinholeTruth(points_mm=points, u=u, v=v)


def _shadowed(rig: PinholeRig, placed: PlacedScene, points: FloatArray, step_mm: float) -> npt.NDArray[np.bool_]:
    """Pixels whose segment to the projector centre passes inside the object."""
    c = rig.projector_center_mm
    z_top = placed.distance_mm - placed.scene.z_max_mm
    p = points.reshape(-1, 3)
    finite = np.isfinite(p).all(axis=1)
    out = np.zeros(len(p), dtype=bool)
    if placed.scene.z_max_mm == placed.scene.z_min_mm or not finite.any():
        return out.reshape(points.shape[:2])  # a plane shadows nothing
    q0 = p[finite]
    direction = c - q0
    # path length until the segment rises above the scene's top (Z < z_top), capped at the centre
    with np.errstate(divide="ignore", invalid="ignore"):
        s_top = np.where(direction[:, 2] < 0, (q0[:, 2] - z_top) / -direction[:, 2], 1.0)
    s_top = np.clip(s_top, 0.0, 1.0)
    length = np.linalg.norm(direction, axis=1) * s_top
    n = max(2, math.ceil(float(length.max()) / step_mm))
    blocked = np.zeros(len(q0), dtype=bool)
    for i in range(1, n + 1):
        s = s_top * i / n
        q = q0 + s[:, None] * direction
        inside = q[:, 2] > placed.surface_z(q[:, 0], q[:, 1]) + 1e-6
        blocked |= inside & (s * np.linalg.norm(direction, axis=1) > 1e-6)
    out[np.flatnonzero(finite)] = blocked
    return out.reshape(points.shape[:2])
