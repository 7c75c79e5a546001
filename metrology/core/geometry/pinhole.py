"""The pinhole model: a calibrated OpenCV pinhole camera and pinhole projector with lens distortion.

Rig file (``"model": "pinhole"``; see docs/pinhole.md)::

    {"model": "pinhole",
     "camera":    {"width_px": 2048, "height_px": 1536, "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                   "dist": [k1, k2, p1, p2, k3]},
     "projector": {"width": 1280, "height": 800, "K": [[...]], "dist": [...],
                   "gamma": 2.2, "response": [256 numbers]},
     "R": [[...], [...], [...]], "T": [tx, ty, tz]}

The camera frame is the model frame (mm); a point ``X_c`` of it is ``X_p = R X_c + T`` in the
projector's frame, so ``T`` is the camera centre in the projector frame and the projector
centre is ``C_p = -R^T T`` in the camera frame. ``K`` maps distorted normalized coordinates to
pixels (camera) or projector units (projector), pixel centres at integers; ``dist`` holds 4, 5,
8, 12 or 14 OpenCV coefficients (:mod:`metrology.core.distortion`), absent or empty for none.
The projector's optional ``gamma`` (a number in 0.2..5: pattern value ``s`` in 0..1 comes out
as ``s**gamma``) and ``response`` (256 non-decreasing numbers in 0..1: the emitted intensity of
each 8-bit level, relative to white) describe its measured response; geometry ignores them.

Triangulation
-------------
Camera pixel ``(k, j)`` sees the ray ``X = t d``, ``d = (x_n, y_n, 1)`` with ``(x_n, y_n)`` its
undistorted normalized coordinates (computed once per rig and frame size, Newton to 1e-6 px).

- **plane** (default), axis ``u``: the projector column of undistorted normalized abscissa
  ``x_p`` is the plane ``n . X_p = 0`` with ``n = (1, 0, -x_p)``; in the camera frame the ray
  meets it at ``t = -(T_x - x_p T_z) / ((R d)_x - x_p (R d)_z)``. Without projector distortion
  ``x_p`` is affine in ``u`` and ``t = -(a + b u) / (A + B u)`` with per-pixel tables ``A, B``
  (a Mobius map of ``u``, no iteration). With distortion the decoded ``u`` is a distorted
  coordinate: with ``v`` decoded too, ``(u, v)`` is undistorted jointly (a bicubic grid, built
  only for codecs that code both axes); with ``u`` alone the uncoded coordinate follows the
  pixel's epipolar line ``y_p = c0 + c1 x_p`` (exact in undistorted projector coordinates) and
  ``x_p`` solves ``fx D_x(x_p, c0 + c1 x_p) + s D_y + cx = u``: every epipolar line passes
  through the epipole, so ``x_p = Q(u, c0)`` is tabulated once per rig
  (:mod:`metrology.core.geometry.epipolar_table`: exact at the nodes, cubic in ``u``, linear in
  ``c0``, within 2e-5 projector units) and read per pixel with one gather (Newton on the line
  where the table cannot be built). Axis ``v`` is the same with rows (``n = (0, 1, -y_p)``).
- **midpoint**: the midpoint of the shortest segment between the camera ray and the projector
  ray of ``(x_p, y_p)`` (both axes decoded, or one axis and its epipolar line).

Which axis (``axis="auto"``): ``u`` when ``|T_x| >= |T_y|``, else ``v``: the axis whose planes
the baseline crosses most steeply.

Uncertainty: ``sigma_X = |dt/du| |d| sigma_u`` (mm), ``dt/du = dt/dx_p dx_p/du`` the analytic
derivative of the ray-plane intersection (``dx_p/du`` the inverse of the distortion's
derivative along the epipolar line, or ``1 / fx`` without distortion).
"""

from __future__ import annotations

import functools
import json
import math
import threading
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from metrology.core import local_cache
from metrology.core.distortion import Distortion, check_dist, project_normalized, undistort_pixels
from metrology.core.geometry.base import (
    AXES,
    CameraRays,
    GeometryError,
    GeometryModel,
    GeometryOptions,
    PlaneCoordinates,
    PreparedGeometry,
    ReferenceSurface,
    check_axes,
    check_frame,
    short_number,
    subpixel_grid,
)
from metrology.core.geometry.epipolar_table import EpipolarTable
from metrology.core.geometry.pinhole_numpy import flat, tile_kernels
from metrology.core.geometry.projector_grid import UndistortionGrid
from metrology.core.geometry.rig_file import (
    Matrix3,
    RigFileError,
    check_coded_axis,
    check_projector_size,
    check_rotation,
    checked_keys,
    distortion_coefficients,
    image_side,
    intrinsics,
    matrix3,
    number,
    positive,
    translation,
)
from metrology.core.kernel_choice import use_compiled
from metrology.core.tiling import nested_threads, run_tiled

MODEL_NAME = "pinhole"
TOP_KEYS: tuple[str, ...] = ("model", "camera", "projector", "R", "T")
CAMERA_KEYS: tuple[str, ...] = ("width_px", "height_px", "K", "dist")
PROJECTOR_KEYS: tuple[str, ...] = ("width", "height", "K", "dist", "gamma", "response")
PROJECTOR_GAMMA_RANGE: tuple[float, float] = (0.2, 5.0)
"""Accepted ``projector.gamma`` values (inclusive)."""
RESPONSE_LEVELS = 256
"""Entries of ``projector.response``: one per 8-bit pattern level."""
PROJECTOR_TOL = 1e-6
"""Convergence tolerance of the projector coordinate's undistortion, projector units."""
PROJECTOR_MAX_ITER = 30

TABLES_FORMAT = 4
"""Version of the prepared tables' layout in the local cache (:mod:`metrology.core.local_cache`)."""
CACHE_KIND = "pinhole"
"""The local cache's folder for prepared pinhole tables."""
GRID_CACHE_KIND = "projector-grid"
"""The local cache's folder for projector undistortion grids."""
LINE_SOLVE_TOL = 1e-9
"""Tolerance of the exact solves at the epipolar table's nodes, projector units."""


# --------------------------------------------------------------------------- projector response
def _gamma(value: Any, name: str) -> float | None:
    if value is None:
        return None
    g = number(value, name)
    lo, hi = PROJECTOR_GAMMA_RANGE
    if not lo <= g <= hi:
        raise RigFileError(f"{name} must be in {lo:g}..{hi:g}, got {value!r}")
    return g


