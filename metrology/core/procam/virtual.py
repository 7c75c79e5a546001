"""Board poses rendered through a pinhole virtual rig (development and tests of the calibration).

A board (:class:`~metrology.core.procam.board.BoardSpec`, chessboards) is printed on an
infinite plane: board point ``X_b`` (mm, ``Z_b = 0``) sits at camera point ``X_c = R_b X_b + t_b``.
Each camera sub-pixel's undistorted ray ``t d`` meets the plane at
``t = (n . t_b) / (n . d)``, ``n = R_b e_z``; the point's board coordinates
``X_b = R_b^T (X_c - t_b)`` give its albedo (the chessboard's squares ``[c s, (c + 1) s) x
[r s, (r + 1) s)`` for ``c in -1..cols-1``, ``r in -1..rows-1``, dark where ``c + r`` is even,
light elsewhere and around the board) and ``X_p = R X_c + T`` projected through the
projector's ``K`` and distortion gives the true ``(u, v)``. :func:`~metrology.core.codecs.render.render_codec`
turns these into the camera images of any codec (noise, blur, gamma, bit depth from the
:class:`~metrology.core.simulate.SimulationOptions`).

Pose planning (:func:`pose_reaching`, :func:`plan_board_poses`) places the board the way a careful
user does for a calibration: for an orientation and a target point on the projector image's edge,
the pose whose outermost corner comes nearest to it with the whole printed board seen by the
camera and lit by the projector (:func:`board_in_view`); :func:`edge_angles_deg` gives the angle of
the board's square edges to the camera's pixel rows and columns (keep it 15 to 30 degrees).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec
from metrology.core.codecs.render import render_codec
from metrology.core.distortion import project_normalized, tilt_matrix, undistort_pixels
from metrology.core.geometry.pinhole import PinholeCamera, PinholeRig
from metrology.core.procam.board import BoardSpec
from metrology.core.simulate import SimulationOptions

FloatArray = npt.NDArray[np.float64]

DARK_ALBEDO = 0.08
LIGHT_ALBEDO = 0.9


@dataclass(frozen=True)
class BoardPose:
    """Board frame to camera frame: ``X_c = R X_b + t`` (mm)."""

    R: FloatArray
    t: FloatArray

    @classmethod
    def from_angles(cls, tilt_x_deg: float, tilt_y_deg: float, spin_deg: float, t_mm: npt.ArrayLike) -> BoardPose:
        """Rotation ``Rz(spin) Ry(tilt_y) Rx(tilt_x)`` (degrees), translation ``t_mm``."""
        rx = cv2.Rodrigues(np.array([np.radians(tilt_x_deg), 0.0, 0.0]))[0]
        ry = cv2.Rodrigues(np.array([0.0, np.radians(tilt_y_deg), 0.0]))[0]
        rz = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(spin_deg)]))[0]
        return cls(R=np.asarray(rz @ ry @ rx, dtype=np.float64), t=np.asarray(t_mm, dtype=np.float64))

    def centred(self, board: BoardSpec) -> BoardPose:
        """The same orientation with ``t`` moved so that ``t`` is where the board's centre sits."""
        centre = np.array([(board.cols - 1) * board.size_mm / 2, (board.rows - 1) * board.size_mm / 2, 0.0])
        return BoardPose(R=self.R, t=self.t - self.R @ centre)


