"""The stereo model prepared: rectification, matching along epipolar lines, triangulation.

A :class:`~metrology.core.geometry.stereo.StereoRig` prepared for camera 0's frame
(:class:`PreparedStereo`) turns both cameras' decoded maps of one projector axis into points on
camera 0's pixel grid in three steps (:meth:`PreparedStereo.combine`, then
:meth:`PreparedStereo.triangulate_rows`):

1. **Rectify.** ``R_0, R_1`` of ``cv2.stereoRectify`` turn both cameras so that their image rows
   are epipolar lines (the cameras side by side: camera 1's rectified centre on the rectified x
   axis, at ``b = (R_1 T)_x`` mm). One rectified focal length ``f`` (the mean of the four ``fx, fy``)
   and one row origin serve both; each camera keeps its own column origin, so the rectified grids
   cover exactly what each camera sees. The tables (computed once per rig and kept): for every
   rectified pixel, where it lies in its camera (the ray ``R_c^T (x_r, y_r, 1)``, distorted by the
   camera's lens, through ``K_c``); for every camera-0 pixel, where it lies in camera 0's rectified
   grid (its undistorted ray, Newton to 1e-6 px, turned by ``R_0``). Each decoded map is sampled
   on the rectified grid bilinearly with exact weights (:class:`Bilinear`; ``cv2.remap`` quantises
   its weights to 1/32 pixel, far too coarse here); a NaN neighbour makes the sample NaN, so
   undecoded pixels never blend in.
2. **Match.** For every valid rectified camera-0 pixel of value ``q``, the camera-1 position on
   the same rectified row where the decoded coordinate is ``q``: the segment ``[x, x + 1]`` of
   camera 1's row with ``u(x) <= q < u(x + 1)`` (both decoded), ``x_1 = x + (q - u(x)) / (u(x + 1) -
   u(x))`` refined to the root of the cubic through ``u(x - 1) .. u(x + 2)`` inside a monotone run
   (:func:`~metrology.core.geometry.stereo_kernels.run_position`; linear interpolation errs by up
   to ``u'' / (8 u')`` px), the position from the decoded values (no pixel locking).
   Found by a merge walk along camera 1's running maximum (camera 0's consistent values grow along
   the row), in a compiled kernel (:mod:`~metrology.core.geometry.stereo_kernels`).
   *Unique matches only*: no decoded value right of ``x + 1`` is at most ``q`` (a
   running minimum from the right), so no other segment of the row holds ``q``. *Left-right
   consistency*: matching ``q`` back from camera 1 into camera 0's row must land on the same
   pixel; with the same rule this holds exactly when ``q`` is above every decoded value left of
   its pixel and below every one right of it, which is what is tested. An *isolated out-of-order
   value* (its two neighbours decoded and in order, itself not between them: a one-pixel spike or
   dip) counts as not decoded in either camera, so it refuses itself alone rather than the rest of
   its row. (When the coordinate falls along the rows both maps are negated first.)
3. **Triangulate.** The disparity ``d = x_1n - x_0n`` (rectified normalized coordinates) is
   sampled back at each camera-0 pixel's rectified position (bilinear; exact for a plane, whose
   disparity is affine in rectified coordinates). The rays of the two cameras meet at rectified
   depth ``Z_r = b / d``; on camera 0's pixel ray ``t (x_n, y_n, 1)`` that is camera-0 depth
   ``t = Z_r / w``, ``w = (R_0 (x_n, y_n, 1))_z``, so ``t = k / d`` with the per-pixel table
   ``k = b / w``, and the point is ``t (x_n, y_n, 1)`` (camera 0's frame, mm).
4. **Direct matches.** Steps 1 and 3 each need four decoded neighbours (a rectified sample with
   one undecoded neighbour takes the plane through the other three; with two it is NaN), so camera
   0's outer rows and columns and the pixels beside one camera 0 dropped get no disparity, nor do
   those whose rectified neighbours camera 1 matched in part. Such a decoded pixel is matched at its
   own rectified position ``(x_0, y_0)`` without resampling camera 0: its own value ``q`` in camera
   1's rectified rows ``r = floor(y_0)`` and ``r + 1`` by step 2's rules (left-right consistency
   against camera 0's rectified rows ``r``, ``r + 1``), ``x_1 = (1 - w) x_1(r) + w x_1(r + 1)``,
   ``w = y_0 - r``: the line ``u_1 = q`` is straight in camera 1's rectified image for a plane lit
   by a pinhole projector (:meth:`PreparedStereo._match_direct`).

Uncertainty (first order): ``u_1(x_1) = q`` moves by ``dx_1 = (dq - du_1) / u_1'`` so
``sigma_x1 = sqrt(sigma_0^2 + sigma_1^2) / |u_1'|`` (rectified px, ``u_1'`` the segment's slope),
``sigma_d = sigma_x1 / f``, and ``sigma_point = |dt/dd| |(x_n, y_n, 1)| sigma_d = t |d|^-1 |(x_n, y_n, 1)| sigma_d``
along camera 0's ray (at a direct match camera 0's ``sigma_0`` is its own and camera 1's share is
multiplied by its interpolation gain, :meth:`PreparedStereo._camera1_gain`).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.distortion import UNDISTORT_TOL_PX, project_normalized, undistort_pixels
from metrology.core.geometry.base import (
    CameraRays,
    CombinedMaps,
    GeometryError,
    PlaneCoordinates,
    PreparedGeometry,
    ReferenceSurface,
    check_frame,
)
from metrology.core.geometry.match_2d_kernels import (
    cell_buckets,
    disparity_sigma_tile,
    match_2d_tile,
    midpoint_tile,
    undistort_tile,
)
from metrology.core.geometry.pinhole import (
    PinholeCamera,
    PinholeProjector,
    PinholeReference,
    PinholeRig,
    camera_rays_of,
    plane_coordinates_of,
    ray_points,
    reference_plane,
)
from metrology.core.geometry.stereo_fusion import PAIR_CAMERAS, PairFusion
from metrology.core.geometry.stereo_kernels import (
    MATCH_SCRATCH_ROWS,
    SAMPLE_STRICT,
    SAMPLE_TRIANGLE,
    depth_tile,
    direct_candidates,
    match_pixels,
    match_tile,
    row_steps,
    sample_tile,
)
from metrology.core.tiling import run_tiled, thread_scratch

if TYPE_CHECKING:
    from metrology.core.geometry.stereo import StereoRig

NOISE_GAIN_FIELDS = 4
"""White-noise fields that estimate :meth:`PreparedStereo.noise_gain`."""
NOISE_GAIN_WINDOW_PX = 15
"""Side of the box that averages :meth:`PreparedStereo.noise_gain`'s squared samples, px."""
MIN_HORIZONTAL = 0.9
"""Smallest ``|(R_1 T)_x| / |T|`` accepted: the cameras must sit side by side (rows are epipolar lines)."""


_EVERYWHERE = np.empty((0, 0), np.float32)
"""``where`` of :func:`~metrology.core.geometry.stereo_kernels.sample_tile` that samples every position."""


