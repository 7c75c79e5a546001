"""render_flat_frames: the virtual rig's camera images under a white and a black projector frame."""

from __future__ import annotations

import numpy as np

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_flat_frames, render_stack
from tests.app.stacks import SMALL_RIG


def test_flat_frames_of_a_plane_are_ambient_and_ambient_plus_gain():
    rig = Rig.from_dict(SMALL_RIG)
    options = SimulationOptions(ambient=0.05, projector_gain=0.8)
    white, black = render_flat_frames(rig, make_scene("reference"), options)
    assert white.shape == black.shape == rig.shape
    np.testing.assert_allclose(black, 0.05 * 65535, rtol=1e-12)
    np.testing.assert_allclose(white, 0.85 * 65535, rtol=1e-12)


def test_white_plus_black_equals_opposite_phase_frames_under_shadows_and_blur():
    """Sinusoidal PS_0 + PS_2 emit 0.5 + 0.5 cos + 0.5 - 0.5 cos = 1: their images sum to white + black
    wherever the light path is the same (the sphere's shadow, the camera blur and supersampling included)."""
    rig = Rig.from_dict(SMALL_RIG)
    options = SimulationOptions(camera_defocus_px=0.8, supersample=3)
    scene = make_scene("sphere", rig=rig)
    white, black = render_flat_frames(rig, scene, options)
    stack = render_stack(rig, scene, options)
    ps0, ps2 = (stack.image(name).astype(np.float64) for name in ("PS_0", "PS_2"))
    assert np.mean(white - black < 0.01 * 65535) > 0.001  # the sphere casts a shadow: unlit pixels exist
    lit_field = np.isfinite(stack.codes)
    # rounding of the two 16-bit images: at most one grey level each
    assert np.max(np.abs((ps0 + ps2) - (white + black))[lit_field]) <= 1.0 + 1e-9


def test_stereo_flats_lit_by_a_kept_cast_are_those_cast_anew():
    """``render_camera_flats(cast=...)`` (the virtual camera's flats at each exposure of a bracket)
    gives, bit for bit, the flats that cast the scene themselves, with and without a reflectance
    map; a cast of another sub-pixel count is refused."""
    import pytest

    from metrology.core.simulate import render_camera_flats
    from metrology.core.simulate.exposures import HdrReflectance
    from metrology.core.simulate.stereo import cast_stereo
    from tests.stereo_rig import PLACEMENT, RIG, codec

    scene = make_scene("plane", z_mm=0.0)
    options = SimulationOptions(supersample=2, camera_defocus_px=0.5, ambient=0.1, projector_gain=2.0)
    cast = cast_stereo(RIG, scene, codec("u"), PLACEMENT, supersample=2)
    rho = HdrReflectance(x0_mm=-60.0, x1_mm=60.0, patch_x_mm=0.0, patch_y_mm=0.0, patch_radius_mm=10.0)
    for reflectance in (None, rho):
        anew = render_camera_flats(RIG, scene, options, placement=PLACEMENT, reflectance=reflectance)
        kept = render_camera_flats(RIG, scene, options, placement=PLACEMENT, reflectance=reflectance, cast=cast)
        assert len(kept) == 2
        for (w0, k0), (w1, k1) in zip(anew, kept, strict=True):
            assert (w0 > k0).mean() > 0.5  # the projector lights most of each camera's pixels
            np.testing.assert_array_equal(w1, w0)
            np.testing.assert_array_equal(k1, k0)
    with pytest.raises(ValueError, match="rays per pixel side"):
        render_camera_flats(RIG, scene, SimulationOptions(), placement=PLACEMENT, cast=cast)