def _response(value: Any, name: str) -> tuple[float, ...] | None:
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != RESPONSE_LEVELS:
        got = f"{len(value)} entries" if isinstance(value, (list, tuple)) else repr(value)
        raise RigFileError(f"{name} must be a list of {RESPONSE_LEVELS} numbers in 0..1, got {got}")
    table = tuple(number(x, f"{name}[{i}]") for i, x in enumerate(value))
    for i, x in enumerate(table):
        if not 0.0 <= x <= 1.0:
            raise RigFileError(f"{name}[{i}] must be in 0..1, got {x!r}")
        if i and x < table[i - 1]:
            raise RigFileError(
                f"{name} must be non-decreasing: {name}[{i}] = {x!r} < {name}[{i - 1}] = {table[i - 1]!r}"
            )
    return table


# --------------------------------------------------------------------------- the rig
@dataclass(frozen=True)
class PinholeCamera:
    """The camera: image size (pixels), intrinsics ``K`` and distortion (0/4/5/8/12/14 coefficients)."""

    width_px: int
    height_px: int
    K: Matrix3
    dist: tuple[float, ...] = ()

    @property
    def distortion(self) -> Distortion:
        return Distortion(check_dist(self.dist, "camera dist"))


@dataclass(frozen=True)
class PinholeProjector:
    """The projector: size in projector units (the codec's), intrinsics ``K``, distortion, and its
    optional measured response: ``gamma`` (emitted ``s**gamma``) or ``response`` (256 levels, 0..1)."""

    width: float
    height: float
    K: Matrix3
    dist: tuple[float, ...] = ()
    gamma: float | None = None
    response: tuple[float, ...] | None = None

    @property
    def distortion(self) -> Distortion:
        return Distortion(check_dist(self.dist, "projector dist"))


@dataclass(frozen=True)
class PinholeRig(GeometryModel):
    """A calibrated pinhole projector-camera rig (see the module docstring).

    Build it with :meth:`from_dict` (validates every key) or directly; immutable and hashable.
    """

    camera: PinholeCamera
    projector: PinholeProjector
    R: Matrix3
    T: tuple[float, float, float]

    model: ClassVar[str] = MODEL_NAME
    label: ClassVar[str] = "Calibrated pinhole camera and projector"
    short_label: ClassVar[str] = "pinhole"
    requires_reference: ClassVar[bool] = False
    unreferenced_result: ClassVar[str] = "depth"
    frame: ClassVar[str] = "camera"
    sigma_direction: ClassVar[str] = "camera ray"

    def __post_init__(self) -> None:
        check_rotation(self.R)

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PinholeRig:
        """Parse and validate a rig file's JSON object; :class:`RigFileError` names the bad key."""
        data = checked_keys(data, TOP_KEYS, TOP_KEYS, "pinhole rig")
        if data["model"] != MODEL_NAME:
            raise RigFileError(f"rig model must be {MODEL_NAME!r} here, got {data['model']!r}")
        cam = checked_keys(data["camera"], CAMERA_KEYS, CAMERA_KEYS[:3], "camera")
        proj = checked_keys(data["projector"], PROJECTOR_KEYS, PROJECTOR_KEYS[:3], "projector")
        camera = PinholeCamera(
            width_px=image_side(cam["width_px"], "camera width_px"),
            height_px=image_side(cam["height_px"], "camera height_px"),
            K=intrinsics(cam["K"], "camera K"),
            dist=distortion_coefficients(cam.get("dist"), "camera dist"),
        )
        projector = PinholeProjector(
            width=positive(proj["width"], "projector width"),
            height=positive(proj["height"], "projector height"),
            K=intrinsics(proj["K"], "projector K"),
            dist=distortion_coefficients(proj.get("dist"), "projector dist"),
            gamma=_gamma(proj.get("gamma"), "projector gamma"),
            response=_response(proj.get("response"), "projector response"),
        )
        return cls(camera=camera, projector=projector, R=matrix3(data["R"], "R"), T=translation(data["T"], "T"))

    @classmethod
    def from_json(cls, text: str) -> PinholeRig:
        """Parse a rig file's text."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RigFileError(f"rig file is not valid JSON: {exc.msg} at line {exc.lineno}") from exc
        except RecursionError:
            raise RigFileError("rig file is nested too deeply to be a rig file") from None
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object (keys in the contract's order; ``dist`` omitted when empty)."""

        def size(x: float) -> float | int:
            return int(x) if float(x).is_integer() else float(x)

        camera: dict[str, Any] = {
            "width_px": self.camera.width_px,
            "height_px": self.camera.height_px,
            "K": [list(row) for row in self.camera.K],
        }
        if self.camera.dist:
            camera["dist"] = list(self.camera.dist)
        projector: dict[str, Any] = {
            "width": size(self.projector.width),
            "height": size(self.projector.height),
            "K": [list(row) for row in self.projector.K],
        }
        if self.projector.dist:
            projector["dist"] = list(self.projector.dist)
        if self.projector.gamma is not None:
            projector["gamma"] = float(self.projector.gamma)
        if self.projector.response is not None:
            projector["response"] = list(self.projector.response)
        return {
            "model": MODEL_NAME,
            "camera": camera,
            "projector": projector,
            "R": [list(row) for row in self.R],
            "T": list(self.T),
        }

    def scene_distance_mm(self, field_width_mm: float) -> float:
        """``fx FW / W``: the distance at which ``field_width_mm`` spans the image's width (pinhole
        approximation, the lens's distortion left out)."""
        return self.camera.K[0][0] * field_width_mm / self.camera.width_px

    @property
    def camera_centre_mm(self) -> np.ndarray:
        """The origin: the camera frame is the model frame."""
        return np.zeros(3)

    def _check_projector(self, projector_size: tuple[float, float]) -> None:
        check_projector_size(projector_size, self.projector.width, self.projector.height)

    def check_codec(
        self, projector_size: tuple[float, float], coded_axes: Collection[str], options: GeometryOptions | None = None
    ) -> None:
        """The codec's projector must be the rig's, and it must code the axis the rig triangulates."""
        self._check_projector(projector_size)
        options = options or GeometryOptions()
        if options.match != "epipolar":
            raise GeometryError(f"a pinhole rig has one camera; match {options.match!r} is for stereo rigs")
        axis = self.auto_axis() if options.triangulate == "auto" else options.triangulate
        check_coded_axis(axis, options.triangulate, coded_axes, "rig triangulates")

    def value_rows(self) -> list[tuple[str, str]]:
        """Camera (size, K, distortion), projector (size, K, distortion), R, T and the baseline |T|."""
        cam, proj = self.camera, self.projector
        rows = [
            (
                "camera",
                f"{cam.width_px} x {cam.height_px} px, K {short_number(cam.K)}"
                + (f", dist {short_number(cam.dist, 4)}" if cam.dist else ""),
            ),
            (
                "projector",
                f"{short_number(proj.width)} x {short_number(proj.height)}, K {short_number(proj.K)}"
                + (f", dist {short_number(proj.dist, 4)}" if proj.dist else ""),
            ),
            ("R", short_number(self.R)),
            ("T", f"{short_number(self.T)} mm"),
        ]
        return rows

    def summary(self) -> str:
        """Camera and projector focal lengths and the baseline, in one line."""
        baseline = math.sqrt(sum(t * t for t in self.T))
        return (
            f"pinhole: camera fx {self.camera.K[0][0]:.2f} px, projector fx {self.projector.K[0][0]:.2f}, "
            f"baseline {baseline:.2f} mm"
        )

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        return (self.camera.height_px, self.camera.width_px)

    @property
    def projector_size(self) -> tuple[float, float]:
        """The projector's ``(width, height)`` in pixels: the codec's projector must have this size."""
        return (self.projector.width, self.projector.height)

    @property
    def projector_center_mm(self) -> np.ndarray:
        """``C_p = -R^T T``: the projector's centre in the camera frame, ``(3,)`` float64, mm."""
        return np.asarray(-np.asarray(self.R).T @ np.asarray(self.T))

    def auto_axis(self) -> str:
        """``"u"`` when ``|T_x| >= |T_y|``, else ``"v"``."""
        return "u" if abs(self.T[0]) >= abs(self.T[1]) else "v"

    def prepare(
        self,
        shape: tuple[int, int] | None = None,
        projector_size: tuple[float, float] | None = None,
        options: GeometryOptions | None = None,
    ) -> PreparedPinhole:
        """The model prepared for ``shape`` (must be the camera size) and the codec's projector size
        (must equal the rig's), triangulating on ``options.triangulate`` (auto|u|v) by
        ``options.method`` (plane|midpoint).

        Cached per (rig, axis, method); the camera rays are cached per rig.
        """
        options = options or GeometryOptions()
        if shape is not None and tuple(shape) != self.shape:
            raise GeometryError(
                f"frames are {shape[1]}x{shape[0]} px but the rig's camera is "
                f"{self.camera.width_px}x{self.camera.height_px} px"
            )
        if projector_size is not None:
            self._check_projector(projector_size)
        resolved = self.auto_axis() if options.triangulate == "auto" else options.triangulate
        return _prepare_cached(self, resolved, options.method)


