"""Conformance decisions with measurement uncertainty (ISO 14253-1: a verdict is given only when
the uncertainty interval lies wholly inside or wholly outside the tolerance).

Each point's standard uncertainty along the nominal's normal combines three independent terms:

``u = sqrt(u_point^2 + u_alignment^2 + u_systematic^2)``

- ``u_point``: the point's own standard uncertainty along the normal. A sigma given for every
  direction (a PLY vertex's ``sigma_mm``) is used as is; a sigma along the camera ray (the
  ``(H, W)`` sigma of ``gcps measure``) is projected: ``u_point = sigma |cos(theta)|``, ``theta``
  the angle between the ray (from the scan frame's origin to the point) and the surface normal
  (:func:`point_uncertainty`); without a sigma it is 0;
- ``u_alignment``: the best fit's uncertainty at that point along the normal
  (:meth:`metrology.core.inspection.alignment.FitResult.normal_uncertainty_mm`);
- ``u_systematic``: the rig's systematic term (from its acceptance or characterization, or set
  by the user), the same for every point.

With a tolerance ``T`` (mm, the allowed ``|deviation|``) and a coverage factor ``k`` (default 2) a
point *conforms* when ``|dev| + k u <= T``, *does not conform* when ``|dev| - k u > T``, and is
*undecided* otherwise (also when ``u`` is unknown, NaN).
"""

from __future__ import annotations

import numpy as np

CONFORMING, UNDECIDED, NONCONFORMING = 1, 0, -1
"""Decision codes of :func:`decide`."""


def point_uncertainty(
    sigma_mm: np.ndarray | None,
    normals: np.ndarray,
    *,
    rays: np.ndarray | None = None,
) -> np.ndarray:
    """``(N,)`` float64: each point's standard uncertainty along the surface normal, mm.

    Parameters
    ----------
    sigma_mm : (N,) array or None
        The points' sigma, mm (None: 0 for every point).
    normals : (N, 3) float64
        Unit normals, in the same frame as ``rays``.
    rays : (N, 3) array or None
        Directions of the camera rays through the points (any length; the scan frame's origin to
        the point); given: ``sigma`` is along the ray and is projected, ``sigma |cos(theta)|``.
    """
    if sigma_mm is None:
        return np.zeros(normals.shape[0])
    sigma = np.asarray(sigma_mm, dtype=np.float64).reshape(-1)
    if rays is None:
        return sigma
    length = np.linalg.norm(rays, axis=1)
    cosine = np.abs(np.einsum("ij,ij->i", rays, normals)) / np.where(length > 0, length, 1.0)
    return sigma * cosine


def combined_uncertainty(u_point: np.ndarray, u_alignment: np.ndarray, systematic_mm: float) -> np.ndarray:
    """``sqrt(u_point^2 + u_alignment^2 + systematic^2)``, mm (module docstring)."""
    return np.sqrt(np.square(u_point) + np.square(u_alignment) + float(systematic_mm) ** 2)


def decide(deviation_mm: np.ndarray, u_mm: np.ndarray, tolerance_mm: float, k: float = 2.0) -> np.ndarray:
    """``(N,)`` int8 decisions: :data:`CONFORMING` when ``|dev| + k u <= T``, :data:`NONCONFORMING`
    when ``|dev| - k u > T``, :data:`UNDECIDED` otherwise (NaN deviation or uncertainty included)."""
    if not tolerance_mm > 0 or not k >= 0:
        raise ValueError(f"tolerance must be > 0 and k >= 0, got {tolerance_mm!r} and {k!r}")
    size = np.abs(np.asarray(deviation_mm, dtype=np.float64))
    margin = k * np.asarray(u_mm, dtype=np.float64)
    decision = np.full(size.shape, UNDECIDED, np.int8)
    decision[size + margin <= tolerance_mm] = CONFORMING
    decision[size - margin > tolerance_mm] = NONCONFORMING
    return decision


def counts(decision: np.ndarray) -> dict[str, int]:
    """``{"conforming", "nonconforming", "undecided"}`` integer counts of :func:`decide`'s codes."""
    return {
        "conforming": int(np.count_nonzero(decision == CONFORMING)),
        "nonconforming": int(np.count_nonzero(decision == NONCONFORMING)),
        "undecided": int(np.count_nonzero(decision == UNDECIDED)),
    }
