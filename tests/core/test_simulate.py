"""The virtual rig against analytic physics: first hits, shadows, field limits, radiometry, seeds."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import PAPER_RIG, Rig, codes_from_abscissa, points_from_heights
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity
from metrology.core.scenes import SCENES, StageScene, make_scene
from metrology.core.simulate import (
    RenderedStack,
    SimulationOptions,
    emitted_pattern,
    realistic_8bit,
    render_series,
    render_stack,
    series_seed,
    stage_positions,
)

# The paper's geometry at a quarter of the resolution (3.125 mm pixels): fast tests.
SMALL = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=160, height_px=120)


def _hit_points(rig: Rig, stack: RenderedStack) -> np.ndarray:
    return points_from_heights(rig, stack.hit_mm)


def _box_first_hit(rig: Rig, box: tuple[float, float, float, float, float]) -> np.ndarray:
    """Analytic first hit of the pixel-centre rays with a box standing on R (slab method)."""
    x0, x1, y0, y1, top = box
    xa, ya = np.meshgrid(rig.column_x_mm(), rig.row_y_mm())
    C = np.array([rig.d_mm, 0.0, rig.L_mm])
    D = np.stack([xa - rig.d_mm, ya, np.full(xa.shape, -rig.L_mm)], axis=-1)
    lo, hi = np.zeros(xa.shape), np.ones(xa.shape)
    for axis, (a, b) in enumerate(((x0, x1), (y0, y1), (0.0, top))):
        with np.errstate(divide="ignore"):
            ta, tb = (a - C[axis]) / D[..., axis], (b - C[axis]) / D[..., axis]
        lo, hi = np.maximum(lo, np.minimum(ta, tb)), np.minimum(hi, np.maximum(ta, tb))
    t = np.where(lo <= hi, lo, 1.0)
    return rig.L_mm * (1.0 - t)


# --------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("z_mm", [0.0, 12.5, 40.0, -5.0])
def test_plane_truth_is_exact(z_mm: float) -> None:
    stack = render_stack(SMALL, make_scene("plane", z_mm=z_mm))
    valid = np.isfinite(stack.truth_mm)
    assert valid.mean() > 0.95
    assert np.all(stack.truth_mm[valid] == np.float32(z_mm))
    assert np.array_equal(valid, stack.lit)


def test_block_truth_matches_ray_box_intersection() -> None:
    block = make_scene("block")
    stack = render_stack(SMALL, block)
    expected = _box_first_hit(SMALL, (*block.x_range_mm, *block.y_range_mm, block.top_mm))
    np.testing.assert_allclose(stack.hit_mm, expected, atol=1e-6)
    top = stack.hit_mm == block.top_mm
    assert top.sum() > 1000  # the top face is exact, not merely close


def test_block_shadow_falls_beside_its_far_side() -> None:
    block = make_scene("block")
    stack = render_stack(SMALL, block)
    xyz = _hit_points(SMALL, stack)
    in_field = (stack.codes >= 0) | np.isnan(stack.codes)  # NaN: shadow or outside the field
    l_all = codes_from_abscissa(SMALL, xyz[..., 0] * SMALL.L_mm / (SMALL.L_mm - xyz[..., 2]))
    shadow = ~stack.lit & (l_all >= 0) & (l_all <= SMALL.nlp) & in_field
    assert shadow.sum() > 50
    x1 = block.x_range_mm[1]
    X, Y, Z = xyz[shadow, 0], xyz[shadow, 1], xyz[shadow, 2]
    # On R, beyond the +X face, no further than the block's shadow length, within its Y extent.
    assert np.all(Z == 0.0)
    assert np.all(x1 < X)
    length = block.top_mm * x1 / (SMALL.L_mm - block.top_mm)
    assert X.max() <= x1 + length * 1.01
    assert np.all(np.abs(Y) <= block.y_range_mm[1] * SMALL.L_mm / (SMALL.L_mm - block.top_mm))
    # Shadowed pixels are dark: ambient light only.
    dark = round(0.05 * 65535)
    assert np.all(stack.images[:, shadow] == dark)


@pytest.mark.parametrize("name", ["sphere", "two_spheres"])
def test_sphere_cap_points_lie_on_the_sphere(name: str) -> None:
    scene = make_scene(name)
    stack = render_stack(SMALL, scene)
    xyz = _hit_points(SMALL, stack)
    centres = [scene.center_mm] if name == "sphere" else list(scene.centers_mm)
    r = scene.radius_mm
    cap = np.zeros(SMALL.shape, dtype=bool)
    for c in centres:
        dist = np.linalg.norm(xyz - np.array(c), axis=-1)
        on = xyz[..., 2] > c[2] + 1.0
        assert np.all(np.abs(dist[on & (dist < r + 5)] - r) < 1e-6)
        cap |= on & (dist < r + 5)
    assert cap.sum() > 100
    # The apex: the highest truth is within a pixel's sag of the top of the sphere.
    assert np.nanmax(stack.truth_mm) == pytest.approx(centres[0][2] + r, abs=0.1)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_scene_truth_is_the_height_field_at_the_hit(name: str) -> None:
    scene = make_scene(name)
    stack = render_stack(SMALL, scene)
    xyz = _hit_points(SMALL, stack)
    h = scene.height_mm(xyz[..., 0], xyz[..., 1])
    z = stack.hit_mm
    assert np.all(z <= h + 1e-6)  # never inside the object
    wall = z < h - 1e-6  # hits on a vertical wall (blocks, risers, below a sphere's equator)
    if scene.smooth:
        assert not wall.any()
    assert wall.mean() < 0.02
    np.testing.assert_allclose(z[~wall], h[~wall], atol=1e-6)
    valid = np.isfinite(stack.truth_mm)
    np.testing.assert_array_equal(stack.truth_mm[valid], z[valid].astype(np.float32))
    assert 0.9 < valid.mean() <= 1.0


def test_staircase_descending_risers_cast_shadows_and_mark_edges() -> None:
    strip = SMALL.with_parameters(width_px=640, height_px=8)  # full X resolution, few rows
    down_scene = make_scene("staircase", ascending=False)
    down = render_stack(strip, down_scene)
    x_hit = _hit_points(strip, down)[4, :, 0]
    levels = (*down_scene.levels_mm, 0.0)
    for i, edge in enumerate(down_scene.edges_x_mm[1:]):
        # Every drop away from the projector shadows the tread beyond it, as far as its
        # top edge hides P: about (rise) * X / (L - top) on the lower tread.
        high, low = levels[i], levels[i + 1]
        length = (high - low) * edge / (strip.L_mm - high)
        assert not down.lit[4, (x_hit > edge + 0.5) & (x_hit < edge + 0.95 * length)].any()
        assert down.lit[4, (x_hit > edge + 1.05 * length) & (x_hit < edge + 2 * length)].all()
    up = render_stack(SMALL, make_scene("staircase"))
    scene = make_scene("staircase")
    cols = np.flatnonzero(up.edges[SMALL.height_px // 2])
    xs = SMALL.column_x_mm()[cols]
    for edge in scene.edges_x_mm[1:-1]:
        # Each riser is marked within a few pixels of its position on the image.
        assert np.min(np.abs(xs - edge)) < 4 * SMALL.pixel_mm


def test_pixels_outside_the_coded_field_are_dark() -> None:
    stack = render_stack(SMALL, make_scene("plane", z_mm=40.0))
    outside = ~stack.lit
    assert outside.sum() > 100
    assert np.all(np.isnan(stack.truth_mm[outside]))
    assert np.all(stack.images[:, outside] == round(0.05 * 65535))
    # Raised 40 mm, the coded field slides towards -X: the camera's +X edge is outside it.
    cols = np.flatnonzero(outside.any(axis=0))
    assert np.all(cols > 3 * SMALL.width_px // 4)


# --------------------------------------------------------------------------- radiometry
@pytest.mark.parametrize("square", [False, True])
def test_noise_free_intensities_equal_the_pattern_at_the_true_code(square: bool) -> None:
    options = SimulationOptions(square=square)
    stack = render_stack(SMALL, make_scene("face"), options)
    lit = stack.lit
    for k, name in enumerate(PATTERN_NAMES):
        expected = np.rint(65535 * (0.05 + 0.8 * pattern_intensity(stack.codes[lit], name, square)))
        np.testing.assert_array_equal(stack.images[k][lit], expected.astype(np.uint16))


def test_noise_free_phase_gives_codes_to_micro_precision() -> None:
    stack = render_stack(SMALL, make_scene("flowerpot"))
    i0, i1, i2, i3 = (stack.image(f"PS_{i}").astype(np.float64) for i in range(4))
    phase = np.arctan2(i1 - i3, i0 - i2)
    lit = stack.lit
    err = np.angle(np.exp(1j * (phase[lit] - np.pi / 2 * stack.codes[lit])))
    assert np.abs(err).max() < 1e-4  # 16-bit quantisation only: < 7e-5 code


def test_projector_defocus_scales_the_fringe_contrast() -> None:
    sigma = 0.5
    sharp = render_stack(SMALL, make_scene("reference"))
    blurred = render_stack(SMALL, make_scene("reference"), SimulationOptions(projector_defocus_codes=sigma))

    def modulation(stack: RenderedStack) -> float:
        i0, i1, i2, i3 = (stack.image(f"PS_{i}").astype(np.float64) for i in range(4))
        centre = (slice(20, -20), slice(20, -20))
        return float(np.median(np.hypot(i1 - i3, i0 - i2)[centre]))

    ratio = modulation(blurred) / modulation(sharp)
    assert ratio == pytest.approx(math.exp(-((math.pi / 2 * sigma) ** 2) / 2), rel=1e-3)


def test_smoothed_square_waves_are_nearly_sinusoidal() -> None:
    options = SimulationOptions(square=True, smoothing_codes=1.0)
    stack = render_stack(SMALL, make_scene("block"), options)
    i0, i1, i2, i3 = (stack.image(f"PS_{i}").astype(np.float64) for i in range(4))
    lit = stack.lit & ~stack.edges & (stack.codes > 8) & (stack.codes < 120)  # away from the field edges
    err = np.angle(np.exp(1j * (np.arctan2(i1 - i3, i0 - i2)[lit] - np.pi / 2 * stack.codes[lit])))
    assert np.abs(err).max() < 2e-3
    gray = render_stack(SMALL, make_scene("block"), options).image("GC_6")
    assert set(np.unique(gray[lit])) <= {round(0.05 * 65535), round(0.85 * 65535)}  # GC not smoothed


def test_emitted_pattern_is_zero_outside_the_field_and_blurred_at_its_edge() -> None:
    codes = np.array([-1.0, 0.0, 64.3, 128.0, 131.0, np.nan])
    exact = emitted_pattern(codes, "GC_0", 128, SimulationOptions())
    assert exact[0] == 0.0 and exact[4] == 0.0 and exact[5] == 0.0
    blurred = emitted_pattern(codes, "GC_0", 128, SimulationOptions(projector_defocus_codes=0.3))
    assert blurred[3] == pytest.approx(0.5, abs=1e-3)  # GC_0 is white at the right edge
    assert emitted_pattern(np.array([96.3]), "GC_0", 128, SimulationOptions(projector_defocus_codes=0.3))[0] == (
        pytest.approx(1.0, abs=1e-9)
    )
    assert blurred[0] < 1e-9 and blurred[4] < 1e-9 and blurred[5] == 0.0  # 10 sigma outside
    gamma = emitted_pattern(np.array([1.0 / 3.0]), "PS_0", 128, SimulationOptions(projector_gamma=2.2))
    assert gamma[0] == pytest.approx((0.5 + 0.5 * math.cos(math.pi / 6)) ** 2.2)


def test_albedo_and_ambient_scale_the_images() -> None:
    bright = render_stack(SMALL, make_scene("reference"))
    grey = render_stack(SMALL, make_scene("reference", reflectance=0.5), SimulationOptions(ambient=0.1))
    expected = np.rint(0.5 * (0.1 * 65535 + (bright.images.astype(np.float64) - 0.05 * 65535)))
    assert np.abs(grey.images.astype(np.float64) - expected).max() <= 1.0


# --------------------------------------------------------------------------- camera
def test_realistic_render_is_seeded_and_noisy_as_asked() -> None:
    options = realistic_8bit(seed=7)
    a = render_stack(SMALL, make_scene("block"), options)
    b = render_stack(SMALL, make_scene("block"), options)
    c = render_stack(SMALL, make_scene("block"), options.with_changes(seed=8))
    assert a.images.dtype == np.uint8 and a.images.shape == (11, 120, 160)
    np.testing.assert_array_equal(a.images, b.images)
    assert not np.array_equal(a.images, c.images)
    diff = a.images.astype(np.float64) - c.images.astype(np.float64)
    assert np.std(diff) / math.sqrt(2) == pytest.approx(1.5, rel=0.1)  # quantisation adds ~1/12
    np.testing.assert_array_equal(a.truth_mm, c.truth_mm)
    # A different scene with the same options gets independent noise.
    ref = render_stack(SMALL, make_scene("reference"), options).images[:, :, -10:].astype(np.float64)
    blk = a.images[:, :, -10:].astype(np.float64)  # beyond the block and its shadow: same plane
    assert np.std(ref - blk) == pytest.approx(1.5 * math.sqrt(2), rel=0.15)


def test_supersampling_keeps_the_truth_and_mixes_edge_pixels() -> None:
    exact = render_stack(SMALL, make_scene("block"))
    mixed = render_stack(SMALL, make_scene("block"), SimulationOptions(supersample=3))
    np.testing.assert_array_equal(exact.truth_mm, mixed.truth_mm)
    assert np.array_equal(exact.lit, mixed.lit)
    assert mixed.edges.sum() >= exact.edges.sum()
    even = render_stack(SMALL, make_scene("block"), SimulationOptions(supersample=2))
    np.testing.assert_allclose(even.truth_mm, exact.truth_mm, atol=1e-6, equal_nan=True)
    flat = ~mixed.edges & mixed.lit

    # Away from edges, averaging over a pixel lowers the fringe contrast but keeps the phase.
    def phase(stack: RenderedStack) -> np.ndarray:
        i0, i1, i2, i3 = (stack.image(f"PS_{i}").astype(np.float64) for i in range(4))
        return np.arctan2(i1 - i3, i0 - i2)

    err = np.angle(np.exp(1j * (phase(mixed) - phase(exact))))[flat]
    assert np.abs(err).max() < 5e-3


def test_centre_sampling_takes_the_centre_ray_then_the_gaussian_blur() -> None:
    """camera_sampling="centre": a pixel's light is its centre ray's (the exact one-ray render),
    blurred by a Gaussian of camera_defocus_px; the sub-rays still mark depth edges in a pixel."""
    scene = make_scene("block")
    exact = render_stack(SMALL, scene)
    for supersample in (2, 3):
        centre = render_stack(SMALL, scene, SimulationOptions(supersample=supersample, camera_sampling="centre"))
        np.testing.assert_array_equal(centre.images, exact.images)
        np.testing.assert_array_equal(centre.truth_mm, exact.truth_mm)
    area = render_stack(SMALL, scene, SimulationOptions(supersample=3))
    centre = render_stack(SMALL, scene, SimulationOptions(supersample=3, camera_sampling="centre"))
    np.testing.assert_array_equal(centre.edges, area.edges)
    assert np.any(area.images != exact.images)  # area sampling mixes the pixels on the block's edges

    # the blur: a Gaussian of sigma 0.7 px on the exact images (float, before rounding to 16 bits)
    sharp_centre = SimulationOptions(supersample=3, camera_sampling="centre")
    blurred = render_stack(SMALL, scene, sharp_centre.with_changes(camera_defocus_px=0.7))
    grey = exact.images.astype(np.float64)
    expected = np.stack([cv2.GaussianBlur(g, (0, 0), 0.7, borderType=cv2.BORDER_REPLICATE) for g in grey])
    # within the two roundings to 16 bits (of the exact images here, of the blurred ones there);
    # without the blur the pixels at the block's edges would be off by thousands of grey levels
    assert np.abs(blurred.images - expected).max() <= 1.0 + 1e-6

    options = realistic_8bit(camera_sampling="centre")
    assert options.to_dict()["camera_sampling"] == "centre"
    assert SimulationOptions(**options.to_dict()) == options
    assert SimulationOptions().camera_sampling == "area"


def test_render_series_shares_geometry_and_draws_fresh_noise() -> None:
    options = realistic_8bit(seed=3, supersample=1)
    frames = list(render_series(SMALL, [0.0, 4.0], repeats=2, options=options))
    assert [(z, r) for z, r, _ in frames] == [(0.0, 0), (0.0, 1), (4.0, 0), (4.0, 1)]
    for z, _, stack in frames:
        valid = np.isfinite(stack.truth_mm)
        assert np.all(stack.truth_mm[valid] == np.float32(z))
    assert not np.array_equal(frames[0][2].images, frames[1][2].images)
    again = list(render_series(SMALL, [0.0, 4.0], repeats=2, options=options))
    for (_, _, x), (_, _, y) in zip(frames, again, strict=True):
        np.testing.assert_array_equal(x.images, y.images)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"bit_depth": 12}, "bit_depth"),
        ({"bit_depth": True}, "bit_depth"),
        ({"noise_grey": -1.0}, "noise_grey"),
        ({"ambient": float("nan")}, "ambient"),
        ({"projector_gain": 0.0}, "projector_gain"),
        ({"projector_gamma": -2.0}, "projector_gamma"),
        ({"projector_defocus_codes": -0.1}, "projector_defocus_codes"),
        ({"camera_defocus_px": "0.7"}, "camera_defocus_px"),
        ({"square": "yes"}, "square"),
        ({"smoothing_codes": -1.0}, "smoothing_codes"),
        ({"supersample": 0}, "supersample"),
        ({"supersample": 2.0}, "supersample"),
        ({"seed": -1}, "seed"),
        ({"camera_sampling": "center"}, "camera_sampling"),
        ({"camera_sampling": None}, "camera_sampling"),
        ({"colour": 1}, "colour"),
    ],
)
def test_bad_options_are_named(changes: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SimulationOptions().with_changes(**changes)


def test_bad_render_arguments() -> None:
    with pytest.raises(TypeError, match="scene"):
        render_stack(SMALL, "block")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="too close to the pupils"):
        render_stack(SMALL, make_scene("plane", z_mm=1000.0))
    with pytest.raises(ValueError, match="repeats"):
        render_series(SMALL, [0.0], repeats=0)
    with pytest.raises(ValueError, match="z_in_mm"):
        render_series(SMALL, [float("inf")], repeats=1)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["reference", "block", "face"])
def test_full_size_realistic_render(name: str) -> None:
    stack = render_stack(PAPER_RIG, make_scene(name), SimulationOptions.realistic_8bit())
    assert stack.images.shape == (11, 480, 640) and stack.images.dtype == np.uint8
    assert np.isfinite(stack.truth_mm).mean() > 0.95


def test_stage_positions_stop_inclusive_and_never_past_it() -> None:
    assert stage_positions(0.0, 8.0, 3.0) == [0.0, 3.0, 6.0]
    assert stage_positions(0.0, 8.0, 4.0) == [0.0, 4.0, 8.0]
    assert stage_positions(0.0, 0.3, 0.1) == [0.0, 0.1, 0.2, 0.3]  # 0.3/0.1 = 2.9999999999999996
    assert stage_positions(2.0, 2.0, 1.0) == [2.0]
    for args, name in (
        ((0.0, 8.0, 0.0), "step_mm"),
        ((8.0, 0.0, 1.0), "stop_mm"),
        ((float("nan"), 1.0, 1.0), "start_mm"),
    ):
        with pytest.raises(ValueError, match=name):
            stage_positions(*args)


def test_a_series_capture_is_render_stack_with_series_seed() -> None:
    options = realistic_8bit(seed=5, supersample=1)
    frames = list(render_series(SMALL, [0.0, 4.0], repeats=2, options=options))
    for index, z in enumerate((0.0, 4.0)):
        for repeat in range(2):
            alone = render_stack(SMALL, StageScene(z_in_mm=z), options.with_changes(seed=series_seed(5, index, repeat)))
            np.testing.assert_array_equal(frames[2 * index + repeat][2].images, alone.images)
    seeds = {series_seed(5, i, r) for i in range(10) for r in range(10)}
    assert len(seeds) == 100 and 5 not in seeds
    with pytest.raises(ValueError, match="repeat"):
        series_seed(5, 0, -1)


@pytest.mark.parametrize("scene_name", ["sphere", "staircase", "two_spheres", "block"])
def test_segments_that_never_pass_over_the_object_are_not_marched(scene_name: str, monkeypatch) -> None:
    """The shadow test skips the segments whose trace on the plane meets no footprint box
    (``cast._may_pass_over_the_object``); the truth is identical to marching every segment."""
    from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
    from metrology.core.simulate import ScenePlacement, cast_truth
    from metrology.core.simulate import cast as cast_module

    camera = PinholeCamera(200, 150, ((300.0, 0, 99.5), (0, 300.0, 74.5), (0, 0, 1)), (-0.05, 0.01, 0, 0, 0))
    projector = PinholeProjector(256, 192, ((300.0, 0, 127.5), (0, 300.0, 95.5), (0, 0, 1)))
    rig = look_at_rig(camera, projector, (-160.0, 8.0, 10.0), (0.0, 0.0, 600.0))
    prepared = rig.prepare(rig.shape, (projector.width, projector.height))
    scene, placement = make_scene(scene_name), ScenePlacement.facing_camera(600.0)
    skipped = cast_truth(prepared, scene, placement)
    every_segment = lambda scene, x0, *rest: np.ones(x0.shape, bool)  # noqa: E731
    monkeypatch.setattr(cast_module, "_may_pass_over_the_object", every_segment)
    marched = cast_truth(prepared, scene, placement)
    assert (~marched.lit).sum() > 400  # about 500 pixels in the shadow of each of these scenes
    np.testing.assert_array_equal(skipped.lit, marched.lit)
    np.testing.assert_array_equal(skipped.points_mm, marched.points_mm)
