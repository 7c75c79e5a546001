"""A stereo rig with a calibrated projector: the camera-projector pairs fused with the camera pair.

With the projector calibrated (``K``, ``dist``, ``R``, ``T`` in the rig file), every camera-0 pixel
has up to three estimates of its depth ``t`` (camera 0's Z, mm; the point is ``t (x_n, y_n, 1)``):

- **camera 0 - camera 1** (bit 0 of the pairs map, :data:`PAIR_CAMERAS`): ``t_01 = k / d`` from the
  normalized disparity ``d`` of the match (:mod:`~metrology.core.geometry.stereo_match`);
- **camera 0 - projector** (bit 1, :data:`PAIR_CAMERA0_PROJECTOR`): camera 0's ray meets the light
  plane of its decoded coordinate ``q``, exactly as a pinhole rig of camera 0 and the projector
  triangulates it (:class:`~metrology.core.geometry.pinhole.PreparedPinhole`, the ``plane`` method:
  the projector's distortion undone along the pixel's epipolar line);
- **camera 1 - projector** (bit 2, :data:`PAIR_CAMERA1_PROJECTOR`), where camera 1 matched: camera
  1's matched ray meets the same light plane. In camera 0's rectified frame (``Y = R_0 X``) camera
  1's ray is ``Y(Z) = (Z (x_r + d) - b, Z y_r, Z)`` (``x_r, y_r`` the pixel's rectified normalized
  coordinates, ``b`` the rectified baseline) and the plane ``n . (R_p X + T_p) = 0`` with
  ``n = (1, 0, -x_p)`` (axis ``u``; ``(0, 1, -y_p)`` for ``v``; ``x_p`` the undistorted normalized
  projector coordinate the camera 0 - projector pair found) is ``m . Y + n . T_p = 0``,
  ``m = R_0 R_p^T n``, so ``Z = (b m_x - n . T_p) / (m . (x_r + d, y_r, 1))``. The point is projected
  on camera 0's ray (as the 2-D match does with its midpoints): ``t_1p = (Y . a) / (a . a) / w``,
  ``a = (x_r, y_r, 1)``, ``w = (R_0 (x_n, y_n, 1))_z``.

**Covariance model.** The estimates are functions of two measured quantities: camera 0's decoded
coordinate ``q`` at the pixel (noise ``e_0``, standard deviation ``sigma_0``) and the disparity
``d``, whose noise is ``(e~_0 - e_1) / (s f)`` (``s`` camera 1's coordinate slope at the match per
rectified pixel, ``f`` the rectified focal length, ``e_1`` camera 1's noise, ``e~_0`` camera 0's
noise after the resampling chain). ``d`` shares camera 0's noise with ``q``::

    Var q = sigma_0^2,   Var d = sigma_d^2 (stereo_match's disparity sigma),
    Cov(q, d) = c sigma_0^2 / (s f)

with ``c`` the weight a camera-0 pixel has on itself through the rectification and back
(:meth:`~metrology.core.geometry.stereo_match.PreparedStereo.self_weight`; white noise per pixel).
To first order ``t_k = t + J_k . (dq, dd)``, ``J`` the estimates' derivatives (``J_01 = (0, -t/d)``,
``J_0p = (dt_0p/dq, 0)``, ``J_1p = (dt_1p/dq, dt_1p/dd)``; the ``q`` derivatives by a forward difference of
:data:`COORDINATE_STEP` projector units through the same code), so the estimates' covariance is
``Sigma = J Sigma_m J^T`` with ``Sigma_m`` the 2x2 covariance of ``(q, d)``. It has rank 2: three
estimates from two measured quantities. The BLUE (generalised least squares)
``t^ = w . t_k``, ``w = Sigma^+ 1 / (1^T Sigma^+ 1)``, is then computed in measurement space:
``1 = J g`` with ``g = (1 / (dt_0p/dq), -d / t)`` (the change of ``(q, d)`` along the ray), and the
optimal combination of the measured quantities is ``z = Sigma_m^-1 g / (g^T Sigma_m^-1 g)``; the
estimates' weights are the minimum-norm solution of ``J^T w = z``, ``w = J (J^T J)^-1 z`` (the one in
the range of ``Sigma``: the pseudo-inverse's), normalised to sum 1, and the fused variance is

    sigma_t^2 = 1 / (g^T Sigma_m^-1 g).

The camera 1 - projector estimate therefore adds no information to first order (it is a function of
the other two's inputs): its weight only shares the fused value among the three. A pixel camera 1
does not see (its shadow, an occlusion, outside its field, a refused match) keeps the camera 0 -
projector estimate, ``sigma_t = |dt_0p/dq| sigma_0``; a pixel whose light plane cannot be solved keeps
the camera pair's. Without the decoder's noise maps both cameras' noise is taken equal (the weights
then follow from the geometry alone).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.geometry.base import GeometryOptions, triangulate_frame
from metrology.core.geometry.stereo_kernels import camera1_depth_tile, fuse_tile

if TYPE_CHECKING:
    from metrology.core.geometry.pinhole import PinholeRig
    from metrology.core.geometry.stereo_match import PreparedStereo

PAIR_CAMERAS = 1
"""Bit of the pairs map: the camera pair (camera 0 - camera 1) measured the point."""
PAIR_CAMERA0_PROJECTOR = 2
"""Bit of the pairs map: camera 0 and the calibrated projector measured the point."""
PAIR_CAMERA1_PROJECTOR = 4
"""Bit of the pairs map: camera 1 and the calibrated projector measured the point."""
PAIR_NAMES: dict[int, str] = {
    PAIR_CAMERAS: "camera0-camera1",
    PAIR_CAMERA0_PROJECTOR: "camera0-projector",
    PAIR_CAMERA1_PROJECTOR: "camera1-projector",
}
"""Each bit's pair, as summaries name it."""
COORDINATE_STEP = 0.05
"""Forward-difference step of the decoded coordinate, projector units (derivatives of ``t_0p``, ``t_1p``)."""
DISPARITY_STEP = 1e-7
"""Forward-difference step of the normalized disparity (derivative of ``t_1p``)."""


