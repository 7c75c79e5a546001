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
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec
from metrology.core.codecs.render import render_codec
from metrology.core.distortion import project_normalized, undistort_pixels
from metrology.core.geometry.pinhole import PinholeRig
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
    """True ``u``, ``v`` and albedo on the camera's ``supersample``-times finer grid, ``(H s, W s)`` float64."""
    s = int(supersample)
    h, w = rig.camera.height_px, rig.camera.width_px
    sub = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(w)[:, None] + sub[None, :]).ravel()
    ys = (np.arange(h)[:, None] + sub[None, :]).ravel()
    U, V = np.meshgrid(xs, ys)
    und = undistort_pixels(np.asarray(rig.camera.K), rig.camera.distortion, U, V)
    d = np.stack([und.x, und.y, np.ones_like(und.x)], axis=-1)
    n = pose.R[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = float(n @ pose.t) / (d @ n)
    X = d * t[..., None]
    Xb = (X - pose.t) @ pose.R  # R^T (X - t) for row vectors
    # anti-aliased squares: each sub-sample covers a box of about fp mm on the board; the
    # fraction of it on either side of the nearest edge line in x and in y weighs the four squares
    fx = float(np.asarray(rig.camera.K)[0, 0])
    fp = np.abs(t) / (fx * s)
    sq = board.size_mm

    def dark(c: FloatArray, r: FloatArray) -> FloatArray:
        inside = (c >= -1) & (c <= board.cols - 1) & (r >= -1) & (r <= board.rows - 1)
        return (inside & ((c + r) % 2 == 0)).astype(np.float64)

    k = np.round(Xb[..., 0] / sq)
    m = np.round(Xb[..., 1] / sq)
    with np.errstate(invalid="ignore"):
        a = np.clip(0.5 + (Xb[..., 0] - k * sq) / fp, 0.0, 1.0)
        b = np.clip(0.5 + (Xb[..., 1] - m * sq) / fp, 0.0, 1.0)
    dark_fraction = (
        a * b * dark(k, m)
        + a * (1 - b) * dark(k, m - 1)
        + (1 - a) * b * dark(k - 1, m)
        + (1 - a) * (1 - b) * dark(k - 1, m - 1)
    )
    albedo = LIGHT_ALBEDO + (DARK_ALBEDO - LIGHT_ALBEDO) * dark_fraction
    Rr = np.asarray(rig.R)
    Xp = X @ Rr.T + np.asarray(rig.T)
    front = (t > 0) & (Xp[..., 2] > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        u, v = project_normalized(
            np.asarray(rig.projector.K), rig.projector.distortion, Xp[..., 0] / Xp[..., 2], Xp[..., 1] / Xp[..., 2]
        )
    u = np.where(front, u, np.nan)
    v = np.where(front, v, np.nan)
    return u, v, albedo


def true_corners(rig: PinholeRig, board: BoardSpec, pose: BoardPose) -> tuple[FloatArray, FloatArray]:
    """The board's points in the camera (pixels) and the projector (projector units), ``(N, 2)`` each."""
    obj = board.object_points()
    Xc = obj @ pose.R.T + pose.t
    Xp = Xc @ np.asarray(rig.R).T + np.asarray(rig.T)
    cu, cv_ = project_normalized(
        np.asarray(rig.camera.K), rig.camera.distortion, Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    )
    pu, pv = project_normalized(
        np.asarray(rig.projector.K), rig.projector.distortion, Xp[:, 0] / Xp[:, 2], Xp[:, 1] / Xp[:, 2]
    )
    return np.stack([cu, cv_], axis=1), np.stack([pu, pv], axis=1)


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
