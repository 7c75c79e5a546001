"""The geometric-model seam and the crossed-axes model behind it (Eqs. 14-17, camera rays)."""

import numpy as np
import pytest

from metrology.core.geometry import GeometryError, model_from_dict, triangulate_frame
from metrology.core.geometry.crossed_axes import (
    PAPER_RIG,
    CrossedAxesReference,
    Rig,
    codes_on_camera_rays,
    height_from_codes,
    points_from_heights,
)
from metrology.core.synthetic import sphere_heights

RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=160, height_px=120)


def test_absolute_triangulation_of_planes_and_a_sphere():
    prepared = RIG.prepare()
    z_sphere = sphere_heights(RIG, (352.0, 0.0, 70.0), 60.0)
    for truth in (np.zeros(RIG.shape), np.full(RIG.shape, 40.0), z_sphere):
        codes = codes_on_camera_rays(RIG, truth)
        in_field = (codes >= 0) & (codes <= RIG.nlp) & np.isfinite(truth)
        codes = np.where(in_field, codes, np.nan)
        result = triangulate_frame(prepared, codes.astype(np.float32), None)
        assert result.height_mm is not None and result.points_mm is not None
        valid = np.isfinite(result.height_mm)
        np.testing.assert_array_equal(valid, in_field)
        # float32 light codes: 2^-24 relative of ~128 codes, ~4 mm per code on R, x3 to heights
        np.testing.assert_allclose(result.height_mm[valid], truth[valid], atol=5e-4)
        expected = points_from_heights(RIG, np.where(valid, truth, np.nan))
        np.testing.assert_allclose(result.points_mm[valid], expected[valid], atol=2e-3)


def test_against_a_captured_reference_equals_eqs_16_17():
    prepared = RIG.prepare()
    ref = codes_on_camera_rays(RIG, 0.0).astype(np.float32)
    obj = codes_on_camera_rays(RIG, 25.0).astype(np.float32)
    surface = prepared.reference(ref, None)
    assert isinstance(surface, CrossedAxesReference)
    z = triangulate_frame(prepared, obj, None, reference=surface, points=False).height_mm
    np.testing.assert_allclose(z, height_from_codes(RIG, ref.astype(float), obj.astype(float)), atol=2e-5)


def test_camera_rays_pass_through_the_measured_points():
    prepared = RIG.prepare()
    rays = prepared.camera_rays()
    np.testing.assert_allclose(np.linalg.norm(rays.direction, axis=-1), 1.0, atol=1e-12)
    xyz = points_from_heights(RIG, np.full(RIG.shape, 30.0))
    offset = xyz - rays.origin_mm
    cross = np.cross(offset, rays.direction)
    assert np.abs(cross).max() < 1e-9


def test_projector_coordinates_map_to_light_codes():
    # u of a projector 1024 wide: l = (u + 0.5) nlp / 1024
    prepared = RIG.prepare(projector_size=(1024, 768))
    codes = codes_on_camera_rays(RIG, 10.0)
    u = (codes * 1024 / RIG.nlp - 0.5).astype(np.float32)
    z = triangulate_frame(prepared, u, None, points=False).height_mm
    np.testing.assert_allclose(z, 10.0, atol=5e-4)


def test_prepare_is_cached_and_checks_sizes():
    assert RIG.prepare() is RIG.prepare()
    with pytest.raises(GeometryError, match="160x120"):
        RIG.prepare((100, 100))
    with pytest.raises(GeometryError, match="projector_size"):
        RIG.prepare(projector_size=(0, 10))


def test_a_models_own_projector_size_is_what_preparing_gives():
    """``GeometryModel.projector_size`` (read without building tables) equals the prepared model's:
    None for the crossed-axes rig (its projector size comes with the codec), the projector's
    pixels for a pinhole rig."""
    from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig

    camera = PinholeCamera(40, 30, ((50.0, 0.0, 19.5), (0.0, 50.0, 14.5), (0.0, 0.0, 1.0)), (-0.1, 0.02, 0, 0, 0))
    projector = PinholeProjector(64, 48, ((80.0, 0.0, 31.5), (0.0, 80.0, 23.5), (0.0, 0.0, 1.0)), (0.05, 0, 0, 0, 0))
    pinhole = look_at_rig(camera, projector, (-100.0, 0.0, 0.0), (0.0, 0.0, 500.0))
    assert RIG.projector_size is None and RIG.prepare().projector_size is None
    assert pinhole.projector_size == pinhole.prepare().projector_size == (64, 48)


def test_missing_u_axis_is_named():
    prepared = RIG.prepare()
    with pytest.raises(GeometryError, match="u axis"):
        triangulate_frame(prepared, None, np.zeros(RIG.shape, np.float32))


def test_model_from_dict_dispatches_on_model():
    assert model_from_dict(PAPER_RIG.to_dict()) == PAPER_RIG
    assert model_from_dict({**PAPER_RIG.to_dict(), "model": "crossed_axes"}) == PAPER_RIG
    with pytest.raises(GeometryError, match="'fisheye'"):
        model_from_dict({**PAPER_RIG.to_dict(), "model": "fisheye"})


def test_the_registry_imports_a_model_when_asked_for():
    """metrology.core.geometry.MODELS: every model class under its own ``model`` key, its module
    imported on first access only (a fresh interpreter reading a crossed-axes rig imports neither
    the pinhole nor the stereo module)."""
    import subprocess
    import sys

    from metrology.core import geometry

    assert list(geometry.MODELS) == ["crossed_axes", "pinhole", "stereo"] and len(geometry.MODELS) == 3
    for name, cls in geometry.MODELS.items():
        assert cls.model == name and getattr(geometry, cls.__name__) is cls
    assert "nope" not in geometry.MODELS
    with pytest.raises(AttributeError):
        geometry.Nope  # noqa: B018
    code = (
        "import sys\n"
        "from metrology.core.geometry import model_from_dict\n"
        "model_from_dict({'L_mm': 1022.0, 'd_mm': 352.0, 'alpha_rad': 0.332, 'fw_mm': 500.0, 'nlp': 128,"
        " 'width_px': 64, 'height_px': 48})\n"
        "print(sorted(m for m in sys.modules if m.startswith('metrology.core.geometry.')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    imported = done.stdout
    assert "crossed_axes" in imported and "geometry.pinhole" not in imported and "geometry.stereo" not in imported
