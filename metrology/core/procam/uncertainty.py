"""What the poses cannot determine: each intrinsic's standard deviation from the full covariance of
the fit (board poses included), its correlation with the boards' distances, and the spread of the
leave-one-pose-out fits beside it (docs/procam-calibration.md, "What the poses cannot determine").

- :func:`intrinsics_uncertainty`: the :class:`Uncertainty` of a stereo fit and its left-out fits;
- :func:`jackknife_std`: the leave-one-pose-out spread of a value;
- :func:`uncertainty_report`: the report's ``uncertainty`` entry.

Correlation of an intrinsic ``p`` with a board distance ``d`` (a function of the parameters,
:func:`~metrology.core.procam.bundle.board_distances`), to first order with ``g = dd/dtheta``::

    corr(p, d) = (g C)_p / sqrt(C_pp g C g^T)

``C`` the fit's covariance (:func:`~metrology.core.procam.fit.final_covariance`). The distance of
a device is the board origin's distance in that device's frame (the report's ``distance_mm`` for
the camera); the *mean* distance is the mean over the poses. A board that faces a device at one
distance lets a focal length ``s f`` and distances ``s d`` explain its corners as well as ``f`` and
``d`` (``u = f X / Z + c``): ``|corr(f, mean distance)|`` tends to 1, and ``f`` is known no better
than the distance, :data:`CORRELATION_LIMIT` says when to warn.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.procam.bundle import INTRINSIC_NAMES, ParameterCovariance, board_distances
from metrology.core.procam.fit import LeftOutFit, StereoFit

FloatArray = npt.NDArray[np.float64]

DEVICES = ("camera", "projector")
FOCAL_NAMES = ("fx", "fy")
CORRELATION_LIMIT = 0.999
"""A focal length whose correlation with the boards' mean distance exceeds this in magnitude is not
separable from the distance: its standard deviation is then more than ``1 / sqrt(1 - 0.999^2)`` =
22 times what it would be were the distances known. Correlation depends on the poses, not on the
noise. Measured on the virtual rig (corners of exact projections plus noise, joint fit): the
planned poses tilted 20 to 30 degrees 0.970 (camera) and 0.978 (projector), boards tilted up to
25 degrees around the images' middle 0.988 and 0.989 (0.993 with the intrinsics held), boards
tilted up to 10 degrees at one distance 0.9992 and 0.9989, up to 5 degrees 0.9998, up to 1.5
degrees 0.99997 (also at three distances); the real kamino410 poses 0.990 and 0.909
(docs/procam-calibration.md)."""
SPREAD_FACTOR = 4.0
"""The leave-one-pose-out spread and the covariance's standard deviation agree when their ratio is
within ``1 / 4 .. 4``: the spread of a few refits is itself uncertain. Over 40 draws of 6 poses with
0.1 px Gaussian corner noise, where the covariance is right (its std is 0.93 to 1.18 times the
draws' spread), the ratio of 16 intrinsics ranged 0.10 to 3.07, 99 % of them within 0.30 to
2.6: a factor 4 flags 0.3 % of them, one calibration in 40; a factor 3 would flag one in 8
(``benchmarks/procam_uncertainty.py``)."""


def jackknife_std(values: FloatArray) -> float | None:
    """The jackknife standard deviation of an estimate from its leave-one-out values ``x_i``
    (n,) float64: ``sqrt((n - 1) / n * sum (x_i - mean x)^2)`` over the finite values; None for
    fewer than 3 finite values."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    n = x.size
    if n < 3:
        return None
    return float(math.sqrt((n - 1) / n * float(np.sum((x - x.mean()) ** 2))))


@dataclass(frozen=True)
class IntrinsicUncertainty:
    """One intrinsic (``fx``, ``fy``, ``cx``, ``cy``, ``k1``, ``k2``, ``p1``, ``p2``, ``k3``) of a device.

    Attributes
    ----------
    name : str
    value : float
        Pixels (projector units) for fx..cy, no unit for the distortion.
    std : float
        ``sqrt(C_pp)`` of the full covariance.
    std_reported : float
        The report's ``std`` (the same in the joint fit; ``calibrateCameraExtended``'s otherwise).
    leave_one_out_std : float or None
        :func:`jackknife_std` of the left-out fits' values (None with fewer than 3).
    distance_correlation : float
        Correlation with the boards' mean distance from the device (NaN when the covariance is).
    pose_distance_correlations : tuple of float
        Correlation with each pose's board distance, in pose order.
    """

    name: str
    value: float
    std: float
    std_reported: float
    leave_one_out_std: float | None
    distance_correlation: float
    pose_distance_correlations: tuple[float, ...]

    @property
    def spread_ratio(self) -> float | None:
        """``leave_one_out_std / std`` (None without a spread or a positive finite std)."""
        if self.leave_one_out_std is None or not (math.isfinite(self.std) and self.std > 0):
            return None
        return self.leave_one_out_std / self.std

    @property
    def agrees(self) -> bool | None:
        """The spread and the std agree within :data:`SPREAD_FACTOR` (None when not compared)."""
        ratio = self.spread_ratio
        return None if ratio is None else 1 / SPREAD_FACTOR <= ratio <= SPREAD_FACTOR


@dataclass(frozen=True)
class DeviceUncertainty:
    """A device's intrinsics and the boards' distances from it.

    ``distances_mm``, ``distance_std_mm``: per pose (mm); ``mean_distance_mm`` and its std.
    """

    device: str
    intrinsics: tuple[IntrinsicUncertainty, ...]
    distances_mm: tuple[float, ...]
    distance_std_mm: tuple[float, ...]
    mean_distance_mm: float
    mean_distance_std_mm: float

    def get(self, name: str) -> IntrinsicUncertainty:
        """The intrinsic ``name``; KeyError when the fit held it."""
        for item in self.intrinsics:
            if item.name == name:
                return item
        raise KeyError(name)

    def focal(self) -> IntrinsicUncertainty:
        """The focal length (fx or fy) most correlated with the mean distance (fx on NaN)."""
        fx, fy = self.get("fx"), self.get("fy")
        if math.isnan(fy.distance_correlation):
            return fx
        return fy if abs(fy.distance_correlation) > abs(fx.distance_correlation) else fx


@dataclass(frozen=True)
class Uncertainty:
    """Both devices' :class:`DeviceUncertainty`, the poses (in order), the covariance they come from,
    whether it is the joint fit's, and how many left-out fits gave the spreads."""

    poses: tuple[str, ...]
    joint: bool
    covariance: ParameterCovariance
    camera: DeviceUncertainty
    projector: DeviceUncertainty
    left_out_fits: int

    def devices(self) -> tuple[DeviceUncertainty, DeviceUncertainty]:
        return self.camera, self.projector

    def coupled(self) -> list[DeviceUncertainty]:
        """The devices whose focal length is not separable from the distance:
        ``|corr| > CORRELATION_LIMIT``, or a singular covariance (NaN)."""
        out = []
        for device in self.devices():
            r = device.focal().distance_correlation
            if math.isnan(r) or abs(r) > CORRELATION_LIMIT:
                out.append(device)
        return out

    def disagreements(self) -> list[str]:
        """``device.name`` of every intrinsic whose spread and std disagree, in order."""
        return [f"{d.device}.{p.name}" for d in self.devices() for p in d.intrinsics if p.agrees is False]


def _correlations(cross: FloatArray, variance: FloatArray, derived_variance: FloatArray) -> FloatArray:
    """``cross (k, n) / sqrt(variance (n,) x derived_variance (k,))``: (k, n), NaN where undefined."""
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cross / np.sqrt(np.outer(derived_variance, variance))
    return np.where(np.isfinite(corr), np.clip(corr, -1.0, 1.0), np.nan)


def _device_uncertainty(
    stereo: StereoFit, covariance: ParameterCovariance, device: str, spreads: dict[str, float | None]
) -> DeviceUncertainty:
    poses = stereo.names
    distance = board_distances(covariance, device, poses)

    def distances_and_mean(theta: FloatArray) -> FloatArray:
        d = distance(theta)
        return np.append(d, d.mean())

    values, derived_cov, cross = covariance.derived(distances_and_mean)
    variance = np.diag(covariance.covariance)
    corr = _correlations(cross, variance, np.diag(derived_cov))
    reported = np.ravel(getattr(stereo, device).std)  # the report's std: the final fit's
    std = covariance.std()
    items = []
    for k, name in enumerate(INTRINSIC_NAMES):
        key = f"{device}.{name}"
        if key not in covariance.names:
            continue
        j = covariance.index(key)
        items.append(
            IntrinsicUncertainty(
                name=name,
                value=float(covariance.values[j]),
                std=float(std[j]),
                std_reported=float(reported[k]) if k < reported.size else math.nan,
                leave_one_out_std=spreads.get(name),
                distance_correlation=float(corr[-1, j]),
                pose_distance_correlations=tuple(float(x) for x in corr[:-1, j]),
            )
        )
    distance_std = np.sqrt(np.clip(np.diag(derived_cov), 0.0, None))
    return DeviceUncertainty(
        device=device,
        intrinsics=tuple(items),
        distances_mm=tuple(float(x) for x in values[:-1]),
        distance_std_mm=tuple(float(x) for x in distance_std[:-1]),
        mean_distance_mm=float(values[-1]),
        mean_distance_std_mm=float(distance_std[-1]),
    )


def intrinsics_uncertainty(stereo: StereoFit, left_out: Sequence[LeftOutFit]) -> Uncertainty:
    """The :class:`Uncertainty` of ``stereo`` (its ``covariance`` must be set) with the spreads of
    ``left_out`` (:func:`~metrology.core.procam.fit.leave_one_out_fits`; empty: no spreads)."""
    covariance = stereo.covariance
    if covariance is None:
        raise ValueError("the stereo fit has no covariance")
    finite = [fit for fit in left_out if np.isfinite(fit.camera).all() and np.isfinite(fit.projector).all()]
    devices = []
    for device in DEVICES:
        table = np.array([getattr(fit, device) for fit in finite]).reshape(len(finite), len(INTRINSIC_NAMES))
        spreads = {name: jackknife_std(table[:, k]) for k, name in enumerate(INTRINSIC_NAMES)}
        devices.append(_device_uncertainty(stereo, covariance, device, spreads))
    return Uncertainty(
        poses=stereo.names,
        joint=stereo.joint,
        covariance=covariance,
        camera=devices[0],
        projector=devices[1],
        left_out_fits=len(finite),
    )


def _number(x: float | None) -> float | None:
    """Finite floats as they are, NaN and None as None (the report's null)."""
    return None if x is None or not math.isfinite(x) else float(x)


def _intrinsic_entry(item: IntrinsicUncertainty, poses: Sequence[str]) -> dict[str, Any]:
    return {
        "value": item.value,
        "std": _number(item.std),
        "std_reported": _number(item.std_reported),
        "leave_one_out_std": _number(item.leave_one_out_std),
        "spread_ratio": _number(item.spread_ratio),
        "agrees": item.agrees,
        "distance_correlation": _number(item.distance_correlation),
        "pose_distance_correlations": {
            pose: _number(r) for pose, r in zip(poses, item.pose_distance_correlations, strict=True)
        },
    }


def _device_entry(device: DeviceUncertainty, poses: Sequence[str]) -> dict[str, Any]:
    focal = device.focal()
    return {
        "focal_distance_correlation": _number(focal.distance_correlation),
        "focal_parameter": focal.name,
        "mean_distance_mm": _number(device.mean_distance_mm),
        "mean_distance_std_mm": _number(device.mean_distance_std_mm),
        "distance_std_mm": {pose: _number(s) for pose, s in zip(poses, device.distance_std_mm, strict=True)},
        "intrinsics": {item.name: _intrinsic_entry(item, poses) for item in device.intrinsics},
    }


def _significant(x: float) -> float | None:
    """A covariance entry to 6 significant digits (None for NaN)."""
    return float(f"{x:.6g}") if math.isfinite(x) else None


def uncertainty_report(uncertainty: Uncertainty) -> dict[str, Any]:
    """The report's ``uncertainty`` entry (docs/procam-calibration.md): the fit it comes from
    (``"joint"`` or ``"per_device"``), the limits, per device the focal length's correlation with
    the mean distance, the distances' standard deviations and per intrinsic its value, std,
    reported std, leave-one-out spread, their ratio and agreement and its distance correlations;
    the disagreements; and the full covariance (``parameters``, ``matrix`` to 6 significant digits,
    ``residual_variance``, ``residuals``). NaN is None."""
    cov = uncertainty.covariance
    poses = uncertainty.poses
    return {
        "fit": "joint" if uncertainty.joint else "per_device",
        "correlation_limit": CORRELATION_LIMIT,
        "spread_factor": SPREAD_FACTOR,
        "leave_one_out_fits": uncertainty.left_out_fits,
        "camera": _device_entry(uncertainty.camera, poses),
        "projector": _device_entry(uncertainty.projector, poses),
        "coupled": [device.device for device in uncertainty.coupled()],
        "disagreements": uncertainty.disagreements(),
        "covariance": {
            "parameters": list(cov.names),
            "matrix": [[_significant(float(x)) for x in row] for row in cov.covariance],
            "residual_variance": _number(cov.residual_variance),
            "residuals": cov.residuals,
        },
    }