def board_truth(
    rig: PinholeRig, board: BoardSpec, pose: BoardPose, supersample: int = 1
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """True ``u``, ``v`` and albedo on the camera's ``supersample``-times finer grid, ``(H s, W s)`` float64.

    Per sub-ray, compiled (:func:`metrology.core.simulate.kernels.board_pixels`, the bits of the
    numpy passes it replaced, ``tests/core/test_render_kernels.py``): the anti-aliased squares (a
    sub-ray covers a box of about ``|t| / (f_x s)`` mm of the board; the fraction of it on either
    side of the nearest edge line in x and in y weighs the four squares around it), the albedo, and
    the projection of the hit through the projector's ``K`` and distortion."""
    from metrology.core.simulate.kernels import board_pixels

    s = int(supersample)
    t, Xb, Xp = board_hits(rig, pose, s)
    coeffs = tuple(float(c) for c in rig.projector.distortion.coeffs)
    tilt = tilt_matrix(coeffs[12], coeffs[13]) if coeffs[12] != 0.0 or coeffs[13] != 0.0 else np.eye(3)
    u, v, albedo = (np.empty(t.shape) for _ in range(3))
    board_pixels(
        t.reshape(-1),
        Xb.reshape(-1, 3),
        Xp.reshape(-1, 3),
        float(np.asarray(rig.camera.K)[0, 0]) * s,
        float(board.size_mm),
        int(board.cols),
        int(board.rows),
        LIGHT_ALBEDO,
        DARK_ALBEDO,
        np.asarray(rig.projector.K, dtype=np.float64),
        coeffs,
        tilt,
        u.reshape(-1),
        v.reshape(-1),
        albedo.reshape(-1),
    )
    return u, v, albedo


def board_hits(rig: PinholeRig, pose: BoardPose, supersample: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Where each camera sub-ray ``t d`` meets the board's plane: ``t`` ``(H s, W s)``, the hit in
    the board's frame and in the projector's ``(H s, W s, 3)`` (mm), all C-contiguous float64."""
    d = _sub_ray_directions(rig.camera, supersample)
    n = pose.R[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = float(n @ pose.t) / (d @ n)
    X = d * t[..., None]
    Xb = (X - pose.t) @ pose.R  # R^T (X - t) for row vectors
    Xp = X @ np.asarray(rig.R).T + np.asarray(rig.T)
    return np.ascontiguousarray(t), np.ascontiguousarray(Xb), np.ascontiguousarray(Xp)


@functools.lru_cache(maxsize=4)
def _sub_ray_directions(camera: PinholeCamera, s: int) -> FloatArray:
    """``(H s, W s, 3)`` float64 directions ``(x, y, 1)`` of the camera's sub-pixel centres
    (undistorted normalized coordinates): the same for every pose, so kept (read-only)."""
    sub = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(camera.width_px)[:, None] + sub[None, :]).ravel()
    ys = (np.arange(camera.height_px)[:, None] + sub[None, :]).ravel()
    U, V = np.meshgrid(xs, ys)
    und = undistort_pixels(np.asarray(camera.K), camera.distortion, U, V)
    d = np.stack([und.x, und.y, np.ones_like(und.x)], axis=-1)
    d.setflags(write=False)
    return d


def true_corners(rig: PinholeRig, board: BoardSpec, pose: BoardPose) -> tuple[FloatArray, FloatArray]:
    """The board's points in the camera (pixels) and the projector (projector units), ``(N, 2)`` each
    (:func:`project_points` of the board's points in the camera frame)."""
    return project_points(rig, board.object_points() @ pose.R.T + pose.t)


def render_board(
    rig: PinholeRig,
    board: BoardSpec,
    pose: BoardPose,
    codec: Codec,
    options: SimulationOptions,
    *,
    seed: int = 0,
    shadow: npt.ArrayLike | None = None,
) -> np.ndarray:
    """The camera images of ``codec`` for a board pose: ``(frames, H, W)`` of the options' dtype.

    ``shadow``: optional ``(H s, W s)`` bool, True where the projector's light is blocked.
    """
    u, v, albedo = board_truth(rig, board, pose, options.supersample)
    if shadow is not None:
        blocked = np.asarray(shadow, dtype=bool)
        u = np.where(blocked, np.nan, u)
        v = np.where(blocked, np.nan, v)
    return render_codec(codec, u, v, options, albedo=albedo, seed=seed)


# ----------------------------------------------------------------------------- pose planning
PLAN_DEPTHS_MM: tuple[float, ...] = tuple(float(z) for z in np.arange(300.0, 651.0, 10.0))
"""Default camera depths (mm) at which :func:`pose_reaching` tries the board's anchor corner."""

PLAN_MARGIN_PX = 4.0
"""Default margin between the printed board and the edges of both images, pixels / projector units."""

PLAN_STEPS = 50
"""Default number of steps from a target towards the projector image's centre."""


def board_outline_mm(board: BoardSpec, per_side: int = 16) -> FloatArray:
    """The printed board's outline, ``(4 per_side, 3)`` float64 mm (board frame, ``Z = 0``).

    The rectangle ``[-s, cols s] x [-s, rows s]`` (``s`` the square) that :func:`board_truth`
    prints: the inner corners plus one square on every side, sampled along its sides because
    lens distortion bends straight edges.
    """
    s = board.size_mm
    x0, x1, y0, y1 = -s, board.cols * s, -s, board.rows * s
    f = np.linspace(0.0, 1.0, per_side, endpoint=False)
    sides = [
        np.stack([x0 + (x1 - x0) * f, np.full_like(f, y0)], axis=1),
        np.stack([np.full_like(f, x1), y0 + (y1 - y0) * f], axis=1),
        np.stack([x1 - (x1 - x0) * f, np.full_like(f, y1)], axis=1),
        np.stack([np.full_like(f, x0), y1 - (y1 - y0) * f], axis=1),
    ]
    xy = np.concatenate(sides)
    return np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1)


def project_points(rig: PinholeRig, Xc: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Camera-frame points ``(N, 3)`` mm to camera pixels and projector units, ``(N, 2)`` each
    (NaN behind a device)."""
    Xp = Xc @ np.asarray(rig.R).T + np.asarray(rig.T)
    with np.errstate(invalid="ignore", divide="ignore"):
        cu, cv_ = project_normalized(
            np.asarray(rig.camera.K), rig.camera.distortion, Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
        )
        pu, pv = project_normalized(
            np.asarray(rig.projector.K), rig.projector.distortion, Xp[:, 0] / Xp[:, 2], Xp[:, 1] / Xp[:, 2]
        )
    cam = np.stack([cu, cv_], axis=1)
    prj = np.stack([pu, pv], axis=1)
    cam[Xc[:, 2] <= 0] = np.nan
    prj[Xp[:, 2] <= 0] = np.nan
    return cam, prj


def board_in_view(rig: PinholeRig, board: BoardSpec, pose: BoardPose, margin_px: float = PLAN_MARGIN_PX) -> bool:
    """Whether the whole printed board (:func:`board_outline_mm`) is seen by the camera and lit by
    the projector, at least ``margin_px`` inside both images (which span ``-0.5 .. W - 0.5``), with
    its printed face towards both devices: the board frame's ``+Z`` axis ``n = R e_z`` points away
    from them (OpenCV's board frame), ``n . (C - t) < 0`` for the camera's centre ``C = 0`` and the
    projector's ``C = -R_rig^T T``."""
    Xc = board_outline_mm(board) @ pose.R.T + pose.t
    cam, prj = project_points(rig, Xc)
    m = float(margin_px)
    for pts, w, h in (
        (cam, rig.camera.width_px, rig.camera.height_px),
        (prj, rig.projector.width, rig.projector.height),
    ):
        with np.errstate(invalid="ignore"):
            ok = (
                (pts[:, 0] >= m - 0.5)
                & (pts[:, 0] <= w - 0.5 - m)
                & (pts[:, 1] >= m - 0.5)
                & (pts[:, 1] <= h - 0.5 - m)
            )
        if not bool(ok.all()):
            return False
    n = pose.R[:, 2]
    projector_centre = -np.asarray(rig.R).T @ np.asarray(rig.T)
    return float(n @ -pose.t) < 0 and float(n @ (projector_centre - pose.t)) < 0


def edge_angles_deg(rig: PinholeRig, board: BoardSpec, pose: BoardPose) -> FloatArray:
    """Angle between each square edge of the board in the camera image and the nearest pixel row
    or column, degrees in ``[0, 45]``; ``(rows (cols - 1) + cols (rows - 1),)`` float64.

    An edge along the pixel rows or columns (or their diagonals) keeps one sub-pixel phase along
    its whole length, so the sampling bias of the corner refinement does not average out: on the
    realistic virtual camera (0.7 px defocus, box pixels, no noise) the camera corners come out
    0.009 to 0.015 px RMS off with the board turned 0 or 45 degrees in the image and 0.003 px with
    it turned 15 to 30 degrees.
    """
    cam, _ = true_corners(rig, board, pose)
    grid = cam.reshape(board.rows, board.cols, 2)
    steps = np.concatenate([np.diff(grid, axis=1).reshape(-1, 2), np.diff(grid, axis=0).reshape(-1, 2)])
    a = np.degrees(np.arctan2(steps[:, 1], steps[:, 0])) % 90.0
    return np.asarray(np.minimum(a, 90.0 - a), dtype=np.float64)


def _projector_ray(rig: PinholeRig, uv: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Projector centre and the direction of the ray through projector point ``uv``, camera frame, mm."""
    und = undistort_pixels(np.asarray(rig.projector.K), rig.projector.distortion, uv[:1], uv[1:2])
    R, T = np.asarray(rig.R), np.asarray(rig.T)
    d = R.T @ np.array([float(und.x[0]), float(und.y[0]), 1.0])
    return -R.T @ T, d


def pose_reaching(
    rig: PinholeRig,
    board: BoardSpec,
    angles_deg: tuple[float, float, float],
    target_uv: tuple[float, float],
    *,
    depths_mm: tuple[float, ...] = PLAN_DEPTHS_MM,
    margin_px: float = PLAN_MARGIN_PX,
    steps: int = PLAN_STEPS,
) -> BoardPose | None:
    """The board pose of a given orientation that brings its outermost corner nearest to a projector point.

    The orientation is :meth:`BoardPose.from_angles` ``(tilt_x, tilt_y, spin)``, degrees. The
    anchor is the board point (inner corner) furthest towards ``target_uv`` from the projector
    image's centre ``c = ((W - 1)/2, (H - 1)/2)``, judged with the board centred on the projector's
    ray through ``c`` at the middle depth. For ``a = 0, 1/steps, ..., 1`` the anchor is put on the
    projector's ray through ``q = target + a (c - target)`` at each camera depth ``Z`` of
    ``depths_mm`` in turn (``X = C_p + l d`` with ``X_z = Z``, then ``t = X - R X_anchor``). The
    first ``a`` for which some depth gives a pose with :func:`board_in_view` wins, with the
    nearest such depth (the board largest in both images). So the board reaches as far towards the
    target as the two images allow: a target on the projector's edge brings the board's outer
    squares to ``margin_px`` from that edge, or as near as the camera's view allows.

    Returns None when no pose of this orientation fits in both images at any depth.
    """
    rot = BoardPose.from_angles(*angles_deg, (0.0, 0.0, 0.0)).R
    obj = board.object_points()
    w, h = rig.projector.width, rig.projector.height
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    target = np.asarray(target_uv, dtype=np.float64)
    direction = target - centre
    norm = float(np.linalg.norm(direction))
    direction = direction / norm if norm > 0 else np.array([1.0, 0.0])
    origin, ray = _projector_ray(rig, centre)
    middle = float(np.median(depths_mm))
    nominal = BoardPose(R=rot, t=origin + ray * (middle - origin[2]) / ray[2]).centred(board)
    _, prj = project_points(rig, obj @ nominal.R.T + nominal.t)
    offsets = prj - prj.mean(axis=0)
    along = np.round(offsets @ direction, 0)
    across = np.abs(offsets @ np.array([-direction[1], direction[0]]))
    anchor = int(np.lexsort((across, -along))[0])  # furthest along, then nearest the line
    for a in np.linspace(0.0, 1.0, int(steps) + 1):
        origin, ray = _projector_ray(rig, target + a * (centre - target))
        for z in depths_mm:
            lam = (float(z) - origin[2]) / ray[2]
            if lam <= 0:
                continue
            candidate = BoardPose(R=rot, t=origin + lam * ray - rot @ obj[anchor])
            if board_in_view(rig, board, candidate, margin_px):
                return candidate
    return None


def plan_board_poses(
    rig: PinholeRig,
    board: BoardSpec,
    plan: list[tuple[tuple[float, float, float], tuple[float, float]]],
    *,
    depths_mm: tuple[float, ...] = PLAN_DEPTHS_MM,
    margin_px: float = PLAN_MARGIN_PX,
    steps: int = PLAN_STEPS,
) -> list[BoardPose]:
    """Board poses for a plan of ``(angles_deg, target_uv)`` pairs, :func:`pose_reaching` each.

    Targets on the projector image's edges and corners, with the board tilted by 20 to 40 degrees
    in several directions and turned 15 to 30 degrees in its plane (:func:`edge_angles_deg`), give
    corners near every edge of the projector image that the camera sees, and of the camera image
    that the projector lights. Raises ValueError naming the entry when an orientation fits at no
    depth.
    """
    poses = []
    for k, (angles, target) in enumerate(plan):
        found = pose_reaching(rig, board, angles, target, depths_mm=depths_mm, margin_px=margin_px, steps=steps)
        if found is None:
            raise ValueError(f"plan[{k}]: the board at angles {angles} fits in both images at no depth")
        poses.append(found)
    return poses