@dataclass(frozen=True)
class Bilinear:
    """Bilinear sampling of an ``(h, w)`` map at fixed positions, with exact weights.

    Attributes
    ----------
    index : int32 array
        Flat index of each position's top-left neighbour (0 outside the map).
    inner : uint8 array
        1 where the top-left neighbour is at least one pixel in from the map's left and top edges and
        two from its right and bottom ones (where both symmetric curvature stencils fit: the fast path).
    wx, wy : float32 arrays
        Weights of the right and lower neighbours, in [0, 1]; NaN outside the map (so is the sample).
    width : int
        ``w``: the map's row stride.
    fallback : int
        Where a neighbour is NaN: :data:`~metrology.core.geometry.stereo_kernels.SAMPLE_STRICT` (the
        sample is NaN) or ``SAMPLE_TRIANGLE`` (with one neighbour NaN, the plane through the other
        three: :func:`~metrology.core.geometry.stereo_kernels.sample_tile`).
    """

    index: np.ndarray
    inner: np.ndarray
    wx: np.ndarray
    wy: np.ndarray
    width: int
    fallback: int = SAMPLE_STRICT

    @classmethod
    def at(cls, x: np.ndarray, y: np.ndarray, shape: tuple[int, int], fallback: int = SAMPLE_STRICT) -> Bilinear:
        """Sampling at pixel positions ``(x, y)`` (column, row; pixel centres at integers) of an
        ``(h, w)`` map (``h, w >= 2``); positions outside ``[0, w - 1] x [0, h - 1]`` give NaN;
        ``fallback`` where a neighbour is NaN (class docstring)."""
        h, w = shape
        inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        ix = np.clip(np.floor(np.where(inside, x, 0.0)), 0, w - 2).astype(np.intp)
        iy = np.clip(np.floor(np.where(inside, y, 0.0)), 0, h - 2).astype(np.intp)
        wx = np.where(inside, x - ix, np.nan).astype(np.float32)
        wy = np.where(inside, y - iy, np.nan).astype(np.float32)
        inner = ((ix >= 1) & (ix <= w - 3) & (iy >= 1) & (iy <= h - 3)).astype(np.uint8)
        index = (iy * w + ix).astype(np.int32)
        return cls(index=index, inner=inner, wx=wx, wy=wy, width=w, fallback=fallback)

    def sample(
        self,
        image: np.ndarray,
        rows: slice | None = None,
        out: np.ndarray | None = None,
        curvature: bool = False,
        where: np.ndarray | None = None,
    ) -> np.ndarray:
        """``image`` (float32 ``(h, w)``, the map) at the positions (of ``rows`` of them), float32; NaN
        where the position is outside, where ``where`` (float32, the positions' shape) is NaN, and where
        a neighbour is NaN unless :attr:`fallback` finds the value from the others. With ``curvature``
        the parabolic terms
        are added, ``-(wx (1 - wx) c_xx + wy (1 - wy) c_yy) / 2`` with ``c_xx``, ``c_yy`` the second
        differences along the row and the column averaged over the cell's two sides, one-sided where
        a neighbour beyond the cell is missing (exact for a quadratic map; each term left out only
        where no three samples in a line give it;
        :func:`~metrology.core.geometry.stereo_kernels.sample_tile`)."""
        rows = rows if rows is not None else slice(0, self.index.shape[0])
        index, inner, wx, wy = self.index[rows], self.inner[rows], self.wx[rows], self.wy[rows]
        shape = index.shape
        if out is None:
            out = np.empty(shape, np.float32)
        image = np.ascontiguousarray(image, dtype=np.float32).reshape(-1, self.width)
        two_d = (lambda a: a.reshape(1, -1)) if len(shape) == 1 else (lambda a: a)
        mask = _EVERYWHERE if where is None else two_d(np.ascontiguousarray(where[rows], dtype=np.float32))
        sample_tile(image, two_d(index), two_d(inner), two_d(wx), two_d(wy), two_d(out), curvature, self.fallback, mask)
        return out


@dataclass(frozen=True)
class Rectification:
    """The rectified grids of both cameras (module docstring, step 1).

    Attributes
    ----------
    R0, R1 : (3, 3) float64
        Rotations of camera 0's and camera 1's frames into their rectified frames.
    baseline_mm : float
        ``b = (R_1 T)_x``: camera 1's rectified centre on the rectified x axis (signed), mm.
    f : float
        Rectified focal length, px.
    cy : float
        Rectified row of the normalized ``y = 0``; both grids share their rows.
    cx : (float, float)
        Rectified column of the normalized ``x = 0`` in camera 0's and camera 1's grid.
    shapes : ((int, int), (int, int))
        ``(rows, columns)`` of each camera's rectified grid.
    """

    R0: np.ndarray
    R1: np.ndarray
    baseline_mm: float
    f: float
    cy: float
    cx: tuple[float, float]
    shapes: tuple[tuple[int, int], tuple[int, int]]