def _table_threads() -> int | None:
    """Threads for building tables: one inside a tile worker, the default elsewhere (:func:`nested_threads`)."""
    return nested_threads()


@functools.lru_cache(maxsize=2)  # tables of a 2048x1536 rig with distortion: ~285 MB
def _prepare_cached(rig: PinholeRig, axis: str, method: str) -> PreparedPinhole:
    return PreparedPinhole(rig, axis, method)


def _projector_grid(projector: PinholeProjector, axis: str) -> UndistortionGrid | None:
    """The projector's :class:`UndistortionGrid` of the coded ``axis`` from the local cache, else
    built (and stored)."""
    parts = {
        "axis": axis,
        "projector": {"width": projector.width, "height": projector.height, "K": projector.K, "dist": projector.dist},
    }
    key = local_cache.entry_key(GRID_CACHE_KIND, {**parts, "format": TABLES_FORMAT})
    stored = local_cache.load(GRID_CACHE_KIND, key)
    if stored is not None:
        return UndistortionGrid.from_arrays(stored) if stored else None
    K = np.asarray(projector.K, dtype=np.float64)
    grid = UndistortionGrid.build(K, projector.distortion, projector.width, projector.height, axis)
    local_cache.store(GRID_CACHE_KIND, key, grid.to_arrays() if grid is not None else {})
    return grid


CAMERA_START_STEP = 4
"""Pixels between the nodes of the coarse grid of camera undistortions whose cubic interpolation
starts every pixel's Newton iteration (:func:`_camera_tables`)."""


