"""The calibration's least-squares model: board points through a device, the residuals of a fit,
their Jacobian and the covariance of every fitted parameter, board poses included.

- :func:`project_board`: board points through a pose and a device (``cv2.projectPoints``);
- :class:`ParameterCovariance`: named parameters, their values and covariance;
- :func:`covariance_of`: ``cov = s^2 (J^T J)^-1`` of a residual function at a minimum;
- :func:`joint_covariance`: the joint fit's (both devices' intrinsics, the stereo pose, each board
  pose in the camera's frame);
- :func:`device_covariance`: one device's own fit's (its intrinsics, each board pose in its frame),
  and :func:`independent`: two independent fits' as one (block diagonal);
- :func:`board_distances`: each board's distance from a device as a function of the parameters.

Parameter names: ``camera.fx``, ``camera.fy``, ``camera.cx``, ``camera.cy``, ``camera.k1``,
``camera.k2``, ``camera.p1``, ``camera.p2`` (``camera.k3`` unless it is held at 0), the same for
``projector``; ``stereo.rx``, ``stereo.ry``, ``stereo.rz`` (Rodrigues vector of ``R``, rad) and
``stereo.tx``, ``stereo.ty``, ``stereo.tz`` (``T``, mm); ``camera.pose[NAME].rx`` .. ``.tz`` (pose
``NAME``'s board in the camera's frame: Rodrigues vector, rad, and translation, mm), and in a
device's own fit ``projector.pose[NAME].rx`` .. ``.tz`` likewise in the projector's frame.
Intrinsics are in pixels (projector units), distortion coefficients without unit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
PointArray = npt.NDArray[np.floating[Any]]
"""Observed points, float32 (as OpenCV takes them) or float64."""

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
"""OpenCV's order of a device's intrinsics and distortion (``calibrateCameraExtended``'s std)."""
POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
SINGULAR_CONDITION = 1e13
"""The normal matrix ``J^T J``, its columns scaled to unit diagonal, counts as singular beyond this
condition number (three digits above double precision's noise): its covariance is then NaN."""


def project_board(obj: FloatArray, rvec: FloatArray, tvec: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    """Board points ``obj`` (n, 3) mm through the pose ``rvec``, ``tvec`` (3,) (Rodrigues vector,
    mm) and the device ``K`` (3, 3), ``dist`` (5,): ``(n, 2)`` float64 pixels / projector units."""
    pts, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, K, dist)
    return np.asarray(pts, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class ParameterCovariance:
    """A fit's parameters and their covariance.

    Attributes
    ----------
    names : tuple of str, (n,)
        The parameters (module docstring).
    values : (n,) float64
        Their fitted values.
    covariance : (n, n) float64
        ``s^2 (J^T J)^-1`` in the parameters' units; NaN when ``J^T J`` is singular or there are
        no more residuals than parameters.
    residual_variance : float
        ``s^2 = sum r^2 / (m - n)``, pixels^2 (NaN when ``m <= n``); for :func:`independent` fits
        the larger of the two.
    residuals : int
        ``m``, the number of residual components (two per point).
    """

    names: tuple[str, ...]
    values: FloatArray
    covariance: FloatArray
    residual_variance: float
    residuals: int

    def index(self, name: str) -> int:
        """The position of parameter ``name``; ValueError when it is not one."""
        return self.names.index(name)

    def std(self) -> FloatArray:
        """``sqrt(diag(covariance))``, (n,) float64."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def derived(self, function: Callable[[FloatArray], FloatArray]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Quantities ``q = function(theta)`` (k,) of the parameters, to first order:
        ``q``, their covariance ``G C G^T`` (k, k) and their covariance with the parameters
        ``G C`` (k, n), ``G = dq/dtheta`` by central differences (:func:`numeric_jacobian`)."""
        G = numeric_jacobian(function, self.values)
        return function(self.values), G @ self.covariance @ G.T, G @ self.covariance


def numeric_jacobian(function: Callable[[FloatArray], FloatArray], theta: FloatArray) -> FloatArray:
    """``d function / d theta`` at ``theta`` (n,) by central differences, steps
    ``1e-6 max(1, |theta_j|)``: (m, n) float64 for an (m,)-valued function."""
    columns = []
    for j in range(theta.size):
        h = 1e-6 * max(1.0, abs(float(theta[j])))
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        columns.append((function(up) - function(down)) / (2 * h))
    return np.stack(columns, axis=1)


def covariance_of(
    residuals: Callable[[FloatArray], FloatArray], theta: FloatArray, names: Sequence[str]
) -> ParameterCovariance:
    """The covariance of a least-squares fit ``theta`` (n,) of ``residuals`` (m,) at its minimum.

    ``cov = s^2 (J^T J)^-1`` with ``s^2 = sum r^2 / (m - n)`` (the estimate
    ``calibrateCameraExtended`` uses) and ``J`` by :func:`numeric_jacobian`; the inverse is taken
    of ``J^T J`` scaled to a unit diagonal (``D^-1 (D^-1 J^T J D^-1)^-1 D^-1``, ``D`` the columns'
    norms), which is the same matrix with the parameters' units taken out of its condition.
    NaN throughout when ``m <= n`` or the scaled matrix's condition exceeds :data:`SINGULAR_CONDITION`.
    """
    theta = np.asarray(theta, dtype=np.float64)
    r0 = residuals(theta)
    m, n = r0.size, theta.size
    nan = np.full((n, n), np.nan)
    if m <= n:
        return ParameterCovariance(tuple(names), theta, nan, float("nan"), m)
    J = numeric_jacobian(residuals, theta)
    s2 = float(r0 @ r0) / (m - n)
    norms = np.linalg.norm(J, axis=0)
    if not np.all(norms > 0):
        return ParameterCovariance(tuple(names), theta, nan, s2, m)
    A = (J / norms).T @ (J / norms)
    if not np.isfinite(A).all() or np.linalg.cond(A) > SINGULAR_CONDITION:
        return ParameterCovariance(tuple(names), theta, nan, s2, m)
    cov = np.linalg.inv(A) / np.outer(norms, norms) * s2
    return ParameterCovariance(tuple(names), theta, (cov + cov.T) / 2, s2, m)


def _n_intrinsics(fix_k3: bool) -> int:
    return 8 if fix_k3 else 9


def _pack_intrinsics(K: FloatArray, dist: FloatArray, fix_k3: bool) -> list[float]:
    d = np.asarray(dist, np.float64).ravel()[:5]
    return [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), *(float(x) for x in d)][
        : _n_intrinsics(fix_k3)
    ]


def _unpack_intrinsics(v: FloatArray, fix_k3: bool) -> tuple[FloatArray, FloatArray]:
    n = _n_intrinsics(fix_k3)
    K = np.array([[v[0], 0.0, v[2]], [0.0, v[1], v[3]], [0.0, 0.0, 1.0]])
    d = np.zeros(5)
    d[: n - 4] = v[4:n]
    return K, d


def _intrinsic_names(device: str, fix_k3: bool) -> list[str]:
    return [f"{device}.{name}" for name in INTRINSIC_NAMES[: _n_intrinsics(fix_k3)]]


def _pose_names(device: str, poses: Sequence[str]) -> list[str]:
    return [f"{device}.pose[{pose}].{name}" for pose in poses for name in POSE_NAMES]


def _pose_values(rvecs: Sequence[FloatArray], tvecs: Sequence[FloatArray]) -> list[float]:
    return [float(x) for r, t in zip(rvecs, tvecs, strict=True) for x in (*np.ravel(r), *np.ravel(t))]


def joint_covariance(
    obj: Sequence[PointArray],
    camera_px: Sequence[PointArray],
    projector_px: Sequence[PointArray],
    poses: Sequence[str],
    camera: tuple[FloatArray, FloatArray],
    projector: tuple[FloatArray, FloatArray],
    R: FloatArray,
    T: FloatArray,
    rvecs: Sequence[FloatArray],
    tvecs: Sequence[FloatArray],
    fix_k3: bool,
) -> ParameterCovariance:
    """The covariance of the joint stereo fit (:func:`covariance_of`).

    Parameters ``theta``: the camera's intrinsics, the projector's, the stereo pose ``rvec(R)``,
    ``T`` and each pose's camera-frame ``rvec_i``, ``t_i`` (module docstring's names). Residuals:
    every point's camera and projector reprojection error (pixels), the camera seeing pose
    ``(R_i, t_i)``, the projector ``(R R_i, R t_i + T)``. ``obj``: per pose (n_i, 3) mm;
    ``camera_px``, ``projector_px``: (n_i, 2); ``camera``, ``projector``: ``(K (3, 3), dist (5,))``;
    ``R`` (3, 3), ``T`` (3,) mm; ``rvecs``, ``tvecs``: per pose (3,) or (3, 1).
    """
    n_int = _n_intrinsics(fix_k3)
    names = [
        *_intrinsic_names("camera", fix_k3),
        *_intrinsic_names("projector", fix_k3),
        *(f"stereo.{name}" for name in POSE_NAMES),
        *_pose_names("camera", poses),
    ]
    theta = np.array(
        [
            *_pack_intrinsics(*camera, fix_k3),
            *_pack_intrinsics(*projector, fix_k3),
            *np.asarray(cv2.Rodrigues(np.asarray(R, np.float64))[0], np.float64).ravel(),
            *np.asarray(T, np.float64).ravel(),
            *_pose_values(rvecs, tvecs),
        ]
    )
    observed = np.concatenate(
        [np.concatenate([np.ravel(c), np.ravel(q)]) for c, q in zip(camera_px, projector_px, strict=True)]
    ).astype(np.float64)
    board = [np.asarray(o, np.float64).reshape(-1, 3) for o in obj]

    def residuals(v: FloatArray) -> FloatArray:
        Kc, dc = _unpack_intrinsics(v[:n_int], fix_k3)
        Kp, dp = _unpack_intrinsics(v[n_int : 2 * n_int], fix_k3)
        Rs = np.asarray(cv2.Rodrigues(v[2 * n_int : 2 * n_int + 3])[0], np.float64)
        Ts = v[2 * n_int + 3 : 2 * n_int + 6]
        out = []
        for k, o in enumerate(board):
            base = 2 * n_int + 6 + 6 * k
            rv, tv = v[base : base + 3], v[base + 3 : base + 6]
            Ri = np.asarray(cv2.Rodrigues(rv)[0], np.float64)
            out.append(project_board(o, rv, tv, Kc, dc).reshape(-1))
            rp = np.asarray(cv2.Rodrigues(Rs @ Ri)[0], np.float64).ravel()
            out.append(project_board(o, rp, Rs @ tv + Ts, Kp, dp).reshape(-1))
        return np.concatenate(out) - observed

    return covariance_of(residuals, theta, names)


def device_covariance(
    device: str,
    obj: Sequence[PointArray],
    image_px: Sequence[PointArray],
    poses: Sequence[str],
    intrinsics: tuple[FloatArray, FloatArray],
    rvecs: Sequence[FloatArray],
    tvecs: Sequence[FloatArray],
    fix_k3: bool,
) -> ParameterCovariance:
    """The covariance of one device's own fit (``calibrateCameraExtended``'s model,
    :func:`covariance_of`): its intrinsics and each pose's ``rvec_i``, ``t_i`` in its frame,
    residuals every point's reprojection error. ``device``: ``"camera"`` or ``"projector"`` (the
    names' prefix); shapes as in :func:`joint_covariance`."""
    n_int = _n_intrinsics(fix_k3)
    names = [*_intrinsic_names(device, fix_k3), *_pose_names(device, poses)]
    theta = np.array([*_pack_intrinsics(*intrinsics, fix_k3), *_pose_values(rvecs, tvecs)])
    observed = np.concatenate([np.ravel(p) for p in image_px]).astype(np.float64)
    board = [np.asarray(o, np.float64).reshape(-1, 3) for o in obj]

    def residuals(v: FloatArray) -> FloatArray:
        K, d = _unpack_intrinsics(v[:n_int], fix_k3)
        out = [
            project_board(o, v[n_int + 6 * k : n_int + 6 * k + 3], v[n_int + 6 * k + 3 : n_int + 6 * k + 6], K, d)
            for k, o in enumerate(board)
        ]
        return np.concatenate([p.reshape(-1) for p in out]) - observed

    return covariance_of(residuals, theta, names)


def independent(a: ParameterCovariance, b: ParameterCovariance) -> ParameterCovariance:
    """Two independently fitted parameter sets as one: names and values concatenated, the
    covariance block diagonal (no correlation between them)."""
    na, nb = len(a.names), len(b.names)
    cov = np.zeros((na + nb, na + nb))
    cov[:na, :na], cov[na:, na:] = a.covariance, b.covariance
    return ParameterCovariance(
        names=(*a.names, *b.names),
        values=np.concatenate([a.values, b.values]),
        covariance=cov,
        residual_variance=max(a.residual_variance, b.residual_variance),
        residuals=a.residuals + b.residuals,
    )


def board_distances(
    covariance: ParameterCovariance, device: str, poses: Sequence[str]
) -> Callable[[FloatArray], FloatArray]:
    """Each pose's board distance from ``device`` as a function of the parameters ``theta`` (n,):
    ``|t_i|`` (mm, the board origin's distance, as the report's ``distance_mm``) with ``t_i`` the
    board's translation in that device's frame: the ``DEVICE.pose[NAME]`` translation when the fit
    has it, else, for the projector of the joint fit, ``R t_i + T`` of the camera-frame pose and
    the stereo pose. Returns a function to (len(poses),) float64."""
    index = {name: k for k, name in enumerate(covariance.names)}

    def translation(prefix: str, pose: str) -> list[int]:
        return [index[f"{prefix}.pose[{pose}].{axis}"] for axis in ("tx", "ty", "tz")]

    if all(f"{device}.pose[{pose}].tx" in index for pose in poses):
        own = [translation(device, pose) for pose in poses]
        return lambda theta: np.array([float(np.linalg.norm(theta[i])) for i in own])
    camera = [translation("camera", pose) for pose in poses]
    r_index = [index[f"stereo.{axis}"] for axis in ("rx", "ry", "rz")]
    t_index = [index[f"stereo.{axis}"] for axis in ("tx", "ty", "tz")]

    def through_stereo(theta: FloatArray) -> FloatArray:
        R = np.asarray(cv2.Rodrigues(theta[r_index])[0], np.float64)
        return np.array([float(np.linalg.norm(R @ theta[i] + theta[t_index])) for i in camera])

    return through_stereo
