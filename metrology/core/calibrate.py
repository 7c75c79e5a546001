"""Calibration of L and alpha on a master block of known height (paper section 4, and better).

Both methods work on decoded light-code maps (reference REF and master OBJ),
which depend only on the true geometry; the parameter estimates enter only
through triangulation (Eqs. 14, 16, 17), so each iteration re-triangulates the
same codes.

``calibrate_paper`` -- the paper's two nested loops
    Each iteration triangulates the master with the current ``(L_e, alpha_e)``,
    takes the profile of its top face along X (all top-face pixels; see
    :func:`find_top_face`) and fits the regression line ``z = z0 + m X``
    (m dimensionless: mm of height per mm of X).

    - exit when ``|mean - H| < delta_z`` **and** ``|m| <= m_hat`` (the paper states only
      the first test; without the second the loop may stop with alpha untouched);
    - inner loop (``|m| > m_hat``): ``alpha' = (1 + w m) alpha`` (Eq. 26);
    - outer loop (``|m| <= m_hat``): ``L' = L H / mean``, the linear dependence of
      height on L of Eq. 17 (``z = L D_R / (d + D_R)``).

    Sign and size of ``w``: an over-estimated alpha tilts a flat profile upwards
    along X (Fig. 6; ``m > 0`` when ``alpha_e > alpha``), so ``w`` must be
    negative. The Newton step is ``w = -1 / (dm/d ln alpha)``; with ``w=None``
    (default) it is "determined experimentally" as the paper puts it, by one
    finite difference of the slope on the master's own codes at the start. For
    the paper's rig and a 40 mm master, ``w`` is about -44; the slope sensitivity
    scales with the master height, so a fixed ``w`` only suits one master.

    Note (:mod:`metrology.core.sensitivity`): an L error also tilts the profile
    (the exact L coefficient varies from ~1.13 to ~0.87 across the field), so the
    inner loop first absorbs part of the L error into alpha; the alternation of the
    two loops removes it.

``calibrate_lsq`` -- joint least squares (recommended default)
    Minimises ``sum (z_i(L, alpha[, d]) - z_known_i)^2`` over all classified pixels
    of one or more master captures: top-face pixels (known height H) and floor
    pixels (known height 0), with ``scipy.optimize.least_squares`` (trust-region
    Gauss-Newton). Jacobian by central differences on the re-triangulated codes.
    The parameter covariance is ``s^2 (J^T J)^-1`` with ``s^2`` the residual variance.

    Identifiability: floor pixels see the same light plane in both captures, so
    their height is 0 for *every* (L, alpha, d): they carry no information (they
    are kept for the residual map). On the top face, L mostly scales the mean height
    and alpha mostly tilts it along X, so (L, alpha) are well identified from one
    master height. d is not: at one height a d error is absorbed by L (Eq. 25 versus
    Eq. 23, see section 4 of the paper); fitting d needs masters at several heights
    and remains poorly conditioned -- keep ``fit_d=False`` unless several heights are given.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage, optimize

from metrology.core.geometry.crossed_axes import Rig, RigError, camera_ray_point, height_from_codes

Roi = tuple[slice, slice]


@dataclass(frozen=True)
class MasterCapture:
    """Decoded codes of one master-block capture and its known height.

    Parameters
    ----------
    ref_codes : (height_px, width_px) float array
        Reference-plane codes (REF), code units, NaN where invalid.
    master_codes : (height_px, width_px) float array
        Codes with the master block on R (OBJ), code units, NaN where invalid.
    height_mm : float
        Known height of the master's top face above R, mm, > 0.
    roi : (slice, slice), optional
        Rows and columns where the top face is looked for (default: whole image).
    """

    ref_codes: np.ndarray
    master_codes: np.ndarray
    height_mm: float
    roi: Roi | None = None


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of a calibration.

    Attributes
    ----------
    method : {'paper', 'lsq'}
    rig : Rig
        The calibrated rig (initial rig with the fitted L, alpha and, if fitted, d).
    converged : bool
    iterations : int
        Profiles evaluated (paper) or Gauss-Newton iterations, i.e. Jacobian
        evaluations (lsq).
    history : tuple of dict
        One entry per iteration: ``L_mm``, ``alpha_rad``, ``d_mm``, ``mean_height_mm``,
        ``slope`` (top-face regression slope, mm/mm) and, by method, ``step``
        (``'alpha'``/``'L'``/``'exit'``) or ``rms_mm``.
    elapsed_s : float
        Wall time, s.
    parameters : dict
        The settings used (delta_z_mm, m_hat, w, ...).
    covariance : (p, p) float64 array or None
        Covariance of the fitted parameters (lsq), in the order of ``parameter_names``.
    parameter_names : tuple of str
    residual_mm : (height_px, width_px) float32 array or None
        Measured minus known height of the (first) master at the result, mm; NaN
        where unused (lsq).
    residual_rms_mm : float
        RMS of the residuals used in the fit (lsq) or of the top-face heights about
        their regression line (paper), mm.
    n_pixels : int
        Pixels used.
    message : str
    """

    method: str
    rig: Rig
    converged: bool
    iterations: int
    history: tuple[dict[str, Any], ...]
    elapsed_s: float
    parameters: dict[str, Any] = field(default_factory=dict)
    covariance: np.ndarray | None = None
    parameter_names: tuple[str, ...] = ()
    residual_mm: np.ndarray | None = field(default=None, repr=False)
    residual_rms_mm: float = math.nan
    n_pixels: int = 0
    message: str = ""

    @property
    def L_mm(self) -> float:
        return self.rig.L_mm

    @property
    def alpha_rad(self) -> float:
        return self.rig.alpha_rad

    @property
    def d_mm(self) -> float:
        return self.rig.d_mm

    @property
    def std_errors(self) -> dict[str, float]:
        """One-sigma uncertainties of the fitted parameters (empty for the paper's method)."""
        if self.covariance is None:
            return {}
        return {
            n: float(math.sqrt(max(v, 0.0)))
            for n, v in zip(self.parameter_names, np.diag(self.covariance), strict=True)
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable summary (the ``"calibration"`` object of a calibrated rig file)."""
        out: dict[str, Any] = {
            "method": self.method,
            "iterations": self.iterations,
            "converged": self.converged,
            "L_mm": self.L_mm,
            "alpha_rad": self.alpha_rad,
            "d_mm": self.d_mm,
            "history": [dict(h) for h in self.history],
            "elapsed_s": self.elapsed_s,
            "parameters": dict(self.parameters),
            "residual_rms_mm": _finite_or_none(self.residual_rms_mm),
            "n_pixels": self.n_pixels,
            "message": self.message,
        }
        if self.covariance is not None:
            out["parameter_names"] = list(self.parameter_names)
            out["covariance"] = self.covariance.tolist()
            out["std_errors"] = self.std_errors
        return out


# --------------------------------------------------------------------------- helpers
def find_top_face(
    z_mm: npt.ArrayLike, height_mm: float, roi: Roi | None = None, erosion_px: int | None = None
) -> np.ndarray:
    """Pixels of a master block's top face, found automatically.

    Pixels measured above ``height_mm / 2`` (inside ``roi``; isolated invalid pixels
    bridged by a 2-pixel closing), largest connected region, eroded by ``erosion_px``
    (default: 2 % of the image width, at least 2) so that edges, side walls and shadow borders are left out.

    Parameters
    ----------
    z_mm : (H, W) float array
        Heights measured with the current estimates, mm, NaN where invalid.
    height_mm : float
        Nominal top-face height, mm, > 0.
    roi : (slice, slice), optional
    erosion_px : int, optional

    Returns
    -------
    mask : (H, W) bool array

    Raises
    ------
    ValueError
        If no top face is found.
    """
    z = np.asarray(z_mm)
    if z.ndim != 2:
        raise ValueError(f"z_mm must be a 2D height map, got shape {z.shape}")
    if not (height_mm > 0):
        raise ValueError(f"height_mm must be positive, got {height_mm!r}")
    with np.errstate(invalid="ignore"):
        candidate = np.isfinite(z) & (z > height_mm / 2)
    if roi is not None:
        window = np.zeros_like(candidate)
        window[roi] = True
        candidate &= window
    finite = np.isfinite(z)
    # bridge isolated invalid pixels (decoding dropouts) so the face stays one region
    candidate = ndimage.binary_closing(candidate, iterations=2, border_value=0) | candidate
    labels, n = ndimage.label(candidate)
    if n == 0:
        raise ValueError(f"no top face above {height_mm / 2} mm found in the master's height map")
    sizes = ndimage.sum_labels(candidate, labels, index=np.arange(1, n + 1))
    face = labels == (1 + int(np.argmax(sizes)))
    if erosion_px is None:
        erosion_px = max(2, round(0.02 * z.shape[1]))
    if erosion_px > 0:
        face = ndimage.binary_erosion(face, iterations=int(erosion_px), border_value=0)
    face &= finite
    if face.sum() < 10:
        raise ValueError("the master's top face is too small after erosion (fewer than 10 pixels)")
    return face


def fit_master_profile(rig: Rig, z_mm: np.ndarray, face: np.ndarray) -> tuple[float, float, float]:
    """Mean height, regression slope along X and residual RMS of the master's top face.

    The profile's abscissa is ``X_H`` of each pixel (docs/conventions.md).

    Returns
    -------
    mean_mm : float
    slope : float
        Regression slope of height against X, mm/mm (dimensionless).
    rms_mm : float
        RMS of the heights about the regression line, mm.
    """
    z = z_mm[face].astype(np.float64)
    x_a = np.broadcast_to(rig.column_x_mm()[None, :], z_mm.shape)[face]
    ok = np.isfinite(z)
    z, x_a = z[ok], x_a[ok]
    x, _ = camera_ray_point(rig, x_a, 0.0, z)
    xc = x - x.mean()
    slope = float(np.dot(xc, z - z.mean()) / np.dot(xc, xc))
    resid = z - z.mean() - slope * xc
    return float(z.mean()), slope, float(np.sqrt(np.mean(resid**2)))


def _check_codes(rig: Rig, name: str, codes: npt.ArrayLike) -> np.ndarray:
    c = np.asarray(codes)
    if c.shape != rig.shape:
        raise ValueError(f"{name} must have the rig's shape {rig.shape}, got {c.shape}")
    if c.dtype.kind != "f":
        raise ValueError(f"{name} must be a float array of light codes, got dtype {c.dtype}")
    return c.astype(np.float64)


def _estimate(rig: Rig, **values: float) -> Rig:
    try:
        return rig.with_parameters(**values)
    except RigError as exc:
        raise ValueError(f"calibration left the valid parameter range: {exc}") from exc


# --------------------------------------------------------------------------- the paper
def calibrate_paper(
    rig: Rig,
    ref_codes: npt.ArrayLike,
    master_codes: npt.ArrayLike,
    height_mm: float,
    *,
    roi: Roi | None = None,
    delta_z_mm: float = 0.025,
    m_hat: float = 1e-4,
    w: float | None = None,
    max_iterations: int = 30,
) -> CalibrationResult:
    """The paper's calibration of L and alpha (section 4, Eq. 26).

    Parameters
    ----------
    rig : Rig
        Initial rough estimates ``L_0``, ``alpha_0`` (and the fixed ``d``, ``FW``, ``nlp``).
    ref_codes, master_codes : (height_px, width_px) float arrays
        Decoded codes of the reference plane and of the master block on it, code
        units, NaN where invalid.
    height_mm : float
        Known height H of the master's top face, mm.
    roi : (slice, slice), optional
        Where to look for the top face.
    delta_z_mm : float
        Required accuracy of the mean top-face height, mm (paper: 0.025).
    m_hat : float
        Slope threshold of the inner loop, mm/mm (paper: 0.0001).
    w : float, optional
        Weight factor of Eq. 26 (negative, see module notes); default: measured at the
        start by a finite difference (about -44 for the paper's rig and H = 40 mm).
    max_iterations : int
        Cap on profile evaluations (paper: typically 15-30).

    Returns
    -------
    CalibrationResult
        ``method='paper'``; ``history`` has one entry per profile evaluated, with the
        step taken after it (``'alpha'``, ``'L'`` or ``'exit'``).

    Raises
    ------
    ValueError
        For bad arguments, no top face, or estimates leaving the valid range.
    """
    t0 = time.perf_counter()
    ref = _check_codes(rig, "ref_codes", ref_codes)
    obj = _check_codes(rig, "master_codes", master_codes)
    if not (height_mm > 0):
        raise ValueError(f"height_mm must be positive, got {height_mm!r}")
    if not (delta_z_mm > 0) or not (m_hat > 0):
        raise ValueError(f"delta_z_mm and m_hat must be positive, got {delta_z_mm!r}, {m_hat!r}")
    if not isinstance(max_iterations, int) or max_iterations < 1:
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if w is not None and not (math.isfinite(w) and w != 0):
        raise ValueError(f"w must be a finite non-zero number or None, got {w!r}")

    face = find_top_face(height_from_codes(rig, ref, obj), height_mm, roi)
    ref_f, obj_f = ref[face], obj[face]

    def profile(estimate: Rig) -> tuple[float, float, float]:
        z = np.full(rig.shape, np.nan)
        z[face] = height_from_codes(estimate, ref_f, obj_f)
        return fit_master_profile(estimate, z, face)

    w_source = "given"
    if w is None:
        h = 0.01
        _, m_plus, _ = profile(_estimate(rig, alpha_rad=rig.alpha_rad * (1 + h)))
        _, m_minus, _ = profile(_estimate(rig, alpha_rad=rig.alpha_rad * (1 - h)))
        w = -2 * h / (m_plus - m_minus)
        w_source = "finite difference at the start"

    estimate = rig
    history: list[dict[str, Any]] = []
    converged = False
    rms = math.nan
    for _ in range(max_iterations):
        mean, slope, rms = profile(estimate)
        entry: dict[str, Any] = {
            "L_mm": estimate.L_mm,
            "alpha_rad": estimate.alpha_rad,
            "d_mm": estimate.d_mm,
            "mean_height_mm": mean,
            "slope": slope,
        }
        history.append(entry)
        if abs(mean - height_mm) < delta_z_mm and abs(slope) <= m_hat:
            entry["step"] = "exit"
            converged = True
            break
        if abs(slope) > m_hat:  # inner loop, Eq. 26
            entry["step"] = "alpha"
            estimate = _estimate(estimate, alpha_rad=(1 + w * slope) * estimate.alpha_rad)
        else:  # outer loop: z is proportional to L (Eq. 17)
            entry["step"] = "L"
            estimate = _estimate(estimate, L_mm=estimate.L_mm * height_mm / mean)

    return CalibrationResult(
        method="paper",
        rig=estimate,
        converged=converged,
        iterations=len(history),
        history=tuple(history),
        elapsed_s=time.perf_counter() - t0,
        parameters={
            "height_mm": float(height_mm),
            "delta_z_mm": float(delta_z_mm),
            "m_hat": float(m_hat),
            "w": float(w),
            "w_source": w_source,
            "max_iterations": max_iterations,
        },
        residual_rms_mm=rms,
        n_pixels=int(face.sum()),
        message="converged" if converged else f"not converged after {max_iterations} iterations",
    )


# --------------------------------------------------------------------------- least squares
def calibrate_lsq(
    rig: Rig,
    captures: MasterCapture | Sequence[MasterCapture],
    *,
    fit_d: bool = False,
    use_floor: bool = True,
    max_iterations: int = 8,
    tolerance: float = 1e-10,
) -> CalibrationResult:
    """Joint least-squares calibration of L and alpha (and optionally d).

    Parameters
    ----------
    rig : Rig
        Initial estimates (e.g. the paper's rough start) and the fixed FW, nlp.
    captures : MasterCapture or sequence of MasterCapture
        One or more master captures (possibly of different heights).
    fit_d : bool
        Also fit d (needs several master heights; poorly conditioned, see module notes).
    use_floor : bool
        Include floor pixels (known height 0). They carry no information about the
        parameters but enter the residual map and the residual variance.
    max_iterations : int
        Cap on Gauss-Newton iterations (Jacobian evaluations).
    tolerance : float
        Relative tolerance on cost, step and gradient (``ftol``, ``xtol``, ``gtol``).

    Returns
    -------
    CalibrationResult
        ``method='lsq'``, with covariance, residual map of the first capture and
        history (``L_mm``, ``alpha_rad``, ``d_mm``, ``rms_mm``, ``mean_height_mm`` and
        ``slope`` of the first capture's top face) per iteration.

    Raises
    ------
    ValueError
        For bad arguments or when no top face is found.
    """
    t0 = time.perf_counter()
    if isinstance(captures, MasterCapture):
        captures = [captures]
    captures = list(captures)
    if not captures or not all(isinstance(c, MasterCapture) for c in captures):
        raise ValueError("captures must be a MasterCapture or a non-empty sequence of them")
    if not isinstance(max_iterations, int) or max_iterations < 1:
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if fit_d and len({round(c.height_mm, 6) for c in captures}) < 2:
        raise ValueError("fit_d=True needs master captures of at least two different heights")

    # classify pixels once, with the initial estimates
    refs, objs, knowns, masks, faces = [], [], [], [], []
    for i, cap in enumerate(captures):
        ref = _check_codes(rig, f"captures[{i}].ref_codes", cap.ref_codes)
        obj = _check_codes(rig, f"captures[{i}].master_codes", cap.master_codes)
        if not (cap.height_mm > 0):
            raise ValueError(f"captures[{i}].height_mm must be positive, got {cap.height_mm!r}")
        z0 = height_from_codes(rig, ref, obj)
        face = find_top_face(z0, cap.height_mm, cap.roi)
        use = face.copy()
        if use_floor:
            with np.errstate(invalid="ignore"):
                low = np.isfinite(z0) & (z0 < cap.height_mm / 2)
            erosion = max(2, round(0.02 * rig.width_px))
            use |= ndimage.binary_erosion(low, iterations=erosion, border_value=1)
        use &= np.isfinite(z0)
        known = np.where(face, cap.height_mm, 0.0)
        refs.append(ref[use])
        objs.append(obj[use])
        knowns.append(known[use])
        masks.append(use)
        faces.append(face)
    ref_all, obj_all, known_all = np.concatenate(refs), np.concatenate(objs), np.concatenate(knowns)

    names = ("L_mm", "alpha_rad", "d_mm") if fit_d else ("L_mm", "alpha_rad")
    p0 = np.array([getattr(rig, n) for n in names])
    scale = np.abs(p0)

    def rig_at(u: np.ndarray) -> Rig:
        return _estimate(rig, **{n: float(v) for n, v in zip(names, p0 + u * scale, strict=True)})

    def residual(u: np.ndarray) -> np.ndarray:
        try:
            estimate = rig_at(u)
        except ValueError:
            return np.full(known_all.shape, 1e6)
        return height_from_codes(estimate, ref_all, obj_all) - known_all

    history: list[dict[str, Any]] = []
    face0 = faces[0]

    def jacobian(u: np.ndarray) -> np.ndarray:
        r = residual(u)
        estimate = rig_at(u)
        z_face = np.full(rig.shape, np.nan)
        z_face[face0] = height_from_codes(estimate, captures[0].ref_codes[face0], captures[0].master_codes[face0])
        mean, slope, _ = fit_master_profile(estimate, z_face, face0)
        history.append(
            {
                "L_mm": estimate.L_mm,
                "alpha_rad": estimate.alpha_rad,
                "d_mm": estimate.d_mm,
                "rms_mm": float(np.sqrt(np.mean(r**2))),
                "mean_height_mm": mean,
                "slope": slope,
            }
        )
        h = 1e-6
        cols = []
        for i in range(len(names)):
            e = np.zeros_like(u)
            e[i] = h
            cols.append((residual(u + e) - residual(u - e)) / (2 * h))
        return np.stack(cols, axis=1)

    sol = optimize.least_squares(
        residual,
        np.zeros(len(names)),
        jac=jacobian,
        method="trf",
        ftol=tolerance,
        xtol=tolerance,
        gtol=tolerance,
        max_nfev=max_iterations + 1,
    )
    final = rig_at(sol.x)
    r = sol.fun
    n, p = r.size, len(names)
    s2 = float(np.dot(r, r) / max(n - p, 1))
    jac = sol.jac / scale[None, :]  # d r / d parameter (physical units)
    try:
        covariance = s2 * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        covariance = np.full((p, p), np.nan)
    converged = bool(sol.status > 0)

    resid_map = np.full(rig.shape, np.nan, dtype=np.float32)
    resid_map[masks[0]] = r[: int(masks[0].sum())]
    face_z = np.full(rig.shape, np.nan)
    face_z[face0] = height_from_codes(final, captures[0].ref_codes[face0], captures[0].master_codes[face0])
    mean, slope, _ = fit_master_profile(final, face_z, face0)
    history.append(
        {
            "L_mm": final.L_mm,
            "alpha_rad": final.alpha_rad,
            "d_mm": final.d_mm,
            "rms_mm": float(np.sqrt(np.mean(r**2))),
            "mean_height_mm": mean,
            "slope": slope,
            "step": "final",
        }
    )
    return CalibrationResult(
        method="lsq",
        rig=final,
        converged=converged,
        iterations=int(sol.njev),
        history=tuple(history),
        elapsed_s=time.perf_counter() - t0,
        parameters={
            "fit_d": fit_d,
            "use_floor": use_floor,
            "max_iterations": max_iterations,
            "tolerance": tolerance,
            "heights_mm": [float(c.height_mm) for c in captures],
        },
        covariance=covariance,
        parameter_names=names,
        residual_mm=resid_map,
        residual_rms_mm=float(np.sqrt(np.mean(r**2))),
        n_pixels=int(n),
        message=str(sol.message),
    )


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
