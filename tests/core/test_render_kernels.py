"""The virtual rig's compiled kernels (metrology/core/simulate/kernels.py) and the FFT blur of its
pattern tables give the numpy passes' numbers: bit for bit, or to float64 rounding where stated."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.scenes import SphereScene, TwoSpheresScene
from metrology.core.simulate.cast import ScenePlacement, cast_truth
from metrology.core.simulate.kernels import interp_uniform, lit_intensity, sine_intensity, slab_interval
from metrology.core.simulate.options import blur_line


@dataclass(frozen=True, kw_only=True)
class UnboxedSpheres(TwoSpheresScene):
    """Two spheres that declare no footprint boxes: every ray is marched against the height field."""

    @property
    def footprints_mm(self) -> tuple[tuple[float, float, float, float], ...]:
        return ()


@dataclass(frozen=True, kw_only=True)
class UnboxedSphere(SphereScene):
    @property
    def footprints_mm(self) -> tuple[tuple[float, float, float, float], ...]:
        return ()


CAMERA = PinholeCamera(
    96, 72, ((120.0, 0.0, 47.3), (0.0, 121.0, 35.8), (0.0, 0.0, 1.0)), (-0.1, 0.04, 0.0005, -0.0003, 0.0)
)
PROJECTOR = PinholeProjector(
    320, 200, ((400.0, 0.0, 160.2), (0.0, 401.0, 99.7), (0.0, 0.0, 1.0)), (0.03, -0.01, 0.0, 0.0, 0.0)
)
RIG = look_at_rig(CAMERA, PROJECTOR, (-150.0, 10.0, 5.0), (0.0, 0.0, 500.0))


@pytest.mark.parametrize(
    ("boxed", "unboxed"),
    [
        (SphereScene(radius_mm=40.0), UnboxedSphere(radius_mm=40.0)),
        (TwoSpheresScene(radius_mm=30.0, spacing_mm=120.0), UnboxedSpheres(radius_mm=30.0, spacing_mm=120.0)),
    ],
)
@pytest.mark.parametrize("supersample", [1, 2])
def test_rays_beside_the_footprints_hit_the_plane_where_the_full_march_does(boxed, unboxed, supersample) -> None:
    """Rays whose trace misses the footprint boxes take the compiled plane search (closed-form march,
    bisections stopped when the bracket is fixed); marched against the height field everywhere
    (a scene without boxes), every ray's hit, height and projector coordinates are the same bits."""
    prepared = RIG.prepare(RIG.shape, (PROJECTOR.width, PROJECTOR.height))
    placement = ScenePlacement.facing_camera(500.0)
    fast = cast_truth(prepared, boxed, placement, supersample=supersample)
    full = cast_truth(prepared, unboxed, placement, supersample=supersample)
    assert np.isfinite(fast.height_mm).all()
    on_object = fast.height_mm > 0
    assert 0.02 < on_object.mean() < 0.5  # both kinds of rays are there
    for name in ("points_mm", "height_mm", "u", "v"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(full, name), err_msg=name)