def pair_combination(bits: int) -> str:
    """The pairs of a pairs-map value joined by ``+`` (``"camera0-camera1+camera0-projector"``), or
    ``"none"``."""
    names = [name for bit, name in PAIR_NAMES.items() if bits & bit]
    return "+".join(names) if names else "none"


def points_per_pairs(pairs: np.ndarray) -> dict[str, int]:
    """The measured points per pair combination of a ``(H, W)`` uint8 pairs map (0: not measured,
    left out), keyed by :func:`pair_combination`, in increasing value order."""
    counts = np.bincount(np.asarray(pairs, np.uint8).ravel(), minlength=8)
    return {pair_combination(value): int(counts[value]) for value in range(1, 8) if counts[value]}


@dataclass(frozen=True)
class FusedDepth:
    """What :meth:`PairFusion.fuse` gives, on camera 0's grid.

    Attributes
    ----------
    t_mm : (H, W) float64
        Fused depth (camera 0's Z), mm; NaN where no pair measured.
    sigma_mm : (H, W) float64
        Its standard deviation (camera Z), mm, in the unit the noise maps give (see the module docstring).
    pairs : (H, W) uint8
        The pairs that measured each pixel (bits :data:`PAIR_CAMERAS`, :data:`PAIR_CAMERA0_PROJECTOR`,
        :data:`PAIR_CAMERA1_PROJECTOR`); 0 where not measured.
    estimates : dict of str to (H, W) float64
        Each pair's depth (``"01"``, ``"0p"``, ``"1p"``), NaN where that pair did not measure.
    """

    t_mm: np.ndarray
    sigma_mm: np.ndarray
    pairs: np.ndarray
    estimates: dict[str, np.ndarray]