def _cv_camera(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    dist = np.asarray(camera.dist if camera.dist else (0.0, 0.0, 0.0, 0.0, 0.0), dtype=np.float64)
    return np.asarray(camera.K, dtype=np.float64), dist


def _border(camera: PinholeCamera, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates of the camera's border pixels (every ``step``-th and the corners)."""
    w, h = camera.width_px, camera.height_px
    xs = np.unique(np.r_[np.arange(0, w, step), w - 1]).astype(np.float64)
    ys = np.unique(np.r_[np.arange(0, h, step), h - 1]).astype(np.float64)
    px = np.r_[xs, xs, np.zeros_like(ys), np.full_like(ys, w - 1)]
    py = np.r_[np.zeros_like(xs), np.full_like(xs, h - 1), ys, ys]
    und = undistort_pixels(np.asarray(camera.K), camera.distortion, px, py)
    ok = np.isfinite(und.x) & np.isfinite(und.y)
    return und.x[ok], und.y[ok]


def _rectified_normalized(R: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R (x, y, 1)`` as rectified normalized ``(x_r, y_r)`` and its ``z`` (float64)."""
    rx = R[0, 0] * x + R[0, 1] * y + R[0, 2]
    ry = R[1, 0] * x + R[1, 1] * y + R[1, 2]
    rz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    return rx / rz, ry / rz, rz


def rectification(rig: StereoRig) -> Rectification:
    """The rectified grids of ``rig`` (module docstring, step 1). :class:`GeometryError` when the
    cameras do not sit side by side."""
    import cv2

    K0, D0 = _cv_camera(rig.camera0)
    K1, D1 = _cv_camera(rig.camera1)
    R = np.asarray(rig.R, dtype=np.float64)
    T = np.asarray(rig.T, dtype=np.float64).reshape(3, 1)
    size = (rig.camera0.width_px, rig.camera0.height_px)
    R0, R1, *_ = cv2.stereoRectify(K0, D0, K1, D1, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    t = R1 @ T.ravel()
    if abs(t[0]) < MIN_HORIZONTAL * float(np.linalg.norm(t)):
        raise GeometryError(
            "the stereo rig's cameras are one above the other (camera 1's T is mostly along y); this version "
            "matches along rows: place the cameras side by side"
        )
    f = float(np.mean([K0[0, 0], K0[1, 1], K1[0, 0], K1[1, 1]]))
    bounds = []
    for camera, Rc in ((rig.camera0, R0), (rig.camera1, R1)):
        x, y, z = _rectified_normalized(Rc, *_border(camera))
        if not (z > 0).all():
            raise GeometryError("a camera of the stereo rig sees more than a half-space of the rectified frame")
        bounds.append((x.min(), x.max(), y.min(), y.max()))
    y_lo = max(b[2] for b in bounds)
    y_hi = min(b[3] for b in bounds)
    if not y_hi > y_lo:
        raise GeometryError("the stereo rig's cameras share no epipolar line (their views do not overlap)")
    cy = -y_lo * f
    # whole pixels covering each extent (its last pixel centre at or beyond the extent's end: a
    # camera-0 pixel of the outermost row or column lies on the grid, not past it)
    rows = math.ceil((y_hi - y_lo) * f) + 1
    cx = tuple(-b[0] * f for b in bounds)
    shapes = tuple((rows, math.ceil((b[1] - b[0]) * f) + 1) for b in bounds)
    return Rectification(
        R0=R0,
        R1=R1,
        baseline_mm=float(t[0]),
        f=f,
        cy=cy,
        cx=(float(cx[0]), float(cx[1])),
        shapes=(shapes[0], shapes[1]),
    )


def _forward(camera: PinholeCamera, Rc: np.ndarray, rect: Rectification, index: int) -> Bilinear:
    """Where each pixel of camera ``index``'s rectified grid lies in the camera's image."""
    rows, cols = rect.shapes[index]
    xr = (np.arange(cols, dtype=np.float64) - rect.cx[index]) / rect.f
    yr = (np.arange(rows, dtype=np.float64) - rect.cy) / rect.f
    xr, yr = np.meshgrid(xr, yr)
    # the ray R_c^T (x_r, y_r, 1) in the camera's frame
    X = Rc[0, 0] * xr + Rc[1, 0] * yr + Rc[2, 0]
    Y = Rc[0, 1] * xr + Rc[1, 1] * yr + Rc[2, 1]
    Z = Rc[0, 2] * xr + Rc[1, 2] * yr + Rc[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px, py = project_normalized(np.asarray(camera.K), camera.distortion, X / Z, Y / Z)
    px = np.where(Z > 0, px, np.nan)
    return Bilinear.at(px, py, (camera.height_px, camera.width_px), SAMPLE_TRIANGLE)


@dataclass(frozen=True)
class Matched:
    """Matches of a rectified camera-0 grid: camera 1's sub-pixel column (NaN: no unique,
    consistent match) and the slope of camera 1's row there (projector units per px)."""

    x1: np.ndarray
    slope: np.ndarray


@dataclass(frozen=True)
class DirectMatches:
    """Camera-0 pixels matched at their own positions (:meth:`PreparedStereo._match_direct`).

    Attributes
    ----------
    index : (n,) intp
        Flat indices of the pixels on camera 0's grid.
    x1, slope, d : (n,) float32
        Camera 1's rectified column at the pixel's epipolar line, camera 1's slope there (projector
        units per px) and the normalized disparity; NaN where not matched.
    y : (n,) float64
        The pixel's rectified row (its epipolar line), rectified px.
    columns : (n, 2) float64
        Camera 1's columns on the rectified rows ``floor(y)`` and ``floor(y) + 1`` (clipped to the grid).
    """

    index: np.ndarray
    x1: np.ndarray
    slope: np.ndarray
    d: np.ndarray
    y: np.ndarray
    columns: np.ndarray


def match_rows(u0: np.ndarray, u1: np.ndarray, lo: float, hi: float) -> Matched:
    """Match rows of rectified maps whose coordinate grows along the rows (module docstring, step 2).

    Parameters
    ----------
    u0 : (n, W0) float32
        Camera 0's rectified decoded coordinate, NaN where not decoded.
    u1 : (n, W1) float32
        Camera 1's, same rows.
    lo, hi : float
        Bounds of every decoded value (projector units; values outside are not matched).

    Returns
    -------
    Matched
        ``x1`` (n, W0) float32 camera-1 columns, ``slope`` (n, W0) float32.
    """
    n, w0 = u0.shape
    x1, slope, d = (np.empty((n, w0), np.float32) for _ in range(3))
    scratch = np.empty((MATCH_SCRATCH_ROWS, max(w0, u1.shape[1])), np.float64)
    u0 = np.ascontiguousarray(u0, dtype=np.float32)
    u1 = np.ascontiguousarray(u1, dtype=np.float32)
    rows0, rows1 = np.empty((n, 2, w0), np.float32), np.empty((n, 2, u1.shape[1]), np.float32)
    match_tile(u0, u1, float(lo), float(hi), np.zeros(w0, np.float32), 1.0, 0.0, x1, slope, d, scratch, rows0, rows1)
    return Matched(x1=x1, slope=slope)


class PreparedStereo(PreparedGeometry):
    """A :class:`~metrology.core.geometry.stereo.StereoRig` prepared for camera 0's frame: the
    rectification and its sampling tables, camera 0's rays and the depth table ``k`` (module
    docstring). Read-only once built; safe to share between threads.

    Its :meth:`combine` turns both cameras' decoded maps of :attr:`axis` into the normalized
    disparity ``d`` on camera 0's grid (and its sigma); :meth:`triangulate_rows` reads ``d`` as
    its ``u`` (and the disparity's sigma as ``sigma_in``). With a calibrated projector it also fuses
    the camera-projector pairs with the camera pair (:attr:`fusion`,
    :mod:`~metrology.core.geometry.stereo_fusion`).
    """

    def __init__(self, rig: StereoRig, axis: str) -> None:
        self.model = rig
        self.rig = rig
        self.shape = rig.shape
        self.projector_size = (rig.projector.width, rig.projector.height)
        self.axis = axis
        self.method = "plane"
        from metrology.core.geometry.pinhole import _camera_tables

        rect = rectification(rig)
        self.rect = rect
        self.forward = (_forward(rig.camera0, rect.R0, rect, 0), _forward(rig.camera1, rect.R1, rect, 1))
        xn, yn = _camera_tables(rig.camera0)
        x0r, y0r, w = _rectified_normalized(rect.R0, xn, yn)
        self.back = Bilinear.at(x0r * rect.f + rect.cx[0], y0r * rect.f + rect.cy, rect.shapes[0])
        self.x0r, self.y0r, self.w = x0r, y0r, w  # camera 0's pixels in its rectified frame (float64)
        self.xn, self.yn = xn, yn
        self.xn32, self.yn32 = xn.astype(np.float32), yn.astype(np.float32)
        self.norm_d = np.sqrt(xn * xn + yn * yn + 1.0).astype(np.float32)
        self.k = (rect.baseline_mm / w).astype(np.float32)
        cols = np.arange(rect.shapes[0][1], dtype=np.float32)
        self._x0n = (cols - np.float32(rect.cx[0])) / np.float32(rect.f)  # rectified camera-0 columns, normalized
        self._projector = _projector_geometry(rig)
        self.fusion = PairFusion(self, self._projector) if self._projector is not None else None
        self._gain: np.ndarray | None = None
        self._self_weight: np.ndarray | None = None
        self._gain_lock = threading.Lock()

    # ------------------------------------------------------------------ interface
    @property
    def required_axes(self) -> tuple[str, ...]:
        return (self.axis,)

    @property
    def has_model_plane(self) -> bool:
        return False

    def rectify(self, camera: int, image: np.ndarray, threads: int | None = None) -> np.ndarray:
        """Camera ``camera``'s ``(H_c, W_c)`` float32 map sampled on its rectified grid (NaN where
        a neighbour is NaN or outside the image), its parabolic terms included (:class:`Bilinear`)."""
        sampler = self.forward[camera]
        image = np.ascontiguousarray(image, dtype=np.float32)
        out = np.empty(self.rect.shapes[camera], np.float32)
        run_tiled(lambda rows: sampler.sample(image, rows, out[rows], True), *out.shape, threads)
        return out

    def rectify_both(
        self, image0: np.ndarray, image1: np.ndarray, threads: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rectify` of camera 0's ``image0`` and camera 1's ``image1`` in one pass of tiles (the
        two grids share their rows: each tile samples the same rows of both, and the threads wait for
        one another once)."""
        images = [np.ascontiguousarray(image, dtype=np.float32) for image in (image0, image1)]
        out = [np.empty(shape, np.float32) for shape in self.rect.shapes]

        def run(rows: slice) -> None:
            for sampler, image, rectified in zip(self.forward, images, out, strict=True):
                sampler.sample(image, rows, rectified[rows], True)

        run_tiled(run, self.rect.shapes[0][0], self.rect.shapes[0][1] + self.rect.shapes[1][1], threads)
        return out[0], out[1]

    def combine(
        self,
        coordinates: Sequence[Mapping[str, np.ndarray | None]],
        sigma: Sequence[np.ndarray | None] | None = None,
        threads: int | None = None,
        other_sigma: Sequence[np.ndarray | None] | None = None,
    ) -> CombinedMaps:
        """Rectify both cameras' maps of :attr:`axis`, match them and sample the disparity back on
        camera 0's grid (module docstring, steps 1-3); with a calibrated projector, fuse the
        camera-projector pairs with the camera pair (:mod:`~metrology.core.geometry.stereo_fusion`).

        Parameters
        ----------
        coordinates : two mappings ``{axis: (H_c, W_c) float32}``
            Each camera's decoded (and filtered) projector coordinates, NaN where not decoded.
        sigma : two (H_c, W_c) float32 arrays, optional
            Each camera's standard deviation of the coordinate (projector units).

        Returns
        -------
        CombinedMaps
            ``u``: the normalized disparity ``d`` (H, W) float32 on camera 0's grid, NaN where
            not matched (with a calibrated projector the fused depth's ``d = k / t``, NaN where no
            pair measured); ``sigma``: its standard deviation (normalized), when ``sigma`` was given;
            ``pairs``: the pairs that measured each pixel (uint8 bits,
            :data:`~metrology.core.geometry.stereo_fusion.PAIR_CAMERAS` ...).
        """
        (u0,), (u1,) = self._maps(coordinates, (self.axis,))
        u0r, u1r = self.rectify_both(u0, u1, threads)
        proj = self.rig.projector
        size = proj.width if self.axis == "u" else proj.height
        lo, hi = -2.0, size + 1.0  # every decoded coordinate (the codec's field and its margin)
        sign = 1.0
        if _decreasing(u1r):
            np.negative(u0r, out=u0r)
            np.negative(u1r, out=u1r)
            lo, hi = -hi, -lo
            sign = -1.0
        rect = self.rect
        rows, cols0 = rect.shapes[0]
        disparity = np.empty((rows, cols0), np.float32)
        x1 = np.empty((rows, cols0), np.float32)
        step = np.empty((rows, cols0), np.float32)
        inv_f = 1.0 / rect.f
        offset = rect.cx[1] / rect.f

        cols1 = rect.shapes[1][1]
        width = max(cols0, cols1)
        # each row's running extrema and camera 1's cleaned row, kept for the direct matches
        rows0 = np.empty((rows, 2, cols0), np.float32)
        rows1 = np.empty((rows, 2, cols1), np.float32)

        def run(tile: slice) -> None:
            scratch = thread_scratch().get("stereo-match", (MATCH_SCRATCH_ROWS, width), np.float64)
            match_tile(
                u0r[tile],
                u1r[tile],
                lo,
                hi,
                self._x0n,
                inv_f,
                offset,
                x1[tile],
                step[tile],
                disparity[tile],
                scratch,
                rows0[tile],
                rows1[tile],
            )

        run_tiled(run, rows, width, threads)
        out = np.empty(self.shape, np.float32)
        # only where camera 0 decoded: _match_direct sets the other pixels NaN
        run_tiled(lambda r: self.back.sample(disparity, r, out[r], True, u0), *self.shape, threads)
        direct = self._match_direct(u0, u0r, (rows0, rows1), disparity, out, sign, lo, hi, threads)
        out.ravel()[direct.index] = direct.d
        noise = _noise_maps(sigma)
        if self.fusion is None and noise is None:
            return _camera_pair(out, None)
        s0, s1 = (None, None) if noise is None else noise
        # equal unit noise in both cameras when no noise maps are given: the weights from the geometry alone
        sigma_d = self._disparity_sigma(s0, s1, x1, step, direct, threads)
        if noise is not None:
            sigma_d[np.isnan(out)] = np.nan
        if self.fusion is None:
            return _camera_pair(out, sigma_d)
        with np.errstate(divide="ignore", invalid="ignore"):
            per_q = np.float32(sign) / (step * np.float32(rect.f))
        d_per_q = np.empty(self.shape, np.float32)
        run_tiled(lambda r: self.back.sample(per_q, r, d_per_q[r]), *self.shape, threads)
        shared = d_per_q * self.self_weight()
        # a directly matched pixel's disparity holds all of its own noise (its weight on itself is 1)
        shared.ravel()[direct.index] = np.float32(sign) / (direct.slope * np.float32(rect.f))
        return self._fuse(u0, out, sigma_d, shared, noise, threads)

    def _fuse(
        self,
        q: np.ndarray,
        d: np.ndarray,
        sigma_d: np.ndarray,
        shared: np.ndarray,
        noise: tuple[np.ndarray, np.ndarray] | None,
        threads: int | None,
    ) -> CombinedMaps:
        """The camera pair's disparity ``d`` ((H, W) float32, either match's) fused with the
        camera-projector pairs (:meth:`PairFusion.fuse
        <metrology.core.geometry.stereo_fusion.PairFusion.fuse>`: ``q`` camera 0's decoded coordinate
        of :attr:`axis`, ``sigma_d`` the disparity's sigma and ``shared`` its ``Cov(q, d) / sigma_0^2``
        under ``noise``, or under unit noise in both cameras when ``noise`` is None) as the maps
        :meth:`triangulate_rows` reads: ``d = k / t`` of the fused depth, its sigma when ``noise`` was
        given, and the pairs map."""
        assert self.fusion is not None
        sigma0 = np.ones(self.shape, np.float32) if noise is None else noise[0]
        fused = self.fusion.fuse(q, d, sigma0, sigma_d, shared, threads)
        with np.errstate(divide="ignore", invalid="ignore"):
            fused_d = (self.k / fused.t_mm).astype(np.float32)
            sigma = None if noise is None else (fused.sigma_mm * np.abs(fused_d) / fused.t_mm).astype(np.float32)
        return CombinedMaps(u=fused_d, v=None, sigma=sigma, pairs=fused.pairs)

    def _match_direct(
        self,
        u0: np.ndarray,
        u0r: np.ndarray,
        kept: tuple[np.ndarray, np.ndarray],
        disparity: np.ndarray,
        out: np.ndarray,
        sign: float,
        lo: float,
        hi: float,
        threads: int | None = None,
    ) -> DirectMatches:
        """Camera 0's decoded pixels that the resampling chain left without a disparity (``out`` NaN)
        because some of the rectified samples they are sampled back from are not decoded (at the
        frame's border, beside a pixel camera 0 dropped) or not matched (``disparity``, rectified: at
        the edge of camera 1's view, beside a refused match), matched at their own positions: the
        pixel's decoded value (times ``sign``) along its own epipolar line, between camera 1's
        rectified rows around it (:func:`~metrology.core.geometry.stereo_kernels.match_pixels`, from
        the rows ``match_tile`` ``kept``: its ``rows0_out`` and ``rows1_out``). Sets ``out`` NaN where
        camera 0 did not decode."""
        # only where the chain lacked a neighbour: among the four rectified samples the pixel is sampled
        # back from, one camera 0 did not decode or one camera 1 matched (not where all four were
        # decoded and camera 1 matched none: outside its view)
        index = np.empty(out.size, np.intp)
        found = direct_candidates(
            u0.ravel(), out.ravel(), self.back.index.ravel(), self.back.width, u0r.ravel(), disparity.ravel(), index
        )
        index = index[:found]
        rect = self.rect
        y = self.y0r.ravel()[index] * rect.f + rect.cy
        order = np.argsort(np.floor(y), kind="stable")
        index, y = index[order], y[order]
        x0n = self.x0r.ravel()[index]
        n = index.size
        x1, slope, d = (np.empty(n, np.float32) for _ in range(3))
        columns = np.empty((n, 2), np.float64)
        q = np.float64(sign) * u0.ravel()[index].astype(np.float64)
        x0 = x0n * rect.f + rect.cx[0]
        rows = rect.shapes[0][0]
        band = np.searchsorted(np.clip(np.floor(y), 0, rows - 2), np.arange(rows + 1))  # pixels per row band

        def run(tile: slice) -> None:
            part = slice(band[tile.start], band[tile.stop])
            match_pixels(
                kept[0],
                kept[1],
                lo,
                hi,
                q[part],
                x0[part],
                y[part],
                x0n[part],
                1.0 / rect.f,
                rect.cx[1] / rect.f,
                x1[part],
                slope[part],
                d[part],
                columns[part],
            )

        run_tiled(run, rows, rect.shapes[0][1], threads)
        return DirectMatches(index=index, x1=x1, slope=slope, d=d, y=y, columns=columns)

    def _camera1_gain(self, direct: DirectMatches) -> np.ndarray:
        """``(n,)`` float32 (NaN where not matched): the standard deviation of camera 1's column at each
        ``direct`` match per unit
        of white noise on camera 1's pixels, relative to its value at one pixel: the match's column is
        ``sum_k c_k u_k`` over the rectified samples it interpolates (rows ``r``, ``r + 1`` weighted
        ``1 - w``, ``w``; columns ``x``, ``x + 1`` of each weighted ``1 - s``, ``s``), each sample
        ``u_k = sum_j f_kj e_j`` of camera 1's pixels ``e_j`` (bilinear weights), so the gain is
        ``sqrt(sum_j (sum_k c_k f_kj)^2)``. The cubic's outer samples are left out (first order at the
        segment)."""
        rect, forward = self.rect, self.forward[1]
        rows, cols = rect.shapes[1]
        gain = np.full(direct.index.shape, np.nan, np.float32)
        matched = np.flatnonzero(np.isfinite(direct.x1))
        y, columns = direct.y[matched], direct.columns[matched]
        r = np.clip(np.floor(y), 0, rows - 2).astype(np.intp)
        w = y - r
        n = matched.size
        pixels = np.zeros((n, 16), np.int64)
        weights = np.zeros((n, 16), np.float64)
        fwx, fwy, findex = forward.wx.ravel(), forward.wy.ravel(), forward.index.ravel()
        k = 0
        for row, row_weight in ((0, 1.0 - w), (1, w)):
            x = columns[:, row]
            column = np.clip(np.floor(np.nan_to_num(x)), 0, cols - 2).astype(np.intp)
            s = np.nan_to_num(x) - column
            for dc, column_weight in ((0, 1.0 - s), (1, s)):
                at = (r + row) * cols + column + dc
                fx = np.nan_to_num(fwx[at].astype(np.float64))
                fy = np.nan_to_num(fwy[at].astype(np.float64))
                base = findex[at].astype(np.int64)
                for ey in (0, 1):
                    for ex in (0, 1):
                        pixels[:, k] = base + ex + ey * forward.width
                        weights[:, k] = row_weight * column_weight * (fx if ex else 1 - fx) * (fy if ey else 1 - fy)
                        k += 1
        same = pixels[:, :, None] == pixels[:, None, :]
        gain[matched] = np.sqrt((weights[:, :, None] * weights[:, None, :] * same).sum(axis=(1, 2)))
        return gain

    def _maps(
        self, coordinates: Sequence[Mapping[str, np.ndarray | None]], axes: tuple[str, ...]
    ) -> list[list[np.ndarray]]:
        """Each camera's float32 maps of ``axes``; :class:`GeometryError` naming the camera when one is
        missing or its size is not the rig's camera's."""
        if len(coordinates) != 2:
            raise GeometryError(f"a stereo rig combines the maps of 2 cameras, got {len(coordinates)}")
        maps = []
        for camera, coords in enumerate(coordinates):
            pair = []
            for axis in axes:
                m = coords.get(axis)
                if m is None:
                    raise GeometryError(f"camera {camera}'s capture lacks the projector's {axis} axis")
                expected = self.rig.camera_shapes[camera]
                if tuple(m.shape) != expected:
                    raise GeometryError(
                        f"camera {camera}'s map is {m.shape[1]}x{m.shape[0]} px but the rig's camera {camera} is "
                        f"{expected[1]}x{expected[0]} px"
                    )
                pair.append(np.ascontiguousarray(m, dtype=np.float32))
            maps.append(pair)
        return maps

    def noise_gain(self) -> np.ndarray:
        """``(H, W)`` float32: the standard deviation, at each camera-0 pixel, of white noise of unit
        standard deviation on camera 0's pixels after the resampling chain (onto the rectified grid and
        back): below 1, as interpolation averages neighbours. A property of the rig alone, estimated
        once (:data:`NOISE_GAIN_FIELDS` noise fields, each squared result averaged over
        :data:`NOISE_GAIN_WINDOW_PX` pixels: the sampling fractions change slowly across the frame)."""
        with self._gain_lock:
            if self._gain is None:
                import cv2

                rng = np.random.default_rng(0)
                total = np.zeros(self.shape, np.float64)
                for _ in range(NOISE_GAIN_FIELDS):
                    field = rng.standard_normal(self.shape).astype(np.float32)
                    rectified = np.empty(self.rect.shapes[0], np.float32)
                    self.forward[0].sample(field, None, rectified)
                    back = self.back.sample(rectified)
                    total += np.nan_to_num(back.astype(np.float64) ** 2)
                size = (NOISE_GAIN_WINDOW_PX, NOISE_GAIN_WINDOW_PX)
                mean = cv2.blur(total / NOISE_GAIN_FIELDS, size, borderType=cv2.BORDER_REFLECT)
                self._gain = np.sqrt(mean).astype(np.float32)
            return self._gain

    def self_weight(self) -> np.ndarray:
        """``(H, W)`` float32: the weight ``c`` each camera-0 pixel has on its own value after the
        resampling chain (onto camera 0's rectified grid and back, bilinear weights): ``c = sum_r b_r
        f_r``, ``b_r`` the back-sampling weight of the rectified pixel ``r`` and ``f_r`` that pixel's
        forward weight on the camera-0 pixel. With white noise of standard deviation ``sigma`` per
        pixel it is the covariance of a pixel's noise and its resampled noise over ``sigma^2`` (the
        disparity shares camera 0's noise with the pixel's coordinate:
        :mod:`~metrology.core.geometry.stereo_fusion`). Exact, computed once."""
        with self._gain_lock:
            if self._self_weight is None:
                back, forward = self.back, self.forward[0]
                h, w = self.shape
                own = np.arange(h * w, dtype=np.int64).reshape(h, w)
                bx, by = np.nan_to_num(back.wx.astype(np.float64)), np.nan_to_num(back.wy.astype(np.float64))
                fwx, fwy = np.nan_to_num(forward.wx.ravel()), np.nan_to_num(forward.wy.ravel())
                findex = forward.index.ravel().astype(np.int64)
                total = np.zeros((h, w), np.float64)
                for dy in (0, 1):
                    for dx in (0, 1):
                        weight_b = (bx if dx else 1 - bx) * (by if dy else 1 - by)
                        r = back.index.astype(np.int64) + dx + dy * back.width
                        fx, fy, base = fwx[r].astype(np.float64), fwy[r].astype(np.float64), findex[r]
                        for ey in (0, 1):
                            for ex in (0, 1):
                                hit = base + ex + ey * forward.width == own
                                weight_f = (fx if ex else 1 - fx) * (fy if ey else 1 - fy)
                                total += np.where(hit, weight_b * weight_f, 0.0)
                self._self_weight = total.astype(np.float32)
            return self._self_weight

    def _disparity_sigma(
        self,
        sigma0: np.ndarray | None,
        sigma1: np.ndarray | None,
        x1: np.ndarray,
        slope: np.ndarray,
        direct: DirectMatches,
        threads: int | None,
    ) -> np.ndarray:
        """The disparity's standard deviation on camera 0's grid (normalized; module docstring):
        ``sqrt(sigma_0^2 + sigma_1^2) / |u_1'| / f`` at the matched pixels, sampled back on camera
        0's grid, times the resampling chain's noise gain (:meth:`noise_gain`, the same for both
        cameras' share: both go onto a rectified grid and back); at the ``direct`` matches
        (:meth:`_match_direct`) ``sqrt(sigma_0^2 + (g_1 sigma_1)^2) / |u_1'| / f`` with camera 0's own
        sigma (not resampled), camera 1's at the nearest rectified pixel of the match and its gain
        ``g_1`` through the interpolation (:meth:`_camera1_gain`). ``sigma0``, ``sigma1`` None: unit
        noise in both cameras."""
        rect = self.rect
        hit = np.isfinite(x1)
        if sigma0 is None or sigma1 is None:
            sigma_x1 = np.full(x1.shape, math.sqrt(2.0), np.float32)
            sigma_direct = np.hypot(np.float32(1.0), self._camera1_gain(direct))
        else:
            s0, s1 = self.rectify_both(sigma0, sigma1, threads)
            rows, cols1 = rect.shapes[1]
            at = np.where(hit, np.clip(np.rint(x1), 0, cols1 - 1), 0).astype(np.intp)
            at += (np.arange(rows, dtype=np.intp) * cols1)[:, None]
            sigma_x1 = np.hypot(s0, s1.ravel().take(at))
            column = np.where(np.isfinite(direct.x1), np.clip(np.rint(direct.x1), 0, cols1 - 1), 0).astype(np.intp)
            row = np.clip(np.rint(direct.y), 0, rows - 1).astype(np.intp)
            sigma_direct = np.hypot(
                np.asarray(sigma0, np.float32).ravel()[direct.index],
                s1.ravel().take(row * cols1 + column) * self._camera1_gain(direct),
            )
        sigma_d = sigma_x1 / np.abs(slope * np.float32(rect.f))
        sigma_d[~hit] = np.nan
        back = np.empty(self.shape, np.float32)
        run_tiled(lambda r: self.back.sample(sigma_d, r, back[r]), *self.shape, threads)
        back *= self.noise_gain()
        back.ravel()[direct.index] = sigma_direct / np.abs(direct.slope * np.float32(rect.f))
        return back

    def plane_coordinates(self, reference: ReferenceSurface | None = None) -> PlaneCoordinates:
        """Camera-0 ``(X, Y)`` (mm) of the point of the reference plane each pixel's ray meets."""
        return plane_coordinates_of(self.xn, self.yn, reference, "a stereo rig")

    def camera_rays(self, supersample: int = 1) -> CameraRays:
        """Camera 0's rays (see :meth:`PreparedGeometry.camera_rays`)."""
        return camera_rays_of(self.rig.camera0, self.xn, self.yn, supersample)

    @property
    def projector_centre_mm(self) -> np.ndarray:
        """The calibrated projector's centre in camera 0's frame; :class:`GeometryError` when the rig's
        projector is not calibrated."""
        return self._projector_rig().prepare().projector_centre_mm

    def projector_coordinates(self, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The calibrated projector's coordinates of camera-0 points (as a pinhole rig's)."""
        return self._projector_rig().prepare().projector_coordinates(points_mm)

    def _projector_rig(self) -> PinholeRig:
        if self._projector is None:
            raise GeometryError(
                "the stereo rig's projector is not calibrated (the rig file gives its size alone); "
                "the virtual rig takes a projector of its own (render_stereo_capture's projector)"
            )
        return self._projector

    def reference(self, u: np.ndarray | None, v: np.ndarray | None, threads: int | None = None) -> PinholeReference:
        """The plane through the points of a reference capture (``u``: its disparity from :meth:`combine`)."""
        return reference_plane(self, u, v, threads)

    def triangulate_rows(
        self,
        rows: slice,
        u: np.ndarray | None,
        v: np.ndarray | None,
        *,
        reference: ReferenceSurface | None = None,
        points_out: np.ndarray | None = None,
        height_out: np.ndarray | None = None,
        sigma_in: np.ndarray | None = None,
        sigma_out: np.ndarray | None = None,
    ) -> None:
        """Points of camera 0's ``rows`` from the disparity ``u`` (:meth:`combine`): ``t = k / d``,
        ``t (x_n, y_n, 1)``; heights above a reference plane; sigma from ``sigma_in`` (the
        disparity's, normalized) along the ray."""
        if u is None:
            raise GeometryError("a stereo rig triangulates the disparity that combine() gives (u); got none")
        if height_out is not None and reference is None:
            raise GeometryError("a stereo rig's heights need its reference plane (a reference capture)")
        xn, yn = self.xn32[rows], self.yn32[rows]
        if points_out is not None:
            depth_tile(np.ascontiguousarray(u, dtype=np.float32), self.k[rows], xn, yn, points_out)
        if height_out is None and (sigma_in is None or sigma_out is None):
            return
        with np.errstate(divide="ignore", invalid="ignore"):
            t = self.k[rows] / u
        t[~(t > 0)] = np.nan
        if height_out is not None:
            if not isinstance(reference, PinholeReference):
                raise GeometryError(f"reference must come from this model, got {type(reference).__name__}")
            n = reference.normal.astype(np.float32)
            c = np.float32(reference.normal @ reference.centroid)
            height_out[...] = t * (n[0] * xn + n[1] * yn + n[2]) - c
        if sigma_in is not None and sigma_out is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                sigma_out[...] = t / np.abs(u) * self.norm_d[rows] * sigma_in

    def points_from_heights(self, z_mm: np.ndarray, reference: ReferenceSurface | None = None) -> np.ndarray:
        """Points on camera 0's rays (as a pinhole rig's): depth ``z`` without a reference, signed
        distance from the reference plane with one."""
        check_frame(self, "z_mm", z_mm)
        return ray_points(self.xn, self.yn, z_mm, reference)


MATCH_BUCKET = 2.0
"""Side of the projector-space buckets that index camera 1's cells for the 2-D match, projector units
(a cell spans about 1.5 units on the example rig: 7 cells scanned per pixel, 3 M bucket entries; 4
units scanned 18 and took 30 % more of the match's time, 1 unit saved another 10 % for twice the
entries)."""
CUBIC = True
"""Refine the 2-D match on camera 1's bicubic maps (``match_2d_kernels.refine_cubic``); False keeps the
cell's bilinear inverse (for comparisons: on the noise-free sphere of ``tests/core/test_stereo.py`` its
99th percentile is 1.5 um, the bicubic's 0.09 um)."""
MIDPOINT_STEP = 1e-6
"""Forward-difference step of camera 1's undistorted normalized coordinates (about 1e-3 px): the 2-D
match's ``dd/d(x_1n, y_1n)``."""


class PreparedStereo2D(PreparedStereo):
    """The stereo model matching in 2-D without rectification (both projector axes coded): each
    camera-0 pixel's decoded pair ``(u, v)`` is found in camera 1's image, in the one cell of four
    decoded pixels whose bilinear map holds it (Newton inverse; no other cell may hold it: unique
    matches only), refined on the bicubic maps of the 4 x 4 pixels around that cell (:data:`CUBIC`;
    the bilinear inverse alone errs by up to ``u'' / (8 u')`` px where the maps bend), and the two
    rays meet by their midpoint. The per-pixel work is compiled
    (:mod:`~metrology.core.geometry.match_2d_kernels`: the match, camera 1's undistortion, the
    midpoint and its slopes), tile by tile on the pool's threads.

    With camera 0's ray ``t a``, ``a = (x_n, y_n, 1)``, and camera 1's ray ``C + s b`` in camera 0's
    frame (``C = -R^T T``, ``b = R^T (x_1n, y_1n, 1)`` from camera 1's undistorted matched position),
    the closest points have ``t = ((a.C)(b.b) - (a.b)(b.C)) / D`` and ``s = ((a.b)(a.C) - (a.a)(b.C)) / D``,
    ``D = (a.a)(b.b) - (a.b)^2``; the point is the midpoint's projection on camera 0's ray,
    ``t_m = ((t a + C + s b) / 2 . a) / (a.a)``. :meth:`combine` hands it on as the disparity the
    epipolar path would have had, ``d = k / t_m``, so :meth:`triangulate_rows` is shared, and so is
    the fusion of a calibrated projector's pairs (:meth:`PreparedStereo._fuse`).

    **Uncertainty** (first order). Camera 1's match ``x_1 = (x_1, y_1)`` solves ``P_1(x_1) = p_0``
    (``P_1`` camera 1's bicubic ``(u, v)`` map, bilinear where the bicubic lacks a pixel; ``p_0``
    camera 0's decoded pair), so camera 0's noise ``e_0`` and camera 1's ``e_1`` (each pixel's, per
    axis) move it by ``dx_1 = A (e_0 - e~_1)``, ``A = J^-1`` the inverse of the map's 2x2 Jacobian ``J =
    d(u, v)/d(x, y)`` at the match and ``e~_1 = sum w_i e_1i`` the weighted mean of its 16 (or 4)
    pixels' noise (standard deviation ``g_1 sigma_1``, ``g_1 = sqrt(sum w_i^2)``). With ``g = dd/dx_1``
    (the midpoint's slopes, ``match_2d_kernels.midpoint_tile``) and ``G = g A`` (the disparity's change
    per unit of camera 0's ``u`` and ``v``)::

        Var d = G_u^2 (sigma_0u^2 + g_1^2 sigma_1u^2) + G_v^2 (sigma_0v^2 + g_1^2 sigma_1v^2),
        Cov(q, d) = G_i sigma_0i^2

    (``i`` :attr:`axis`; camera 0's values are used as decoded, not resampled; each camera's and
    axis's ``sigma`` the decoder's, camera 1's at the match's nearest pixel). Without the other
    axis's sigma maps (``other_sigma``) its noise is taken equal to :attr:`axis`'s."""

    @property
    def required_axes(self) -> tuple[str, ...]:
        return ("u", "v")

    @property
    def noise_axes(self) -> tuple[str, ...]:
        return (self.axis, "v" if self.axis == "u" else "u")

    def combine(
        self,
        coordinates: Sequence[Mapping[str, np.ndarray | None]],
        sigma: Sequence[np.ndarray | None] | None = None,
        threads: int | None = None,
        other_sigma: Sequence[np.ndarray | None] | None = None,
    ) -> CombinedMaps:
        """Both cameras' ``u`` and ``v`` maps (``{axis: (H_c, W_c) float32}``) to the equivalent
        disparity ``d = k / t_m`` (H, W) float32 on camera 0's grid (class docstring), its sigma when
        both cameras' ``sigma`` maps (of :attr:`axis`, projector units) are given (and ``other_sigma``,
        of the other axis; taken equal to ``sigma`` without them); with a calibrated
        projector fused with the camera-projector pairs (:mod:`~metrology.core.geometry.stereo_fusion`),
        as :meth:`PreparedStereo.combine`."""
        maps = self._maps(coordinates, ("u", "v"))
        (u0, v0), (u1, v1) = maps
        proj = self.rig.projector
        nu = math.ceil((proj.width + 2.0) / MATCH_BUCKET)
        nv = math.ceil((proj.height + 2.0) / MATCH_BUCKET)
        start, cells = cell_buckets(u1, v1, MATCH_BUCKET, nu, nv)
        h, w = self.shape
        x1 = np.empty((h, w), np.float32)
        y1 = np.empty((h, w), np.float32)
        slopes = np.empty((h, w, 5), np.float32)
        noise = _noise_maps(sigma)
        other = _noise_maps(other_sigma) if noise is not None else None
        with_slopes = self.fusion is not None or noise is not None
        d = np.empty((h, w))
        g = np.empty((h, w, 2)) if with_slopes else np.empty((1, 1, 2))
        sigma_d = np.empty((h, w), np.float32)
        shared = np.empty((h, w), np.float32)
        geometry = self._midpoint_geometry
        # each axis's noise, camera 0's at the pixel and camera 1's at the match's nearest pixel;
        # equal unit noise in both cameras and axes without noise maps (the weights from the geometry alone)
        unit = np.ones((1, 1), np.float32)
        s0, s1 = (unit, unit) if noise is None else noise
        o0, o1 = (s0, s1) if other is None else other

        def run(rows: slice) -> None:
            match_2d_tile(
                u0[rows], v0[rows], u1, v1, start, cells, MATCH_BUCKET, nu, nv, CUBIC, x1[rows], y1[rows], slopes[rows]
            )
            und = self._undistort_camera1(x1[rows], y1[rows])
            midpoint_tile(
                und,
                self.xn[rows],
                self.yn[rows],
                self.k[rows],
                geometry,
                MIDPOINT_STEP,
                d[rows],
                g[rows] if with_slopes else g,
                with_slopes,
            )
            if with_slopes:
                disparity_sigma_tile(
                    slopes[rows],
                    g[rows],
                    x1[rows],
                    y1[rows],
                    s0 if noise is None else s0[rows],
                    o0 if other is None and noise is None else o0[rows],
                    s1,
                    o1,
                    noise is not None,
                    self.axis == "u",
                    sigma_d[rows],
                    shared[rows],
                )

        run_tiled(run, h, w, threads)
        d32 = d.astype(np.float32)
        if not with_slopes:
            return _camera_pair(d32, None)
        sigma_d[~np.isfinite(d32)] = np.nan
        if self.fusion is None:
            return _camera_pair(d32, sigma_d)
        return self._fuse(u0 if self.axis == "u" else v0, d32, sigma_d, shared, noise, threads)

    @functools.cached_property
    def _midpoint_geometry(self) -> np.ndarray:
        """:func:`~metrology.core.geometry.match_2d_kernels.midpoint_tile`'s ``geometry`` (15 float64):
        ``R`` row-major, camera 1's centre ``C = -R^T T`` in camera 0's frame, camera 1's ``fx, s, fy``."""
        R = np.asarray(self.rig.R, np.float64)
        T = np.asarray(self.rig.T, np.float64)
        K = np.asarray(self.rig.camera1.K, np.float64)
        return np.concatenate([R.ravel(), -R.T @ T, [K[0, 0], K[0, 1], K[1, 1]]])

    def _undistort_camera1(self, x1: np.ndarray, y1: np.ndarray) -> np.ndarray:
        """Camera 1's matched pixels ``(x1, y1)`` ((n, m) float32) to undistorted normalized
        coordinates and the lens's Jacobian there, ``(n, m, 6)`` float64 as
        :func:`~metrology.core.geometry.match_2d_kernels.undistort_tile` gives them (compiled for an
        untilted lens; a tilted one, and a point that compiled Newton leaves unconverged, through
        :func:`~metrology.core.distortion.undistort_pixels`)."""
        cam1 = self.rig.camera1
        dist = cam1.distortion
        K = np.asarray(cam1.K, np.float64)
        out = np.empty((*x1.shape, 6))
        tilted = bool(dist.coeffs[12] != 0.0 or dist.coeffs[13] != 0.0)
        if not tilted:
            camera = np.array([K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]])
            if not undistort_tile(x1, y1, camera, dist.coeffs, UNDISTORT_TOL_PX, out):
                return out
            redo = np.isinf(out[..., 0])
        else:
            redo = np.ones(x1.shape, bool)
        und = undistort_pixels(K, dist, x1[redo].astype(np.float64), y1[redo].astype(np.float64))
        _, _, jac = dist.distort_with_jacobian(und.x, und.y)
        out[redo] = np.stack([und.x, und.y, *jac], axis=-1)
        return out


def _noise_maps(sigma: Sequence[np.ndarray | None] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Both cameras' coordinate sigma maps as float32, or None unless both were given."""
    if sigma is None or sigma[0] is None or sigma[1] is None:
        return None
    return np.asarray(sigma[0], np.float32), np.asarray(sigma[1], np.float32)


def _camera_pair(d: np.ndarray, sigma: np.ndarray | None) -> CombinedMaps:
    """The camera pair's disparity (and its sigma) alone, its pairs map bit 0 where it matched."""
    finite = np.isfinite(d)
    # a bool is stored as the byte 1: the camera pair's bit as it is, without another pass
    pairs = finite.view(np.uint8) if PAIR_CAMERAS == 1 else np.where(finite, np.uint8(PAIR_CAMERAS), np.uint8(0))
    return CombinedMaps(u=d, v=None, sigma=sigma, pairs=pairs)


def _decreasing(u1r: np.ndarray) -> bool:
    """True when the coordinate mostly falls along the rows (every 8th row's steps)."""
    falling, finite = row_steps(u1r, 8)
    return bool(finite) and falling > finite // 2


def _projector_geometry(rig: StereoRig) -> PinholeRig | None:
    """The calibrated projector with camera 0 as a pinhole rig, or None."""
    proj = rig.projector
    if not proj.calibrated:
        return None

    assert proj.K is not None and proj.R is not None and proj.T is not None
    projector = PinholeProjector(width=proj.width, height=proj.height, K=proj.K, dist=proj.dist)
    return PinholeRig(camera=rig.camera0, projector=projector, R=proj.R, T=proj.T)


_lock = threading.Lock()


@functools.lru_cache(maxsize=2)
def _prepare_cached(rig: StereoRig, axis: str, match: str = "epipolar") -> PreparedStereo:
    return PreparedStereo2D(rig, axis) if match == "2d" else PreparedStereo(rig, axis)


def prepare_stereo(rig: StereoRig, axis: str, match: str = "epipolar") -> PreparedStereo:
    """The rig prepared for matching ``axis`` along epipolar lines, or both axes in 2-D (``match``
    ``"2d"``; cached per rig, axis and match: tables built once)."""
    with _lock:
        return _prepare_cached(rig, axis, match)