def test_interp_uniform_is_numpys_interp_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    lo, step, n = -13.37, 1.0 / 64.0, 5000
    table = gaussian_filter1d((np.arange(n) // 700 % 2).astype(np.float64), 20.0)
    grid = lo + np.arange(n) * step
    x = np.concatenate(
        [
            rng.uniform(lo - 1.0, lo + (n + 60) * step, 200_000),
            grid,  # the grid values themselves, as numpy computes them
            np.nextafter(grid, -np.inf),
            np.nextafter(grid, np.inf),
            [lo, grid[-1], np.nan, -np.inf, np.inf],
        ]
    )
    out = np.empty_like(x)
    interp_uniform(x, lo, step, table, out)
    np.testing.assert_array_equal(out, np.interp(x, grid, table))


def test_lit_intensity_is_the_scatter_of_the_numpy_passes() -> None:
    rng = np.random.default_rng(6)
    base = rng.uniform(0.0, 0.1, 10_000)
    index = np.flatnonzero(rng.random(base.size) < 0.7)
    gain, emitted = rng.uniform(0.0, 0.9, index.size), rng.uniform(0.0, 1.0, index.size)
    out = np.empty_like(base)
    lit_intensity(base, index, gain, emitted, out)
    expected = base.copy()
    expected[index] += gain * emitted
    np.testing.assert_array_equal(out, expected)


def test_sine_intensity_is_the_direct_cosine_to_rounding() -> None:
    """``offset + A cos(a + p)`` from ``cos a`` and ``sin a``: within ``A ulp(a)`` (the rounding of the
    direct cosine's own argument ``a + p``) plus 4e-16 of the direct cosine."""
    rng = np.random.default_rng(7)
    angle = rng.uniform(-50.0, 400.0, 20_000)
    index = np.arange(angle.size)
    base, gain = np.zeros(angle.size), np.ones(angle.size)
    for p in 2 * np.pi * np.arange(8) / 8:
        out = np.empty_like(angle)
        sine_intensity(base, index, gain, np.cos(angle), np.sin(angle), 0.5, 0.45 * np.cos(p), 0.45 * np.sin(p), out)
        bound = 0.45 * np.spacing(np.abs(angle) + p) + 4e-16
        assert (np.abs(out - (0.5 + 0.45 * np.cos(angle + p))) <= bound).all()


@pytest.mark.parametrize(
    ("sigma", "truncate", "mode"), [(76.8, 6.0, "nearest"), (38.4, 8.0, "constant"), (3.0, 6.0, "nearest")]
)
def test_blur_line_is_scipys_gaussian_filter_to_rounding(sigma, truncate, mode) -> None:
    """A stepped pattern (cell means of 0/1 steps), blurred by FFT beyond 129 taps: within 2e-15 of
    scipy's direct sum (the bits themselves below that)."""
    n = 40_000
    line = (np.arange(n) // 1000 % 2).astype(np.float64)
    line[999::1000] = 0.375
    expected = gaussian_filter1d(line, sigma, mode=mode, cval=0.0, truncate=truncate)
    got = blur_line(line, sigma, truncate, mode)
    if 2 * int(truncate * sigma + 0.5) + 1 <= 129:
        np.testing.assert_array_equal(got, expected)
    else:
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-15)


def test_slab_interval_is_the_slab_test_of_numpy() -> None:
    """Per axis ``[a / p, b / p]`` sorted (every s or none where ``p == 0``), intersected: the bits of
    the numpy passes it replaced, on rays of every direction, axis-parallel ones and boxes holding 0."""
    rng = np.random.default_rng(8)
    px = np.concatenate([rng.uniform(-300.0, 300.0, 5000), np.zeros(50), [np.nan, 1.0]])
    py = np.concatenate([rng.uniform(-200.0, 200.0, 5000), rng.uniform(-5.0, 5.0, 50), [1.0, np.nan]])
    py[:100] = 0.0
    for box in ((-40.0, 90.0, -30.0, 25.0), (10.0, 90.0, 5.0, 25.0), (-90.0, -10.0, -25.0, 0.0)):
        lo, hi = np.full(px.shape, -np.inf), np.full(px.shape, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for p, a, b in ((px, box[0], box[1]), (py, box[2], box[3])):
                nz = p != 0.0
                first, last = np.minimum(a / p, b / p), np.maximum(a / p, b / p)
                inside = a <= 0.0 <= b
                np.maximum(lo, np.where(nz, first, -np.inf if inside else np.inf), out=lo)
                np.minimum(hi, np.where(nz, last, np.inf if inside else -np.inf), out=hi)
        got_lo, got_hi = np.empty_like(px), np.empty_like(px)
        slab_interval(px, py, *box, got_lo, got_hi)
        np.testing.assert_array_equal(got_lo, lo)
        np.testing.assert_array_equal(got_hi, hi)
        assert ((got_lo <= got_hi) == (lo <= hi)).all()


def test_sample_light_is_the_code_samplers_interpolation_scaled() -> None:
    """``ambient + signal * E``, ``E`` the table interpolated at the codes' cells: the bits of
    :class:`_CodeSampler`'s passes (codes beyond both ends of the table included)."""
    from metrology.core.simulate.paper_rig import CODE_GRID_STEP, _CodeSampler

    rng = np.random.default_rng(9)
    codes = rng.uniform(-3.0, 131.0, (60, 80))
    codes[0, :5] = np.nan
    pad = 2.0
    table = gaussian_filter1d((np.arange(round((128 + 2 * pad) / CODE_GRID_STEP) + 1) // 300 % 2).astype(float), 9.0)
    signal, ambient = rng.uniform(0.0, 0.8, codes.shape), rng.uniform(0.0, 0.05, codes.shape)
    sampler = _CodeSampler(codes, pad)
    np.testing.assert_array_equal(sampler.light(table, signal, ambient), ambient + signal * sampler.sample(table))


def test_the_first_float_below_the_plane_is_where_the_bisections_end() -> None:
    """The plane rays' bisections replaced by ulp steps from the crossing: the same float on random
    brackets, brackets of a few ulps and crossings at powers of two (where the ulp doubles)."""
    from metrology.core.simulate.kernels import _bisect_plane, _first_below

    rng = np.random.default_rng(10)
    n = 20_000
    slope = -rng.uniform(1e-3, 1.0, n)
    root = np.where(
        rng.random(n) < 0.5,
        rng.uniform(1.0, 3000.0, n),
        2.0 ** rng.integers(-3, 12, n) * (1 + rng.integers(-40, 40, n) * 2.0**-52),
    )
    s_origin = -root * slope
    width = root * 10.0 ** rng.uniform(-15.0, -0.5, n)
    below = rng.random(n)
    for a, b, s, r in zip(root - width * below, root + width * (1 - below), s_origin, slope, strict=True):
        if a < b:
            assert _first_below(a, b, s, r, 60) == _bisect_plane(a, b, s, r, 60)


def numpy_board_truth(rig, board, pose, supersample):  # type: ignore[no-untyped-def]
    """The numpy passes that :func:`metrology.core.simulate.kernels.board_pixels` replaced in
    :func:`metrology.core.procam.virtual.board_truth` (the reference of its bits)."""
    from metrology.core.distortion import project_normalized
    from metrology.core.procam.virtual import DARK_ALBEDO, LIGHT_ALBEDO, board_hits

    s = int(supersample)
    t, Xb, Xp = board_hits(rig, pose, s)
    fp = np.abs(t) / (float(np.asarray(rig.camera.K)[0, 0]) * s)
    sq = board.size_mm
    k, m = np.round(Xb[..., 0] / sq), np.round(Xb[..., 1] / sq)
    with np.errstate(invalid="ignore"):
        even = (k + m) % 2 == 0
        column = [(k - i >= -1) & (k - i <= board.cols - 1) for i in (0, 1)]
        row = [(m - j >= -1) & (m - j <= board.rows - 1) for j in (0, 1)]

    def dark(i: int, j: int) -> np.ndarray:
        return (column[i] & row[j] & (even if (i + j) % 2 == 0 else ~even)).astype(np.float64)

    with np.errstate(invalid="ignore"):
        a = np.clip(0.5 + (Xb[..., 0] - k * sq) / fp, 0.0, 1.0)
        b = np.clip(0.5 + (Xb[..., 1] - m * sq) / fp, 0.0, 1.0)
    fraction = a * b * dark(0, 0) + a * (1 - b) * dark(0, 1) + (1 - a) * b * dark(1, 0) + (1 - a) * (1 - b) * dark(1, 1)
    albedo = LIGHT_ALBEDO + (DARK_ALBEDO - LIGHT_ALBEDO) * fraction
    front = (t > 0) & (Xp[..., 2] > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        u, v = project_normalized(
            np.asarray(rig.projector.K), rig.projector.distortion, Xp[..., 0] / Xp[..., 2], Xp[..., 1] / Xp[..., 2]
        )
    return np.where(front, u, np.nan), np.where(front, v, np.nan), albedo


@pytest.mark.parametrize(
    "dist",
    [
        (0.03, -0.01, 0.0, 0.0, 0.0),
        (0.03, -0.01, 0.001, -0.002, 0.004, 0.01, -0.003, 0.002),  # rational
        (0.03, -0.01, 0.001, -0.002, 0.004, 0.0, 0.0, 0.0, 1e-3, -2e-4, 3e-4, 1e-4, 0.01, -0.02),  # tilted
    ],
)
@pytest.mark.parametrize("supersample", [1, 2])
def test_board_truth_is_the_numpy_passes_bit_for_bit(dist, supersample) -> None:
    """The compiled chessboard pass gives the numpy passes' ``u``, ``v`` and albedo, NaN where they
    have it: a board in view (squares, its edge and the light plane around it), one seen at a grazing
    angle (sub-rays far beyond the board, some hitting its plane behind the camera or the projector)."""
    from metrology.core.procam import parse_board
    from metrology.core.procam.virtual import BoardPose, board_truth

    board = parse_board("chessboard:9x6:20")
    rig = look_at_rig(CAMERA, PinholeProjector(320, 200, PROJECTOR.K, dist), (-150.0, 10.0, 5.0), (0.0, 0.0, 500.0))
    poses = [BoardPose.from_angles(10.0, -15.0, 20.0, (0.0, 0.0, 500.0)).centred(board)]
    poses.append(BoardPose.from_angles(86.0, 10.0, 5.0, (0.0, 0.0, 300.0)).centred(board))
    seen = []
    for pose in poses:
        got, expected = board_truth(rig, board, pose, supersample), numpy_board_truth(rig, board, pose, supersample)
        for name, a, b in zip(("u", "v", "albedo"), got, expected, strict=True):
            np.testing.assert_array_equal(a, b, err_msg=name)
        seen.append((np.isnan(got[0]).mean(), np.unique(np.round(got[2], 6)).size))
    (nan_in_view, shades), (nan_grazing, _) = seen
    assert nan_in_view == 0 and shades > 10  # light, dark and anti-aliased edges
    assert 0.05 < nan_grazing < 0.95, nan_grazing  # both kinds of sub-rays