class PairFusion:
    """The camera-projector pairs of a prepared stereo rig whose projector is calibrated (module
    docstring). Built once per prepared rig; read-only afterwards."""

    def __init__(self, stereo: PreparedStereo, projector: PinholeRig) -> None:
        self.stereo = stereo
        self.pinhole = projector.prepare(
            projector.shape,
            (projector.projector.width, projector.projector.height),
            GeometryOptions(triangulate=stereo.axis),
        )
        self._i = 0 if stereo.axis == "u" else 1
        self._Rp = np.asarray(projector.R, np.float64)
        self._Tp = np.asarray(projector.T, np.float64)
        G = stereo.rect.R0 @ self._Rp.T
        i, Tp = self._i, self._Tp
        # camera1_depth's plane terms (b, g_i, g_z, T_i, T_z) and the projector's rows i and z with T
        self._plane = np.array([stereo.rect.baseline_mm, *G[:, i], *G[:, 2], Tp[i], Tp[2]], np.float64)
        self._projector_rows = np.array([*self._Rp[i], Tp[i], *self._Rp[2], Tp[2]], np.float64)

    def camera0_projector(self, q: np.ndarray, threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Camera 0 - projector depth ``t_0p`` (mm) of camera 0's decoded coordinate ``q`` ((H, W)
        float32, projector units) and the undistorted normalized projector coordinate ``x_p`` of the
        plane it met (both (H, W) float64; NaN where not triangulated)."""
        points = triangulate_frame(self.pinhole, q, None, points=True, heights=False, threads=threads).points_mm
        assert points is not None
        p = points.astype(np.float64)
        Rp, Tp = self._Rp, self._Tp
        i = self._i
        coded = Rp[i, 0] * p[..., 0] + Rp[i, 1] * p[..., 1] + Rp[i, 2] * p[..., 2] + Tp[i]
        depth = Rp[2, 0] * p[..., 0] + Rp[2, 1] * p[..., 1] + Rp[2, 2] * p[..., 2] + Tp[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return p[..., 2], coded / depth

    def camera1_projector(self, rows: slice, xp: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Camera 1 - projector depth ``t_1p`` (mm, on camera 0's ray; module docstring) of camera 0's
        ``rows``: the light plane ``x_p`` and camera 1's matched ray at normalized disparity ``d``
        ((n, W) float64 each); NaN where the point is not in front of camera 0
        (:func:`~metrology.core.geometry.stereo_kernels.camera1_depth`)."""
        s = self.stereo
        out = np.empty(np.shape(xp))
        camera1_depth_tile(
            np.ascontiguousarray(xp, np.float64),
            np.ascontiguousarray(d, np.float64),
            s.x0r[rows],
            s.y0r[rows],
            s.w[rows],
            self._plane,
            out,
        )
        return out

    def fuse(
        self,
        q: np.ndarray,
        d: np.ndarray,
        sigma0: np.ndarray,
        sigma_d: np.ndarray,
        d_per_q: np.ndarray,
        threads: int | None = None,
        self_weight: np.ndarray | None = None,
    ) -> FusedDepth:
        """Fuse the pairs' depths of camera 0's pixels (module docstring), tile by tile in a compiled
        kernel (:func:`~metrology.core.geometry.stereo_kernels.fuse_tile`).

        Parameters
        ----------
        q : (H, W) float32
            Camera 0's decoded coordinate of the matched axis, projector units, NaN where not decoded.
        d : (H, W) float32
            The normalized disparity on camera 0's grid, NaN where camera 1 did not match.
        sigma0 : (H, W) float32
            Camera 0's coordinate standard deviation, projector units.
        sigma_d : (H, W) float32
            The disparity's standard deviation (normalized).
        d_per_q : (H, W) float32
            ``1 / (s f)``: the disparity's change per unit of camera 0's coordinate noise (signed).
        threads : int, optional
            Threads over row tiles (does not change the result).
        self_weight : (H, W) float32, optional
            ``c`` per pixel; default the resampling chain's
            (:meth:`~metrology.core.geometry.stereo_match.PreparedStereo.self_weight`).
        """
        from metrology.core.tiling import run_tiled

        q32 = np.ascontiguousarray(q, np.float32)
        points = [  # q is the matched axis's coordinate: the pinhole model's u or v
            triangulate_frame(
                self.pinhole, *((at, None) if self._i == 0 else (None, at)), points=True, heights=False, threads=threads
            ).points_mm
            for at in (q32, q32 + np.float32(COORDINATE_STEP))
        ]
        p0, p0h = points
        assert p0 is not None and p0h is not None
        weight = self.stereo.self_weight() if self_weight is None else self_weight
        shared = np.asarray(d_per_q, np.float32) * weight
        s = self.stereo
        shape = q32.shape
        out = FusedDepth(
            t_mm=np.empty(shape),
            sigma_mm=np.empty(shape),
            pairs=np.empty(shape, np.uint8),
            estimates={"01": np.empty(shape), "0p": p0[..., 2].astype(np.float64), "1p": np.empty(shape)},
        )
        steps = np.array([COORDINATE_STEP, DISPARITY_STEP])
        inputs = [np.ascontiguousarray(a, np.float32) for a in (d, sigma0, sigma_d, shared)]

        def run(rows: slice) -> None:
            dd, s0, sd, sh = (a[rows] for a in inputs)
            fuse_tile(
                dd,
                p0[rows],
                p0h[rows],
                s0,
                sd,
                sh,
                s.k[rows],
                s.x0r[rows],
                s.y0r[rows],
                s.w[rows],
                self._plane,
                self._projector_rows,
                steps,
                out.t_mm[rows],
                out.sigma_mm[rows],
                out.pairs[rows],
                out.estimates["01"][rows],
                out.estimates["1p"][rows],
            )

        run_tiled(run, shape[0], shape[1], threads)
        return out