def _cubic_weights(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The weights of four nodes at ``-1, 0, 1, 2`` for a point at ``t`` (float64, any shape) in the
    cubic through them (Lagrange): the interpolation of :func:`_camera_tables`' grid of solutions."""
    return (
        -t * (t - 1.0) * (t - 2.0) / 6.0,
        (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0,
        -(t + 1.0) * t * (t - 2.0) / 2.0,
        (t + 1.0) * t * (t - 1.0) / 6.0,
    )


def _cubic_nodes(at: np.ndarray, n_nodes: int) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """For pixel coordinates ``at`` (float64 ``(n,)``) on a grid of ``n_nodes`` nodes every
    :data:`CAMERA_START_STEP` pixels whose first lies one step before pixel 0: the index of each
    point's first of four nodes and their weights (:func:`_cubic_weights`)."""
    position = at / CAMERA_START_STEP + 1.0
    first = np.clip(np.floor(position), 1, n_nodes - 3).astype(np.intp)
    return first - 1, _cubic_weights(position - first)


@functools.lru_cache(maxsize=4)
def _camera_tables(rig_camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates ``(x_n, y_n)`` of every camera pixel, ``(H, W)`` float64
    each, to 1e-6 px (:func:`~metrology.core.distortion.undistort_pixels`). Each pixel's Newton
    iteration starts from the cubic interpolation (four nodes along each axis, separable) of a grid
    of solutions every :data:`CAMERA_START_STEP` pixels, one node beyond the frame on each side
    (1/16 of the pixels, solved first). On issue 22's strongly distorted camera that start is
    within 8e-8 px of the solution everywhere, so the iteration only checks it (no Newton step),
    where the bilinear start of a grid every 8 pixels was within 5.5e-3 px (one step and a second
    check). Wherever the start is not close enough, the iteration steps from it as before."""
    h, w = rig_camera.height_px, rig_camera.width_px
    xn, yn = np.empty((h, w)), np.empty((h, w))
    K, dist = np.asarray(rig_camera.K), rig_camera.distortion
    cols = np.arange(w, dtype=np.float64)
    failed_rows: list[int] = []
    start = None
    n_rows = 0
    if not dist.is_identity:
        step = CAMERA_START_STEP  # nodes at -step, 0, step, ... up to the second beyond the last pixel
        node_c = step * np.arange(-1, -(-(w - 1) // step) + 3, dtype=np.float64)
        node_r = step * np.arange(-1, -(-(h - 1) // step) + 3, dtype=np.float64)
        coarse = undistort_pixels(K, dist, *np.meshgrid(node_c, node_r))
        if coarse.converged.all():
            first, weights = _cubic_nodes(cols, node_c.size)
            # the coarse grid interpolated along the rows to every column: (rows of nodes, W)
            start = tuple(sum(g[:, first + k] * weights[k] for k in range(4)) for g in (coarse.x, coarse.y))
            n_rows = node_r.size

    def run(rows: slice) -> None:  # row blocks of ~32k pixels: temporaries stay in cache
        r = np.arange(rows.start, rows.stop, dtype=np.float64)
        jj, kk = np.meshgrid(cols, r)
        guess = None
        if start is not None:
            first, weights = _cubic_nodes(r, n_rows)
            guess = tuple(sum(g[first + k] * weights[k][:, None] for k in range(4)) for g in start)
        res = undistort_pixels(K, dist, jj, kk, start=guess)
        xn[rows], yn[rows] = res.x, res.y
        failed_rows.append(res.n_failed)

    run_tiled(run, h, w, threads=_table_threads(), tile_px=1 << 15)
    failed = sum(failed_rows)
    if failed:
        raise GeometryError(
            f"camera dist: {failed} pixel(s) of the {w}x{h} frame cannot be undistorted "
            "(the distortion folds over inside the image)"
        )
    return xn, yn


@dataclass(frozen=True)
class PinholeReference(ReferenceSurface):
    """The total-least-squares plane through a reference capture's points, normal towards the camera.

    Height of a point ``p``: ``normal . (p - centroid)`` (mm, positive towards the camera).
    """

    frame_shape: tuple[int, int]
    centroid: np.ndarray
    normal: np.ndarray
    n_points: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.frame_shape

    @property
    def per_pixel(self) -> bool:
        return False

    def describe(self) -> dict[str, Any]:
        """``{"centroid_mm", "normal", "points"}``: the fitted plane."""
        return {"centroid_mm": self.centroid.tolist(), "normal": self.normal.tolist(), "points": self.n_points}


class PreparedPinhole(PreparedGeometry):
    """A :class:`PinholeRig` prepared for its camera frame (tables computed once, kept).

    Per pixel: ``x_n, y_n`` (ray ``d = (x_n, y_n, 1)``, float64 and float32), ``|d|``; without
    projector distortion the Mobius tables ``A, B`` of the closed form; with it ``(Rd)_i, (Rd)_z``
    (float32), the epipolar table and each pixel's row of it (one axis) and, built on first use
    by a codec that codes both axes, the undistortion grid. ``R d`` and the epipolar lines
    ``c0, c1`` of the Newton paths are recomputed per tile from ``x_n, y_n`` (:meth:`_rows_terms`).
    """

    def __init__(self, rig: PinholeRig, axis: str, method: str) -> None:
        self.model = rig
        self.rig = rig
        self.shape = rig.shape
        self._frame_px = rig.shape[0] * rig.shape[1]  # chooses the tiles' kernels (pinhole_numpy.tile_kernels)
        self.projector_size = (rig.projector.width, rig.projector.height)
        self.axis = axis
        self.method = method
        self._lock = threading.Lock()
        self._tables: dict[str, np.ndarray] | None = None
        R = np.asarray(rig.R, dtype=np.float64)
        T = np.asarray(rig.T, dtype=np.float64)
        self._R, self._T = R, T
        Kp = np.asarray(rig.projector.K, dtype=np.float64)
        self._Kp = Kp
        self._pdist = rig.projector.distortion
        self._p_distorted = not self._pdist.is_identity
        self._C_p = -R.T @ T
        self._grid: UndistortionGrid | None = None
        self._grid_built = False
        self._grid_lock = threading.Lock()
        self._line: EpipolarTable | None = None
        self.tables()  # now, on the caller's thread: never lazily inside a tile worker

    # ------------------------------------------------------------------ interface
    @property
    def required_axes(self) -> tuple[str, ...]:
        return (self.axis,)

    @property
    def has_model_plane(self) -> bool:
        return False

    def used_axes(self, decoded: Collection[str]) -> tuple[str, ...]:
        """The triangulated axis, and the other one where it is decoded and read: by the midpoint
        method, and by the plane method through a distorted projector (both undistorted jointly)."""
        other = "v" if self.axis == "u" else "u"
        reads_other = other in decoded and (self.method == "midpoint" or self._p_distorted)
        if reads_other and self.method == "plane":
            self.undistortion_grid()  # built now, on the caller's thread, for codecs that need it
        return tuple(a for a in AXES if a == self.axis or (a == other and reads_other))

    @property
    def points_on_rays(self) -> bool:
        return self.method == "plane"

    def plane_coordinates(self, reference: ReferenceSurface | None = None) -> PlaneCoordinates:
        """Camera-frame ``(X, Y)`` (mm) of the point of the reference plane each pixel's ray meets
        (:func:`plane_coordinates_of`)."""
        tab = self.tables()
        return plane_coordinates_of(tab["xn"], tab["yn"], reference, "a pinhole rig")

    def tables(self) -> dict[str, np.ndarray]:
        """The per-pixel tables (computed on first use, then kept)."""
        with self._lock:
            if self._tables is None:
                self._tables = self._build_tables()
            return self._tables

    def _ray_terms(self, xn: np.ndarray, yn: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """``R d`` (three arrays) for the rays ``d = (x_n, y_n, 1)`` and their epipolar lines
        ``(c0, c1)`` in undistorted normalized projector coordinates; float64, shape of ``xn``.

        The points ``t Rd + T`` of a ray project onto ``l . (x_p, y_p, 1) = 0`` with
        ``l = (Rd) x T``: ``y_p = c0 + c1 x_p`` for axis u (``x_p = c0 + c1 y_p`` for axis v)."""
        R, T = self._R, self._T
        rd = [R[i, 0] * xn + R[i, 1] * yn + R[i, 2] for i in range(3)]
        lx = rd[1] * T[2] - rd[2] * T[1]
        ly = rd[2] * T[0] - rd[0] * T[2]
        lz = rd[0] * T[1] - rd[1] * T[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.axis == "u":  # y = -(lx x + lz) / ly
                c0, c1 = -lz / ly, -lx / ly
            else:  # x = -(ly y + lz) / lx
                c0, c1 = -lz / lx, -ly / lx
        return rd, c0, c1

    def _rows_terms(self, rows: slice) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """:meth:`_ray_terms` of the camera pixels of ``rows`` (computed per call, not kept)."""
        tab = self.tables()
        return self._ray_terms(tab["xn"][rows], tab["yn"][rows])

    def _cache_key(self) -> str | None:
        """The local-cache key of this preparation (rig, frame size, axis, method, table layout),
        or None when nothing here is worth caching (no distortion: the tables are a few passes)."""
        if self.rig.camera.distortion.is_identity and not self._p_distorted:
            return None
        parts = {
            "rig": self.rig.to_dict(),
            "shape": list(self.shape),
            "axis": self.axis,
            "method": self.method,
            "format": TABLES_FORMAT,
        }
        return local_cache.entry_key(CACHE_KIND, parts)

    def _build_tables(self) -> dict[str, np.ndarray]:
        key = self._cache_key()
        stored = local_cache.load(CACHE_KIND, key) if key is not None else None
        if stored is not None and stored["xn"].shape == self.shape:
            xn, yn = stored["xn"], stored["yn"]
            kept: dict[str, np.ndarray] = {k: stored[k] for k in ("line_base", "line_frac") if k in stored}
            if "line_planes" in stored:
                self._line = EpipolarTable.from_arrays(stored)
        else:
            stored = None
            xn, yn = _camera_tables(self.rig.camera)
            kept = {}
            if self._p_distorted:
                self._line = self._build_line_table(xn, yn)
        if self._p_distorted and use_compiled(self._frame_px):  # its frames' compiled kernels, loaded now
            from metrology.core.geometry import pinhole_kernels

            pinhole_kernels.warm()
        T, Kp = self._T, self._Kp
        fx, s, cx, fy, cy = Kp[0, 0], Kp[0, 1], Kp[0, 2], Kp[1, 1], Kp[1, 2]
        if self.axis == "u":
            # Column u (no distortion): fx X + s Y - (u - cx) Z = 0 in the projector frame, i.e.
            # n = (fx, s, 0) - w e_z with the centred coordinate w = u - cx (smaller float32 terms).
            a, b, centre = fx * T[0] + s * T[1], -T[2], cx
        else:
            a, b, centre = fy * T[1], -T[2], cy
        # without projector distortion the Mobius tables A, B of the closed form; with it the
        # plane of the coded axis' undistorted coordinate, (Rd)_i and (Rd)_z
        names = (
            ("xn32", "yn32", "norm_d", "A", "B")
            if not self._p_distorted
            else ("xn32", "yn32", "norm_d", "rdi32", "rdz32")
        )
        tables: dict[str, np.ndarray] = {"xn": xn, "yn": yn, "ab": np.array([a, b, centre]), **kept}
        tables.update({name: np.empty(self.shape, np.float32) for name in names})
        line = self._line
        # each pixel's row of the epipolar table, from its line's intercept c0
        need_rows = line is not None and "line_base" not in kept
        if need_rows:
            tables["line_base"] = np.empty(self.shape, np.int32)
            tables["line_frac"] = np.empty(self.shape, np.float32)
        R = self._R
        i = 0 if self.axis == "u" else 1

        def run(rows: slice) -> None:
            x, y = xn[rows], yn[rows]
            tables["xn32"][rows], tables["yn32"][rows] = x, y
            tables["norm_d"][rows] = np.sqrt(x * x + y * y + 1.0)
            if self._p_distorted:
                rd, c0, _ = self._ray_terms(x, y)
                tables["rdi32"][rows], tables["rdz32"][rows] = rd[i], rd[2]
                if need_rows and line is not None:
                    tables["line_base"][rows], tables["line_frac"][rows] = line.pixel_rows(c0)
                return
            rdz = R[2, 0] * x + R[2, 1] * y + R[2, 2]
            rdi = R[i, 0] * x + R[i, 1] * y + R[i, 2]
            rdi = fx * rdi + s * (R[1, 0] * x + R[1, 1] * y + R[1, 2]) if self.axis == "u" else fy * rdi
            tables["A"][rows], tables["B"][rows] = rdi, -rdz

        run_tiled(run, self.shape[0], self.shape[1], threads=_table_threads(), tile_px=1 << 15)
        if key is not None and stored is None:  # written while the caller goes on measuring
            rows_of_line: dict[str, np.ndarray] = {k: tables[k] for k in ("line_base", "line_frac") if k in tables}
            arrays: dict[str, np.ndarray] = {"xn": xn, "yn": yn, **rows_of_line}
            if line is not None:
                arrays.update(line.to_arrays())
            local_cache.store_later(CACHE_KIND, key, arrays)
        return tables

    def _coded_domain(self) -> tuple[float, float]:
        """``(lo, hi)``: the coded coordinates triangulated (projector units), half a unit beyond
        the projector's first and last pixel centres and one more on the far side (as before)."""
        size = self.rig.projector.width if self.axis == "u" else self.rig.projector.height
        mid, half = (size - 1) / 2, size / 2 + 1.0
        return mid - half, mid + half

    def _line_slope(self, c0: np.ndarray) -> np.ndarray:
        """``c1`` of the epipolar line of intercept ``c0`` (it passes through the epipole):
        ``c1 = (T_o - c0 T_z) / T_a``."""
        T = self._T
        ta, to = (T[0], T[1]) if self.axis == "u" else (T[1], T[0])
        return np.asarray((to - c0 * T[2]) / ta)

    def _line_range(self) -> tuple[float, float] | None:
        """The intercepts of the lines that cross the projector's image grown by
        :data:`~metrology.core.geometry.epipolar_table.LINE_MARGIN` (from its undistorted border),
        or None when the epipole lies inside it (or the coded axis' baseline is zero)."""
        from metrology.core.geometry.epipolar_table import LINE_MARGIN

        T = self._T
        ta, to = (T[0], T[1]) if self.axis == "u" else (T[1], T[0])
        if ta == 0.0:
            return None
        w, h = self.rig.projector.width, self.rig.projector.height
        m = LINE_MARGIN
        side = np.linspace(0.0, 1.0, 512)
        lo_u, hi_u, lo_v, hi_v = -0.5 - m, w - 0.5 + m, -0.5 - m, h - 0.5 + m
        bu = np.concatenate(
            [lo_u + (hi_u - lo_u) * side, np.full(512, hi_u), hi_u - (hi_u - lo_u) * side, np.full(512, lo_u)]
        )
        bv = np.concatenate(
            [np.full(512, lo_v), lo_v + (hi_v - lo_v) * side, np.full(512, hi_v), hi_v - (hi_v - lo_v) * side]
        )
        und = undistort_pixels(self._Kp, self._pdist, bu, bv)
        if und.n_failed:
            return None
        a, o = (und.x, und.y) if self.axis == "u" else (und.y, und.x)
        den = 1.0 - a * T[2] / ta
        if not (np.all(den > 0) or np.all(den < 0)):
            return None
        c0 = (o - a * to / ta) / den
        return float(c0.min()), float(c0.max())

    def _build_line_table(self, xn: np.ndarray, yn: np.ndarray) -> EpipolarTable | None:
        """The epipolar table of this rig's coded axis (None: Newton per frame)."""
        c_range = self._line_range()
        if c_range is None:
            return None
        Kp = self._Kp
        fx, s, cx, fy, cy = Kp[0, 0], Kp[0, 1], Kp[0, 2], Kp[1, 1], Kp[1, 2]

        def solve(w: np.ndarray, c0: np.ndarray, c1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            q = np.empty_like(w)
            dq = np.empty_like(w)

            def run(rows: slice) -> None:
                with np.errstate(all="ignore"):
                    xp, yp, d = self._solve_on_line(w[rows], c0[rows], c1[rows], fx, s, cx, fy, cy, tol=LINE_SOLVE_TOL)
                q[rows] = xp if self.axis == "u" else yp
                dq[rows] = d

            run_tiled(run, w.shape[0], w.shape[1], threads=_table_threads(), tile_px=1 << 14)
            return q, dq

        scale_w, scale_c = (fx, fy) if self.axis == "u" else (fy, fx)
        return EpipolarTable.build(solve, self._line_slope, self._coded_domain(), c_range, scale_w, scale_c)

    def undistortion_grid(self) -> UndistortionGrid | None:
        """The projector's undistortion grid (both axes decoded, plane method): built on first
        use, kept, and kept in the local cache; None without projector distortion or when no
        grid meets its tolerance (Newton per frame then)."""
        if not self._p_distorted:
            return None
        with self._grid_lock:
            if not self._grid_built:
                self._grid = _projector_grid(self.rig.projector, self.axis)
                self._grid_built = True
            return self._grid

    def camera_rays(self, supersample: int = 1) -> CameraRays:
        """Rays ``(x_n, y_n, 1) / |.|`` from the camera centre (the origin), undistorted (Newton to
        1e-6 px) at the pixel (or sub-pixel) centres (:func:`camera_rays_of`)."""
        if supersample != 1:
            return camera_rays_of(self.rig.camera, None, None, supersample)
        t = self.tables()
        return camera_rays_of(self.rig.camera, t["xn"], t["yn"])

    @property
    def projector_centre_mm(self) -> np.ndarray:
        return self._C_p.copy()

    def projector_coordinates(self, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X_p = R X + T`` projected through the projector's ``K`` and distortion (OpenCV's
        ``projectPoints``); NaN where ``Z_p <= 0``."""
        p = np.asarray(points_mm, dtype=np.float64)
        xp = p @ self._R.T + self._T
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = project_normalized(self._Kp, self._pdist, xp[..., 0] / xp[..., 2], xp[..., 1] / xp[..., 2])
        in_front = xp[..., 2] > 0
        return np.where(in_front, u, np.nan), np.where(in_front, v, np.nan)

    def reference(self, u: np.ndarray | None, v: np.ndarray | None, threads: int | None = None) -> PinholeReference:
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
        """See :meth:`PreparedGeometry.triangulate_rows`; in addition, with ``sigma_in`` (the
        ``(n, W)`` sigma of the triangulated axis's projector coordinate, projector units) it
        writes the points' standard uncertainty (mm) to ``sigma_out``."""
        check_axes(self, u, v)
        if height_out is not None and reference is None:
            raise GeometryError("the pinhole model has no model plane: heights need a reference capture")
        if reference is not None and not isinstance(reference, PinholeReference):
            raise GeometryError(f"reference must come from this model's reference(), got {type(reference).__name__}")
        t_rows, mid, written = self._depth_rows(rows, u, v, sigma_in, sigma_out, points_out)
        tab = self.tables()
        xn, yn = tab["xn32"][rows], tab["yn32"][rows]
        if mid is not None:  # midpoint method: points off the camera ray
            px, py, pz = mid
        if points_out is not None and not written:
            if mid is None:
                np.multiply(t_rows, xn, out=points_out[..., 0])
                np.multiply(t_rows, yn, out=points_out[..., 1])
                points_out[..., 2] = t_rows
            else:
                points_out[..., 0], points_out[..., 1], points_out[..., 2] = px, py, pz
        if height_out is not None:
            assert isinstance(reference, PinholeReference)
            n, c = reference.normal, reference.centroid
            if mid is None:  # n . (t d - c) = t (n . d) - n . c
                nd = (n[0] * xn + n[1] * yn + n[2]).astype(np.float32)
                np.multiply(t_rows, nd, out=height_out)
                height_out -= np.float32(n @ c)
            else:
                height_out[...] = n[0] * (px - c[0]) + n[1] * (py - c[1]) + n[2] * (pz - c[2])

    # ------------------------------------------------------------------ kernels
    def _depth_rows(
        self,
        rows: slice,
        u: np.ndarray | None,
        v: np.ndarray | None,
        sigma_in: np.ndarray | None,
        sigma_out: np.ndarray | None,
        points_out: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None, bool]:
        """Ray parameter ``t`` (= camera Z, mm) of each pixel of ``rows``, ``(n, W)`` float32, for
        the midpoint method the midpoints' ``(X, Y, Z)`` (float64, mm; None otherwise), and
        whether the points ``t d`` were written to ``points_out`` too (by ``plane_tile``)."""
        tab = self.tables()
        coded = u if self.axis == "u" else v
        assert coded is not None
        other = v if self.axis == "u" else u
        if not self._p_distorted and (self.method == "plane" or other is None):
            # Mobius map of the centred coded coordinate w = u - cx (or v - cy): t = -(a + b w) / (A + B w).
            a, b, centre = (np.float32(x) for x in tab["ab"])
            A, B = tab["A"][rows], tab["B"][rows]
            w = np.asarray(coded, dtype=np.float32) - centre
            den = B * w
            den += A
            num = b * w
            num += a
            with np.errstate(divide="ignore", invalid="ignore"):
                t = num / den
                np.negative(t, out=t)
                if sigma_in is not None and sigma_out is not None:
                    # dt/dw = -(b A - a B) / (A + B w)^2
                    dtdw = (b * A - a * B) / (den * den)
                    np.multiply(np.abs(dtdw), tab["norm_d"][rows], out=sigma_out)
                    sigma_out *= sigma_in
            t[~(t > 0)] = np.nan
            return t, None, False
        if other is None and self.method == "plane" and self._line is not None:
            t, written = self._plane_from_line(rows, coded, sigma_in, sigma_out, points_out)
            return t, None, written
        if other is not None and self.method == "plane" and self.undistortion_grid() is not None:
            t, written = self._plane_from_grid(rows, coded, other, sigma_in, sigma_out, points_out)
            return t, None, written
        xp, yp, dxp_dw = self._projector_normalized(rows, coded, other)
        return (*self._intersect(rows, xp, yp, dxp_dw, sigma_in, sigma_out), False)

    def _plane_from_grid(
        self,
        rows: slice,
        coded: np.ndarray,
        other: np.ndarray,
        sigma_in: np.ndarray | None,
        sigma_out: np.ndarray | None,
        points_out: np.ndarray | None,
    ) -> tuple[np.ndarray, bool]:
        """Both axes through a distorted projector: ``(u, v)`` undistorted by the grid (bicubic,
        error below :data:`GRID_TOL`), then :meth:`_plane_of`."""
        grid = self._grid
        assert grid is not None
        want_sigma = sigma_in is not None and sigma_out is not None
        u, v = (coded, other) if self.axis == "u" else (other, coded)
        q, dq = grid.normalized(u, v, want_sigma, self._frame_px)
        return self._plane_of(rows, q, dq, sigma_in, sigma_out, points_out)

    def _plane_from_line(
        self,
        rows: slice,
        coded: np.ndarray,
        sigma_in: np.ndarray | None,
        sigma_out: np.ndarray | None,
        points_out: np.ndarray | None,
    ) -> tuple[np.ndarray, bool]:
        """One coded axis through a distorted projector: ``q`` from the epipolar table (one
        gather and a cubic per pixel), then :meth:`_plane_of`; NaN for coded coordinates outside
        :meth:`_coded_domain`."""
        line = self._line
        assert line is not None
        tab = self.tables()
        want_sigma = sigma_in is not None and sigma_out is not None
        q, dq = line.evaluate(coded, tab["line_base"][rows], tab["line_frac"][rows], want_sigma, self._frame_px)
        return self._plane_of(rows, q, dq, sigma_in, sigma_out, points_out)

    def _plane_of(
        self,
        rows: slice,
        q: np.ndarray,
        dq: np.ndarray | None,
        sigma_in: np.ndarray | None,
        sigma_out: np.ndarray | None,
        points_out: np.ndarray | None,
    ) -> tuple[np.ndarray, bool]:
        """The plane of the coded axis' undistorted normalized coordinate ``q`` (float32 ``(n,
        W)``) met by each pixel's ray, in one pass of ``plane_tile``, compiled or numpy's
        (:func:`~metrology.core.geometry.pinhole_numpy.tile_kernels`): ``t = (q T_z - T_i) / (Rd_i
        - q Rd_z)``, NaN unless ``t > 0``; with ``dq = dq/dw``, ``sigma_in`` and ``sigma_out`` the
        sigma ``|dt/dq dq/dw| |d| sigma_in`` (mm) written to ``sigma_out``; the points ``t (x_n,
        y_n, 1)`` (mm) written straight to ``points_out`` when that is a contiguous float32 ``(n,
        W, 3)`` array (one pass less). Returns ``t`` (float32 ``(n, W)``) and whether the points
        were written."""
        kernels = tile_kernels(self._frame_px)
        tab = self.tables()
        T = self._T
        T_i = T[0] if self.axis == "u" else T[1]
        t = np.empty(q.shape, np.float32)
        want_sigma = sigma_in is not None and sigma_out is not None and dq is not None
        sigma = np.empty(t.shape if want_sigma else 0, np.float32)
        empty = np.empty(0, np.float32)
        write = points_out is not None and points_out.flags.c_contiguous and points_out.dtype == np.float32
        kernels.plane_tile(
            flat(q),
            flat(dq) if want_sigma and dq is not None else empty,
            flat(tab["rdi32"][rows]),
            flat(tab["rdz32"][rows]),
            float(T[2]),
            float(T_i),
            flat(tab["norm_d"][rows]),
            flat(sigma_in) if want_sigma and sigma_in is not None else empty,
            sigma.reshape(-1),
            want_sigma,
            flat(tab["xn32"][rows]),
            flat(tab["yn32"][rows]),
            points_out.reshape(-1) if write and points_out is not None else empty,
            write,
            t.reshape(-1),
        )
        if want_sigma and sigma_out is not None:
            sigma_out[...] = sigma
        return t, write

    def _projector_normalized(
        self, rows: slice, coded: np.ndarray, other: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Undistorted normalized projector coordinates of each pixel and d(coded normalized)/d(coded)."""
        Kp = self._Kp
        fx, s, cx, fy, cy = Kp[0, 0], Kp[0, 1], Kp[0, 2], Kp[1, 1], Kp[1, 2]
        w = np.asarray(coded, dtype=np.float64)
        if other is not None:
            o = np.asarray(other, dtype=np.float64)
            uu, vv = (w, o) if self.axis == "u" else (o, w)
            res = undistort_pixels(Kp, self._pdist, uu, vv, tol_px=PROJECTOR_TOL, max_iter=PROJECTOR_MAX_ITER)
            xp, yp = res.x, res.y
            _, _, (jxx, jxy, jyx, jyy) = self._pdist.distort_with_jacobian(xp, yp)
            det = jxx * jyy - jxy * jyx
            with np.errstate(divide="ignore", invalid="ignore"):
                # d(x_p)/du with v fixed, d(y_p)/dv with u fixed (zero skew part only; skew enters via u)
                dxp_dw = jyy / (det * fx) if self.axis == "u" else jxx / (det * fy)
            return xp, yp, dxp_dw
        _, c0, c1 = self._rows_terms(rows)
        with np.errstate(all="ignore"):
            return self._solve_on_line(w, c0, c1, fx, s, cx, fy, cy)

    def _solve_on_line(
        self,
        w: np.ndarray,
        c0: np.ndarray,
        c1: np.ndarray,
        fx: float,
        s: float,
        cx: float,
        fy: float,
        cy: float,
        q0: np.ndarray | None = None,
        tol: float = PROJECTOR_TOL,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Newton on the epipolar line: the coded normalized coordinate ``q`` with
        ``pixel(q, c0 + c1 q) = w`` to ``tol`` projector units, from ``q0`` (default: the
        undistorted guess); NaN where it does not converge. Returns ``x_p, y_p, dq/dw``."""
        dist = self._pdist
        axis_u = self.axis == "u"
        if q0 is not None:
            q = np.where(np.isfinite(q0), q0, (w - cx) / fx if axis_u else (w - cy) / fy)
        elif axis_u:  # pixel on the line ignoring distortion: fx q + s (c0 + c1 q) + cx
            q = (w - cx - s * c0) / (fx + s * c1)
        else:
            q = (w - cy) / fy
        dq = np.ones_like(q)
        done = ~np.isfinite(q)
        for _ in range(PROJECTOR_MAX_ITER):
            r = c0 + c1 * q
            x, y = (q, r) if axis_u else (r, q)
            xd, yd, (jxx, jxy, jyx, jyy) = dist.distort_with_jacobian(x, y)
            if axis_u:
                g = fx * xd + s * yd + cx - w
                dg = fx * (jxx + c1 * jxy) + s * (jyx + c1 * jyy)
            else:
                g = fy * yd + cy - w
                dg = fy * (jyy + c1 * jyx)
            step = g / dg
            q = np.where(done, q, q - step)
            dq = dg
            conv = np.abs(g) <= tol
            done |= conv
            if done.all():
                break
        bad = ~done | ~np.isfinite(q)
        q[bad] = np.nan
        r = c0 + c1 * q
        xp, yp = (q, r) if axis_u else (r, q)
        return xp, yp, 1.0 / dq

    def _intersect(
        self,
        rows: slice,
        xp: np.ndarray,
        yp: np.ndarray,
        dq_dw: np.ndarray,
        sigma_in: np.ndarray | None,
        sigma_out: np.ndarray | None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
        """``t`` (float32) from undistorted normalized projector coordinates, and the midpoints."""
        tab = self.tables()
        T = self._T
        (rdx, rdy, rdz), _, _ = self._rows_terms(rows)
        mid = None
        with np.errstate(all="ignore"):
            # Plane of the coded axis, n = (1, 0, -x_p) (u) or (0, 1, -y_p) (v):
            # t = -(T_i - q T_z) / (Rd_i - q Rd_z)
            q, Ti, rdi = (xp, T[0], rdx) if self.axis == "u" else (yp, T[1], rdy)
            num = q * T[2] - Ti
            den = rdi - q * rdz
            t = num / den
            if sigma_in is not None and sigma_out is not None:
                dtdq = (T[2] * den + num * rdz) / (den * den)
                sigma_out[...] = np.abs(dtdq * dq_dw) * tab["norm_d"][rows] * sigma_in
            if self.method == "midpoint":
                mid = self._midpoints(rows, xp, yp)
                t = mid[2]
            t[~(t > 0)] = np.nan
        return t.astype(np.float32), mid

    def _midpoints(self, rows: slice, xp: np.ndarray, yp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Midpoints ``(X, Y, Z)`` (float64, mm) of the shortest segments between the camera rays
        ``t d`` and the projector rays ``C_p + s e``, ``e = R^T (x_p, y_p, 1)``:
        ``t = (dc ee - de ec) / (dd ee - de^2)``, ``s = (de dc - dd ec) / (dd ee - de^2)``."""
        tab = self.tables()
        R, C = self._R, self._C_p
        d = (tab["xn"][rows], tab["yn"][rows])
        e = [R[0, i] * xp + R[1, i] * yp + R[2, i] for i in range(3)]
        dd = d[0] * d[0] + d[1] * d[1] + 1.0
        ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        de = d[0] * e[0] + d[1] * e[1] + e[2]
        dc = d[0] * C[0] + d[1] * C[1] + C[2]
        ec = e[0] * C[0] + e[1] * C[1] + e[2] * C[2]
        den = dd * ee - de * de
        t = (dc * ee - de * ec) / den
        s = (de * dc - dd * ec) / den
        return (
            0.5 * (t * d[0] + C[0] + s * e[0]),
            0.5 * (t * d[1] + C[1] + s * e[1]),
            0.5 * (t + C[2] + s * e[2]),
        )

    def points_from_heights(self, z_mm: np.ndarray, reference: ReferenceSurface | None = None) -> np.ndarray:
        """Points on the camera rays: at depth ``z`` (camera Z) without a reference, at signed
        distance ``z`` from the reference plane with one. ``(H, W, 3)`` float64, mm."""
        check_frame(self, "z_mm", z_mm)
        tab = self.tables()
        return ray_points(tab["xn"], tab["yn"], z_mm, reference)


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


# --------------------------------------------------------------------------- camera-frame helpers
def plane_coordinates_of(
    xn: np.ndarray, yn: np.ndarray, reference: ReferenceSurface | None, rig: str
) -> PlaneCoordinates:
    """Camera-frame ``(X, Y)`` (mm) of the point of the reference plane each ray ``t (x_n, y_n, 1)``
    meets: on the plane ``n . (p - c0) = 0`` at ``t = n . c0 / n . (x_n, y_n, 1)``. The field centre
    is the principal point's ray, ``t (0, 0, 1)``. ``rig`` names the rig in the error raised
    without a :class:`PinholeReference`."""
    if not isinstance(reference, PinholeReference):
        raise GeometryError(f"{rig}'s plane coordinates need its reference plane (a reference capture)")
    n, c0 = np.asarray(reference.normal, np.float64), np.asarray(reference.centroid, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(n @ c0) / (n[0] * xn + n[1] * yn + n[2])
    return PlaneCoordinates(x_mm=t * xn, y_mm=t * yn, centre_x_mm=0.0)


def camera_rays_of(
    camera: PinholeCamera, xn: np.ndarray | None, yn: np.ndarray | None, supersample: int = 1
) -> CameraRays:
    """Unit rays from the origin through ``camera``'s pixel centres (its undistorted ``xn, yn`` when
    given and ``supersample == 1``) or an ``s x s`` grid of sub-pixel centres (undistorted now)."""
    if supersample != 1 or xn is None or yn is None:
        jj, kk = np.meshgrid(subpixel_grid(camera.width_px, supersample), subpixel_grid(camera.height_px, supersample))
        und = undistort_pixels(np.asarray(camera.K), camera.distortion, jj, kk)
        xn, yn = und.x, und.y
    d = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return CameraRays(origin_mm=np.zeros(3), direction=d)


def reference_plane(
    prepared: PreparedGeometry, u: np.ndarray | None, v: np.ndarray | None, threads: int | None = None
) -> PinholeReference:
    """:func:`fit_reference_plane` of the points ``prepared`` triangulates from a reference capture's
    decoded maps (the :meth:`PreparedGeometry.reference` of models whose frame is camera 0's)."""
    from metrology.core.geometry.base import triangulate_frame

    result = triangulate_frame(prepared, u, v, points=True, heights=False, threads=threads)
    assert result.points_mm is not None
    return fit_reference_plane(result.points_mm, prepared.shape)


def fit_reference_plane(points_mm: np.ndarray, shape: tuple[int, int]) -> PinholeReference:
    """The total-least-squares plane through the finite ``(H, W, 3)`` points of a reference capture
    (camera frame, mm), its normal towards the camera (the origin)."""
    from metrology.core.acceptance import fit_plane

    pts = points_mm.reshape(-1, 3).astype(np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        raise GeometryError(f"the reference capture has {len(pts)} triangulated point(s); a plane needs 3")
    fit = fit_plane(pts)
    normal = fit.normal
    if float(normal @ fit.centroid) > 0:  # orient towards the camera (the origin)
        normal = -normal
    return PinholeReference(frame_shape=shape, centroid=fit.centroid, normal=normal, n_points=len(pts))


def ray_points(
    xn: np.ndarray, yn: np.ndarray, z_mm: np.ndarray, reference: ReferenceSurface | None = None
) -> np.ndarray:
    """Points on the rays ``t (x_n, y_n, 1)``: at depth ``z`` (camera Z) without a reference, at signed
    distance ``z`` from the reference plane with one. ``(H, W, 3)`` float64, mm."""
    z = np.asarray(z_mm, dtype=np.float64)
    if reference is None:
        t = z
    else:
        if not isinstance(reference, PinholeReference):
            raise GeometryError(f"reference must come from this model, got {type(reference).__name__}")
        n, c = reference.normal, reference.centroid
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z + n @ c) / (n[0] * xn + n[1] * yn + n[2])
    return np.stack([t * xn, t * yn, t], axis=-1)
