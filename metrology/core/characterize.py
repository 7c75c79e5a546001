"""Linearity and accuracy of the rig with a plane moved along Z (paper section 5).

A plane parallel to R is moved by a translation stage to positions ``Z_in``
(paper: 0..80 mm in 4 mm steps) and measured several times at each (paper: 30).
Test points are small pixel patches (default 5 x 5); each one's height is the
mean of its valid pixels. From them:

- per test point, the in-out characteristic: the line ``Z_out = slope Z_in +
  intercept`` through the per-position means (paper Fig. 12: slopes 1 +- 0.0001),
  its ``r2``, and the repeatability ``sigma_mm`` (pooled standard deviation of the
  repeats about their position mean) -- which grows towards the field edges;
- per position, the mean and standard deviation of ``dz = z - Z_in`` over all test
  points and repeats (paper Fig. 13: 12-33 um, +-37 um);
- overall, the mean and standard deviation of every ``dz``, the full scale
  (``max Z_in - min Z_in``) and the error as a percentage of full scale. The paper's
  "40 um +- 35 um, 0.06 % of FS" is read as the RMS error
  ``sqrt(mean^2 + std^2)`` over the full scale (53 um / 80 mm = 0.066 %);
  ``error_pct_fs`` follows that reading, and the mean and std shares are given too.

Test-point coordinates ``x_mm``, ``y_mm`` are those of point A on R seen by the
patch's centre (``x_A``, ``Y_A`` of docs/conventions.md): the paper chooses its test
points "on reference R", and this keeps them fixed while the plane moves
(``X_H`` would drift towards ``d`` by ``z/L`` of the distance).

The input is streamed, ``(z_in_mm, repeat_index, height_map)`` at a time, so a
full 21 x 30 series of VGA maps never needs to be in memory at once: only the
patch means are kept.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.base import GeometryModel, PlaneCoordinates
from metrology.core.geometry.crossed_axes import Rig, height_from_codes

SeriesItem = tuple[float, int, np.ndarray]


TestPoints = GeometryModel | PlaneCoordinates
"""Where test points sit: a model with a plane of its own (its :meth:`~PreparedGeometry.plane_coordinates`
without a reference, the paper's rig's R), or a prepared model's plane coordinates of a captured
reference plane."""


def plane_coordinates(where: TestPoints) -> PlaneCoordinates:
    """The :class:`PlaneCoordinates` of ``where`` (a model's own plane when given a model)."""
    if isinstance(where, PlaneCoordinates):
        return where
    return where.prepare().plane_coordinates()


def _test_point_xy(frame: PlaneCoordinates, centers: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray, float]:
    """``(x_mm, y_mm)`` of each centre, ``(n,)`` float64 each, and the field centre's x (mm)."""
    rr = np.array([r for r, _ in centers], dtype=int)
    cc = np.array([c for _, c in centers], dtype=int)
    return np.asarray(frame.x_mm, np.float64)[rr, cc], np.asarray(frame.y_mm, np.float64)[rr, cc], frame.centre_x_mm


def place_test_points(
    rig: TestPoints,
    n_points: int = 21,
    rows: int | Sequence[int] | None = None,
    margin_frac: float = 0.08,
    patch_px: int = 5,
) -> list[tuple[int, int]]:
    """Pixel centres ``(row, column)`` of the test points.

    Parameters
    ----------
    rig : Rig
    n_points : int
        Test points per row, spread evenly along X, >= 2.
    rows : int or sequence of int, optional
        None: the middle row only; an int: that many rows spread evenly over the
        central 80 % of the image; a sequence: those rows.
    margin_frac : float
        Fraction of the width left out at each side (the right edge loses its code
        at large heights: ``x_B - x_A = d z / (L - z)``), in [0, 0.5).
    patch_px : int
        Patch size, odd, >= 1 (the centres keep the whole patch inside the image).

    Returns
    -------
    list of (int, int)
        Row-major order: all points of the first row, left to right, then the next row.
    """
    if not isinstance(n_points, (int, np.integer)) or n_points < 2:
        raise ValueError(f"n_points must be an integer >= 2, got {n_points!r}")
    if not (0.0 <= margin_frac < 0.5):
        raise ValueError(f"margin_frac must lie in [0, 0.5), got {margin_frac!r}")
    _check_patch(patch_px)
    half = patch_px // 2
    h, w = rig.shape
    if rows is None:
        row_list = [h // 2]
    elif isinstance(rows, (int, np.integer)):
        if rows < 1:
            raise ValueError(f"rows must be >= 1, got {rows!r}")
        row_list = [int(r) for r in np.linspace(0.1 * h, 0.9 * h, int(rows)).round()] if rows > 1 else [h // 2]
    else:
        row_list = [int(r) for r in rows]
    for r in row_list:
        if not (half <= r < h - half):
            raise ValueError(f"test-point row {r} leaves the {patch_px}-pixel patch outside the image (height {h})")
    lo = max(half, round(margin_frac * w))
    hi = min(w - 1 - half, round((1 - margin_frac) * w) - 1)
    if hi <= lo:
        raise ValueError(f"no room for test points across {w} columns with margin {margin_frac}")
    cols = np.linspace(lo, hi, int(n_points)).round().astype(int)
    return [(r, int(c)) for r in row_list for c in cols]


def patch_means(z_mm: npt.ArrayLike, centers: Sequence[tuple[int, int]], patch_px: int = 5) -> np.ndarray:
    """Mean of the valid pixels of each square patch.

    Parameters
    ----------
    z_mm : (H, W) float array
        Height map, mm, NaN where invalid.
    centers : sequence of (row, column)
    patch_px : int
        Odd patch size.

    Returns
    -------
    means : (n_points,) float64 array, mm; NaN where a patch has no valid pixel.
    """
    z = np.asarray(z_mm)
    if z.ndim != 2:
        raise ValueError(f"z_mm must be a 2D height map, got shape {z.shape}")
    half = patch_px // 2
    c = np.asarray(centers, dtype=int).reshape(-1, 2)
    offsets = np.arange(-half, half + 1)
    rr = c[:, 0, None, None] + offsets[None, :, None]
    cc = c[:, 1, None, None] + offsets[None, None, :]
    patches = z[rr, cc].astype(np.float64).reshape(len(c), -1)
    valid = np.isfinite(patches)
    n = valid.sum(axis=1)
    total = np.where(valid, patches, 0.0).sum(axis=1)
    return np.divide(total, n, out=np.full(len(c), np.nan), where=n > 0)


def heights_from_code_series(
    rig: Rig, ref_codes: npt.ArrayLike, series: Iterable[tuple[float, int, np.ndarray]]
) -> Iterable[SeriesItem]:
    """Turn a stream of ``(z_in, repeat, codes)`` into ``(z_in, repeat, heights)`` (Eqs. 16-17)."""
    ref = np.asarray(ref_codes)
    for z_in, rep, codes in series:
        yield z_in, rep, height_from_codes(rig, ref, codes)


def characterize(
    rig: TestPoints,
    series: Iterable[SeriesItem] | Mapping[float, Sequence[np.ndarray]],
    *,
    n_points: int = 21,
    rows: int | Sequence[int] | None = None,
    patch_px: int = 5,
    margin_frac: float = 0.08,
    centers: Sequence[tuple[int, int]] | None = None,
) -> dict[str, Any]:
    """Characterize linearity and accuracy from a stage series (paper section 5).

    Parameters
    ----------
    rig : GeometryModel or PlaneCoordinates
        Where the test points sit (:data:`TestPoints`): the rig the heights were measured with,
        when it has a plane of its own, or the plane coordinates of the captured reference plane.
    series : iterable of (z_in_mm, repeat_index, z_mm), or mapping z_in_mm -> list of z_mm
        Height maps ``(height_px, width_px)`` (float, mm, NaN where invalid) of the
        plane at stage position ``z_in_mm``; consumed once, in any order.
    n_points, rows, margin_frac : see :func:`place_test_points`
        Placement of the test points (default: 21 along X at the middle row).
    patch_px : int
        Test-point patch size, odd (default 5).
    centers : sequence of (row, column), optional
        Explicit test-point centres (overrides the placement arguments).

    Returns
    -------
    dict
        JSON-serialisable::

            {"z_in_mm": [...], "mean_error_mm": [...], "std_error_mm": [...],
             "n_samples": [...],
             "test_points": [{"x_mm", "y_mm", "row_px", "column_px", "slope",
                              "intercept_mm", "r2", "sigma_mm", "mean_error_mm",
                              "n_positions"}, ...],
             "overall": {"mean_error_mm", "std_error_mm", "rms_error_mm", "full_scale_mm",
                         "error_pct_fs", "mean_error_pct_fs", "std_error_pct_fs",
                         "max_abs_mean_error_mm", "slope_min", "slope_max",
                         "max_abs_slope_deviation"},
             "edge_sigma_ratio": float, "sigma_vs_x": {"x_mm": [...], "sigma_mm": [...]},
             "patch_px": int, "repeats": int}

        Lists over ``z_in_mm`` are in ascending order. ``std`` values use ddof = 1.
        ``edge_sigma_ratio`` is the mean repeatability of the outer fifth of the test
        points (by distance from the field centre) over that of the central fifth.

    Raises
    ------
    ValueError
        For a map of the wrong shape, fewer than two stage positions or bad arguments.
    """
    _check_patch(patch_px)
    frame = plane_coordinates(rig)
    if centers is None:
        centers = place_test_points(frame, n_points, rows, margin_frac, patch_px)
    else:
        centers = [(int(r), int(c)) for r, c in centers]
        half = patch_px // 2
        for r, c in centers:
            if not (half <= r < frame.height_px - half and half <= c < frame.width_px - half):
                raise ValueError(f"test-point centre {(r, c)} puts its patch outside the image {frame.shape}")
    if isinstance(series, Mapping):
        series = ((z, i, m) for z, maps in series.items() for i, m in enumerate(maps))

    samples: dict[float, list[np.ndarray]] = {}
    for item in series:
        try:
            z_pos, _rep, z_map = item
        except (TypeError, ValueError) as exc:
            raise ValueError("series items must be (z_in_mm, repeat_index, height_map) triples") from exc
        z_map = np.asarray(z_map)
        if z_map.shape != frame.shape:
            raise ValueError(f"height map at z_in = {z_pos} mm has shape {z_map.shape}, expected {frame.shape}")
        if not math.isfinite(float(z_pos)):
            raise ValueError(f"z_in_mm must be finite, got {z_pos!r}")
        samples.setdefault(float(z_pos), []).append(patch_means(z_map, centers, patch_px))
    if len(samples) < 2:
        raise ValueError(f"characterization needs at least two stage positions, got {len(samples)}")

    z_in = np.array(sorted(samples))
    n_tp = len(centers)
    # per position: (repeats, n_tp) patch means
    per_pos = [np.vstack(samples[z]) for z in z_in]
    repeats = max(p.shape[0] for p in per_pos)

    mean_err, std_err, n_samp = [], [], []
    all_dz = []
    for z, p in zip(z_in, per_pos, strict=True):
        dz = (p - z).ravel()
        dz = dz[np.isfinite(dz)]
        all_dz.append(dz)
        mean_err.append(float(dz.mean()) if dz.size else math.nan)
        std_err.append(float(dz.std(ddof=1)) if dz.size > 1 else math.nan)
        n_samp.append(int(dz.size))

    # per test point: position means, line fit, repeatability
    z_out = np.full((len(z_in), n_tp), np.nan)
    ss_within = np.zeros(n_tp)
    dof_within = np.zeros(n_tp)
    for i, p in enumerate(per_pos):
        valid = np.isfinite(p)
        cnt = valid.sum(axis=0)
        tot = np.where(valid, p, 0.0).sum(axis=0)
        mean = np.divide(tot, cnt, out=np.full(n_tp, np.nan), where=cnt > 0)
        z_out[i] = mean
        dev = np.where(valid, p - mean[None, :], 0.0)
        ss_within += (dev**2).sum(axis=0)
        dof_within += np.maximum(cnt - 1, 0)
    sigma_tp = np.divide(np.sqrt(ss_within), np.sqrt(dof_within), out=np.full(n_tp, np.nan), where=dof_within > 0)

    x_tp, y_tp, centre_x = _test_point_xy(frame, centers)
    points = []
    slopes = []
    for t, (r, c) in enumerate(centers):
        ok = np.isfinite(z_out[:, t])
        entry: dict[str, Any] = {
            "x_mm": float(x_tp[t]),
            "y_mm": float(y_tp[t]),
            "row_px": r,
            "column_px": c,
            "n_positions": int(ok.sum()),
            "sigma_mm": _num(sigma_tp[t]),
        }
        if ok.sum() >= 2 and np.ptp(z_in[ok]) > 0:
            slope, intercept = np.polyfit(z_in[ok], z_out[ok, t], 1)
            pred = slope * z_in[ok] + intercept
            ss_res = float(np.sum((z_out[ok, t] - pred) ** 2))
            ss_tot = float(np.sum((z_out[ok, t] - z_out[ok, t].mean()) ** 2))
            entry.update(
                slope=float(slope),
                intercept_mm=float(intercept),
                r2=1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan,
                mean_error_mm=float(np.mean(z_out[ok, t] - z_in[ok])),
            )
            slopes.append(float(slope))
        else:
            entry.update(slope=None, intercept_mm=None, r2=None, mean_error_mm=None)
        points.append({k: _num(v) if isinstance(v, float) else v for k, v in entry.items()})

    dz_all = np.concatenate(all_dz)
    full_scale = float(z_in.max() - z_in.min())
    mean_all = float(dz_all.mean()) if dz_all.size else math.nan
    std_all = float(dz_all.std(ddof=1)) if dz_all.size > 1 else math.nan
    rms_all = math.sqrt(mean_all**2 + std_all**2)
    slopes_arr = np.array(slopes) if slopes else np.array([math.nan])

    dist = np.abs(x_tp - centre_x)
    order = np.argsort(dist)
    fifth = max(1, n_tp // 5)
    inner_mean = _finite_mean(sigma_tp[order[:fifth]])
    outer_mean = _finite_mean(sigma_tp[order[-fifth:]])
    edge_ratio = outer_mean / inner_mean if inner_mean > 0 else math.nan

    return {
        "z_in_mm": z_in.tolist(),
        "mean_error_mm": [_num(v) for v in mean_err],
        "std_error_mm": [_num(v) for v in std_err],
        "n_samples": n_samp,
        "test_points": points,
        "overall": {
            "mean_error_mm": _num(mean_all),
            "std_error_mm": _num(std_all),
            "rms_error_mm": _num(rms_all),
            "full_scale_mm": full_scale,
            "error_pct_fs": _num(100 * rms_all / full_scale) if full_scale > 0 else None,
            "mean_error_pct_fs": _num(100 * abs(mean_all) / full_scale) if full_scale > 0 else None,
            "std_error_pct_fs": _num(100 * std_all / full_scale) if full_scale > 0 else None,
            "max_abs_mean_error_mm": _num(_finite_max(np.abs(np.array(mean_err)))),
            "slope_min": _num(-_finite_max(-slopes_arr)),
            "slope_max": _num(_finite_max(slopes_arr)),
            "max_abs_slope_deviation": _num(_finite_max(np.abs(slopes_arr - 1))),
        },
        "edge_sigma_ratio": _num(edge_ratio),
        "sigma_vs_x": {"x_mm": [p["x_mm"] for p in points], "sigma_mm": [p["sigma_mm"] for p in points]},
        "patch_px": patch_px,
        "repeats": repeats,
    }


def _finite_max(values: np.ndarray) -> float:
    ok = np.isfinite(values)
    return float(values[ok].max()) if ok.any() else math.nan


def _finite_mean(values: np.ndarray) -> float:
    ok = np.isfinite(values)
    return float(values[ok].mean()) if ok.any() else math.nan


def _num(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _check_patch(patch_px: int) -> None:
    if not isinstance(patch_px, (int, np.integer)) or patch_px < 1 or patch_px % 2 == 0:
        raise ValueError(f"patch_px must be an odd positive integer, got {patch_px!r}")
