"""The numpy twins of the pinhole model's compiled tile kernels (``pinhole_numpy`` against
``pinhole_kernels``): the same float32 outputs, within float64 rounding, on random inputs and on
the edges (NaN, guard cells, lines not tabulated, ``t <= 0``), and the rule that chooses them."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core import kernel_choice
from metrology.core.geometry import pinhole_kernels, pinhole_numpy
from metrology.core.geometry.base import triangulate_frame
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, cast_truth

F32_ULP = 2.0**-23
"""A float32 ulp relative to the value: the two implementations round the same float64 result
(up to the compiled code's fused multiply-adds) to float32, so they differ by at most one."""


def _close(new: np.ndarray, old: np.ndarray, atol: float = 0.0) -> None:
    """``new`` equals ``old`` (NaN where ``old`` is NaN) within one float32 ulp of the value or ``atol``;
    nearly always to the bit (at least 99.9 %)."""
    np.testing.assert_array_equal(np.isnan(new), np.isnan(old))
    fin = np.isfinite(old)
    a, b = new[fin].astype(np.float64), old[fin].astype(np.float64)
    np.testing.assert_array_less(np.abs(a - b), np.maximum(np.abs(b) * F32_ULP * 1.01, atol) + 1e-300)
    assert a.size == 0 or np.mean(a == b) >= 0.999


def _table(rng: np.random.Generator, n_planes: int, n_lines: int = 5, n_cols: int = 40) -> np.ndarray:
    """Float32 coefficient planes ``(n_planes, n_lines n_cols)`` of the magnitudes of a real table."""
    planes = (
        rng.normal(0.0, 1.0, (n_planes, n_lines * n_cols))
        * np.array([0.5, 0.02, 1e-3, 1e-4, 1e-2, 1e-3, 1e-5][:n_planes])[:, None]
    )
    return planes.astype(np.float32)


def _run_table(
    module: object, coded: np.ndarray, base: np.ndarray, frac: np.ndarray, planes: np.ndarray, want_dq: bool
):
    g0, inv_h, n_cols = -2.0, 0.25, 40
    q = np.full(coded.size, -7.0, np.float32)
    dq = np.full(coded.size if want_dq else 0, -7.0, np.float32)
    module.table_tile(coded, base, frac, planes, g0, inv_h, n_cols, q, dq, want_dq)  # type: ignore[attr-defined]
    return q, dq


@pytest.mark.parametrize("n_planes", [6, 7])
@pytest.mark.parametrize("want_dq", [False, True])
def test_table_tile_equals_the_compiled_one(n_planes: int, want_dq: bool) -> None:
    rng = np.random.default_rng(n_planes)
    planes = _table(rng, n_planes)
    n = 20000
    # coded coordinates across the row and beyond it on both sides (the guard cells, the clamp)
    coded = rng.uniform(-20.0, 180.0, n).astype(np.float32)
    base = (rng.integers(0, 4, n) * 40).astype(np.int32)
    frac = rng.uniform(0.0, 1.0, n).astype(np.float32)
    coded[:50] = np.nan  # not decoded
    frac[50:100] = np.nan  # its line not tabulated
    coded[100:110] = np.array([-2.0, -1.999, 0.0, 157.99, 158.0, 158.001, 1e9, -1e9, np.inf, -np.inf])
    base[110:120] = 4 * 40  # the last row: the clamp of the flat index
    coded[110:120] = 200.0
    new = _run_table(pinhole_numpy, coded, base, frac, planes, want_dq)
    old = _run_table(pinhole_kernels, coded, base, frac, planes, want_dq)
    _close(new[0], old[0], atol=1e-12)
    if want_dq:
        _close(new[1], old[1], atol=1e-12)
    else:
        assert new[1].size == old[1].size == 0
    assert np.isnan(old[0][:100]).all() and np.isfinite(old[0][100:109]).all()


@pytest.mark.parametrize("axis_u", [True, False])
def test_grid_tile_equals_the_compiled_one(axis_u: bool) -> None:
    rng = np.random.default_rng(3)
    planes = _table(rng, 7)
    n = 20000
    coded = rng.uniform(-20.0, 180.0, n).astype(np.float32)
    other = rng.uniform(-3.0, 30.0, n).astype(np.float32)  # beyond the table's lines on both sides
    coded[:40], other[40:80] = np.nan, np.nan
    other[80:90] = np.array([0.0, 1e-7, 7.0, 8.0, 7.9999, 8.0001, 1e9, -1e9, np.inf, -np.inf])
    args = (planes, -2.0, 0.25, 40, 0.5, 0.5, 5, axis_u, 1500.5, 0.3, 640.2, 1499.8, 400.1)
    out = {}
    for module in (pinhole_numpy, pinhole_kernels):
        q = np.full(n, -7.0, np.float32)
        dq = np.full(n, -7.0, np.float32)
        module.grid_tile(coded, other, *args, q, dq, True)  # type: ignore[attr-defined]
        out[module.__name__] = q, dq
    (q_new, dq_new), (q_old, dq_old) = out.values()
    _close(q_new, q_old, atol=1e-12)
    _close(dq_new, dq_old, atol=1e-12)
    assert np.isnan(q_old[:80]).all() and np.isfinite(q_old[80:88]).all()


@pytest.mark.parametrize("want_sigma", [False, True])
@pytest.mark.parametrize("want_points", [False, True])
def test_plane_tile_equals_the_compiled_one(want_sigma: bool, want_points: bool) -> None:
    rng = np.random.default_rng(4)
    n = 20000
    f32 = np.float32
    tz, ti = 18.25, -210.12
    q = rng.uniform(-0.6, 0.6, n).astype(f32)
    dq = rng.uniform(5e-4, 8e-4, n).astype(f32)
    rdi = rng.uniform(0.5, 0.9, n).astype(f32)
    rdz = rng.uniform(0.2, 0.5, n).astype(f32)
    xn, yn = rng.uniform(-0.4, 0.4, n).astype(f32), rng.uniform(-0.3, 0.3, n).astype(f32)
    norm_d = np.sqrt(xn * xn + yn * yn + 1).astype(f32)
    sigma_in = rng.uniform(0.01, 0.1, n).astype(f32)
    q[:30] = np.nan
    q[30:40] = rdi[30:40] / rdz[30:40]  # den about 0: t huge, of either sign
    q[40:50], rdi[40:50], rdz[40:50] = 5.0, 0.6, 0.45  # t < 0: behind the camera, NaN
    q[50:60] = ti / tz  # t = 0 where num = q T_z - T_i rounds to 0: NaN
    empty = np.empty(0, f32)
    out = {}
    for module in (pinhole_numpy, pinhole_kernels):
        t = np.full(n, -7.0, f32)
        sigma = np.full(n if want_sigma else 0, -7.0, f32)
        points = np.full(3 * n if want_points else 0, -7.0, f32)
        module.plane_tile(  # type: ignore[attr-defined]
            q,
            dq if want_sigma else empty,
            rdi,
            rdz,
            tz,
            ti,
            norm_d,
            sigma_in if want_sigma else empty,
            sigma,
            want_sigma,
            xn,
            yn,
            points,
            want_points,
            t,
        )
        out[module.__name__] = t, sigma, points
    new, old = out.values()
    for a, b in zip(new, old, strict=True):
        _close(a, b)
    assert np.isnan(old[0][:30]).all() and np.isnan(old[0][40:60]).all() and (old[0][60:] > 0).all()
    if want_points:
        np.testing.assert_array_equal(old[2][2::3], old[0])


def _issue22_like_rig():
    camera = PinholeCamera(
        320, 256, ((575.0, 0.0, 159.5), (0.0, 575.0, 127.5), (0.0, 0.0, 1.0)), (-0.28, 0.12, 0.001, -0.0008, -0.03)
    )
    projector = PinholeProjector(
        480, 270, ((700.0, 0.0, 240.2), (0.0, 700.0, 135.1), (0.0, 0.0, 1.0)), (0.09, -0.06, 0.0004, 0.0003, 0.01)
    )
    return look_at_rig(camera, projector, (-210.0, -5.5, 18.0), (0.0, 0.0, 740.0))


@pytest.mark.parametrize("both_axes", [False, True])
def test_frames_triangulated_by_either_implementation_agree(monkeypatch: pytest.MonkeyPatch, both_axes: bool) -> None:
    """A whole frame through a strongly distorted projector, sigma and points: the same numbers from
    both implementations (points within 1e-6 mm or a float32 ulp), and both within 1 um of the truth."""
    rig = _issue22_like_rig()
    prep = rig.prepare(rig.shape, (480, 270))
    truth = cast_truth(prep, make_scene("sphere"), ScenePlacement.facing_camera(740.0))
    u = truth.u.astype(np.float32)
    v = truth.v.astype(np.float32) if both_axes else None
    if both_axes:
        prep.used_axes(("u", "v"))
    sigma_u = np.full(u.shape, 0.02, np.float32)
    results = {}
    for compiled in (False, True):
        monkeypatch.setattr(kernel_choice, "COMPILED", compiled)
        assert (pinhole_numpy.tile_kernels(1) is pinhole_kernels) is compiled
        results[compiled] = triangulate_frame(prep, u, v, heights=False, sigma=sigma_u)
    new, old = results[False], results[True]
    assert new.points_mm is not None and old.points_mm is not None
    assert new.sigma_mm is not None and old.sigma_mm is not None
    _close(new.points_mm, old.points_mm, atol=1e-6)
    _close(new.sigma_mm, old.sigma_mm)
    lit = np.isfinite(old.points_mm[..., 2])
    assert lit.mean() > 0.3
    assert np.nanmax(np.abs(new.points_mm[lit] - truth.points_mm[lit])) < 1e-3


def test_the_rule_is_the_decoders_rule(monkeypatch: pytest.MonkeyPatch) -> None:
    """Numpy's twins in a process without numba, the compiled kernels where numba is loaded or a
    frame is large (:func:`metrology.core.kernel_choice.use_compiled`, the decoders' rule too)."""
    import sys

    monkeypatch.setattr(kernel_choice, "COMPILED", None)
    assert "numba" in sys.modules  # this module imported the compiled kernels
    assert pinhole_numpy.tile_kernels(100) is pinhole_kernels
    monkeypatch.delitem(sys.modules, "numba")
    assert pinhole_numpy.tile_kernels(100) is pinhole_numpy
    assert pinhole_numpy.tile_kernels(kernel_choice.COMPILED_MIN_PX) is pinhole_kernels
