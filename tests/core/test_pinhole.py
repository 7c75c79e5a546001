"""The pinhole model: rig file contract, exact triangulation through distorted devices, uncertainty."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metrology.core.geometry.base import GeometryError, GeometryOptions, triangulate_frame
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, PreparedPinhole, look_at_rig
from metrology.core.geometry.rig_file import RigFileError
from metrology.core.scenes import Scene, make_scene
from metrology.core.simulate import CastTruth, ScenePlacement, cast_truth

CAMERA = PinholeCamera(
    160, 120, ((200.0, 0.0, 79.5), (0.0, 201.0, 59.5), (0.0, 0.0, 1.0)), (-0.15, 0.05, 0.001, -0.0008, 0.01)
)
PROJECTOR = PinholeProjector(
    320, 200, ((380.0, 0.0, 160.2), (0.0, 381.0, 99.7), (0.0, 0.0, 1.0)), (0.08, -0.04, 0.0005, 0.0003, 0.0)
)
BASELINES = {"u": (-160.0, 8.0, 10.0), "v": (6.0, -150.0, 12.0)}
Z0 = 600.0
TOL_MM = 1e-3  # the contract: 1 um on every valid pixel


def _rig(axis: str, projector: PinholeProjector = PROJECTOR) -> PinholeRig:
    return look_at_rig(CAMERA, projector, BASELINES[axis], (0.0, 0.0, Z0))


def _cast(rig: PinholeRig, scene: Scene, distance_mm: float = Z0) -> CastTruth:
    """Ground truth of ``scene`` facing the camera, its reference plane at camera Z = distance_mm."""
    prepared = rig.prepare(rig.shape, (rig.projector.width, rig.projector.height))
    return cast_truth(prepared, scene, ScenePlacement.facing_camera(distance_mm))


_TRUTHS: dict[tuple[str, str, bool], CastTruth] = {}


def _truth(axis: str, scene: str, projector_distorted: bool = True) -> CastTruth:
    key = (axis, scene, projector_distorted)
    if key not in _TRUTHS:
        proj = PROJECTOR if projector_distorted else PinholeProjector(320, 200, PROJECTOR.K, ())
        _TRUTHS[key] = _cast(_rig(axis, proj), make_scene(scene))
    return _TRUTHS[key]


def _prepare(rig: PinholeRig, triangulate: str = "auto", method: str = "plane") -> PreparedPinhole:
    return rig.prepare(options=GeometryOptions(triangulate=triangulate, method=method))


# --------------------------------------------------------------------------- rig file
def _rig_dict() -> dict[str, Any]:
    return _rig("u").to_dict()


def test_rig_file_round_trip_and_contract_keys() -> None:
    data = _rig_dict()
    assert list(data) == ["model", "camera", "projector", "R", "T"]
    assert set(data["camera"]) == {"width_px", "height_px", "K", "dist"}
    assert set(data["projector"]) == {"width", "height", "K", "dist"}
    rig = PinholeRig.from_json(json.dumps(data))
    assert rig == _rig("u")
    assert PinholeRig.from_dict(rig.to_dict()).to_dict() == data


@pytest.mark.parametrize("dist", [None, []])
def test_absent_or_empty_dist_means_none(dist: list[float] | None) -> None:
    data = _rig_dict()
    if dist is None:
        del data["projector"]["dist"]
    else:
        data["projector"]["dist"] = dist
    rig = PinholeRig.from_dict(data)
    assert rig.projector.distortion.is_identity
    assert "dist" not in rig.to_dict()["projector"]


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_dist_counts_accepted(n: int) -> None:
    data = _rig_dict()
    data["camera"]["dist"] = [0.01] * n
    assert len(PinholeRig.from_dict(data).camera.dist) == n


def _mutate(path: str, value: Any) -> dict[str, Any]:
    data = copy.deepcopy(_rig_dict())
    *parents, last = path.split(".")
    node = data
    for key in parents:
        node = node[key]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("colour", 1, "unknown key 'colour'"),
        ("camera.fov", 1, "camera has unknown key 'fov'"),
        ("projector.lumens", 1, "projector has unknown key 'lumens'"),
        ("camera.dist", [0.1, 0.2, 0.3], "camera dist must hold 4, 5, 8, 12 or 14 coefficients"),
        ("projector.dist", [0.0] * 6, "projector dist must hold 4, 5, 8, 12 or 14 coefficients"),
        ("R", [[1, 0, 0], [0, 1, 0], [0, 0, 1.01]], "R is not a rotation"),
        ("R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "R is not a rotation: det R"),
        ("R", [[1, 0], [0, 1]], "R must be a 3x3 matrix"),
        ("camera.K", [[0, 0, 1], [0, 200, 1], [0, 0, 1]], "camera K must have fx > 0"),
        ("projector.K", [[300, 0, 1], [0, -2, 1], [0, 0, 1]], "projector K must have fx > 0 and fy > 0"),
        ("camera.K", [[300, 0, 1], [0, 300, 1], [0, 0, 2]], "camera K must have the form"),
        ("camera.width_px", 10.5, "camera width_px must be a positive integer"),
        ("projector.height", 0, "projector height must be positive"),
        ("T", [1, 2], "T must be a list of three numbers"),
        ("T", _DELETE, "missing key 'T'"),
        ("camera.K", _DELETE, "camera is missing key 'K'"),
        ("model", "pinhole2", "rig model must be 'pinhole'"),
        # bounded values (issue 23 item 6)
        ("camera.dist", [1e300, 0, 0, 0, 0], "camera dist[0] must be within +-10000, got 1e+300"),
        ("projector.dist", [0, 0, 0, -10000.5], "projector dist[3] must be within +-10000, got -10000.5"),
        ("camera.dist", [0, float("nan"), 0, 0], "camera dist[1] must be finite"),
        ("T", [0, 0, 1e308], "T[2] must be within +-100000 mm, got 1e+308"),
        ("T", [-100000.5, 0, 0], "T[0] must be within +-100000 mm"),
        ("T", [0, float("inf"), 0], "T[1] must be finite"),
    ],
)
def test_bad_rig_files_name_the_key(path: str, value: Any, message: str) -> None:
    with pytest.raises(RigFileError, match=re.escape(message)):
        PinholeRig.from_dict(_mutate(path, value))


def test_the_bounds_themselves_are_accepted() -> None:
    rig = PinholeRig.from_dict(_mutate("T", [100000.0, -100000.0, 0.0]))
    assert rig.T == (100000.0, -100000.0, 0.0)
    rig = PinholeRig.from_dict(_mutate("camera.dist", [10000.0, -10000.0, 0.0, 0.0]))
    assert rig.camera.dist[:2] == (10000.0, -10000.0)


def test_sizes_must_match() -> None:
    rig = _rig("u")
    with pytest.raises(GeometryError, match=r"codec's projector is 1280x800 but the rig's projector is 320x200"):
        rig.prepare(projector_size=(1280, 800))
    with pytest.raises(GeometryError, match=r"frames are 640x480 px but the rig's camera is 160x120 px"):
        rig.prepare(shape=(480, 640))
    with pytest.raises(ValueError, match="triangulate must be one of auto, u, v, got 'w'"):
        rig.prepare(options=GeometryOptions(triangulate="w"))
    with pytest.raises(ValueError, match="method must be one of plane, midpoint, got 'dlt'"):
        rig.prepare(options=GeometryOptions(method="dlt"))


def test_auto_axis_follows_the_baseline() -> None:
    assert _rig("u").prepare().axis == "u"
    assert _rig("v").prepare().axis == "v"
    assert _rig("u").prepare().required_axes == ("u",)


def test_missing_axis_is_named() -> None:
    prep = _rig("v").prepare()
    with pytest.raises(GeometryError, match="needs the projector's v axis coded"):
        triangulate_frame(prep, np.zeros(prep.shape, np.float32), None)


# --------------------------------------------------------------------------- exactness
@pytest.mark.parametrize("scene", ["plane", "sphere", "staircase"])
@pytest.mark.parametrize("axis", ["u", "v"])
@pytest.mark.parametrize("method", ["plane", "midpoint"])
@pytest.mark.parametrize("both_axes", [False, True])
def test_exact_through_distorted_rig(scene: str, axis: str, method: str, both_axes: bool) -> None:
    """Exact (u, v) of ray-cast scenes through a rig distorted on both devices: every valid
    pixel within 1 um of the truth, nothing valid lost."""
    truth = _truth(axis, scene)
    prep = _prepare(_rig(axis), "auto", method)
    assert prep.axis == axis
    u = truth.u.astype(np.float32)
    v = truth.v.astype(np.float32)
    res = triangulate_frame(
        prep, u if both_axes or axis == "u" else None, v if both_axes or axis == "v" else None, heights=False
    )
    assert res.points_mm is not None and res.points_mm.dtype == np.float32
    valid = truth.lit
    assert valid.mean() > 0.5
    err = np.linalg.norm(res.points_mm.astype(np.float64) - truth.points_mm, axis=-1)
    assert np.all(np.isfinite(err[valid]))
    assert err[valid].max() < TOL_MM
    assert np.all(np.isnan(res.points_mm[~np.isfinite(truth.u if axis == "u" else truth.v)]))


@pytest.mark.parametrize("axis", ["u", "v"])
def test_closed_form_without_projector_distortion(axis: str) -> None:
    truth = _truth(axis, "sphere", projector_distorted=False)
    rig = look_at_rig(CAMERA, PinholeProjector(320, 200, PROJECTOR.K, ()), BASELINES[axis], (0.0, 0.0, Z0))
    coded = (truth.u if axis == "u" else truth.v).astype(np.float32)
    prep = rig.prepare()
    res = triangulate_frame(prep, coded if axis == "u" else None, coded if axis == "v" else None, heights=False)
    assert res.points_mm is not None
    err = np.linalg.norm(res.points_mm - truth.points_mm, axis=-1)[truth.lit]
    assert err.max() < TOL_MM


def test_heights_above_reference_plane() -> None:
    """Reference: the plane Z = Z0; object: a plane 20 mm nearer; heights 20 mm, positive towards the camera."""
    rig = _rig("u")
    prep = rig.prepare()
    ref_truth = _cast(rig, make_scene("plane", z_mm=0.0))
    obj_truth = _cast(rig, make_scene("plane", z_mm=20.0))
    reference = prep.reference(ref_truth.u.astype(np.float32), None)
    assert abs(reference.normal @ np.array([0.0, 0.0, 1.0]) + 1) < 1e-9  # normal points to the camera (-Z)
    res = triangulate_frame(prep, obj_truth.u.astype(np.float32), None, reference=reference)
    assert res.height_mm is not None and res.points_mm is not None
    h = res.height_mm[obj_truth.lit]
    assert np.abs(h - 20.0).max() < TOL_MM
    # points_from_heights inverts the height map onto the camera rays
    back = prep.points_from_heights(res.height_mm, reference)
    assert np.nanmax(np.abs(back - res.points_mm)) < TOL_MM
    depth_back = prep.points_from_heights(res.points_mm[..., 2])
    assert np.nanmax(np.abs(depth_back - res.points_mm)) < TOL_MM
    with pytest.raises(GeometryError, match="heights need a reference"):
        triangulate_frame(prep, obj_truth.u.astype(np.float32), None)


@pytest.mark.parametrize("projector_distorted", [False, True])
@pytest.mark.parametrize("both_axes", [False, True])
def test_sigma_is_the_derivative_of_the_point(projector_distorted: bool, both_axes: bool) -> None:
    """sigma_mm / sigma_u equals |dX/du| measured by finite differences of the triangulation."""
    truth = _truth("u", "sphere", projector_distorted)
    proj = PROJECTOR if projector_distorted else PinholeProjector(320, 200, PROJECTOR.K, ())
    prep = look_at_rig(CAMERA, proj, BASELINES["u"], (0.0, 0.0, Z0)).prepare()
    u = truth.u
    v = truth.v if both_axes else None
    h, w = prep.shape
    sigma_in = np.full((h, w), 0.05, np.float32)
    sigma = np.empty((h, w), np.float32)
    pts = np.empty((h, w, 3), np.float32)
    prep.triangulate_rows(slice(0, h), u, v, points_out=pts, sigma_in=sigma_in, sigma_out=sigma)
    du = 1e-3
    pts2 = np.empty_like(pts)
    prep.triangulate_rows(slice(0, h), u + du, v, points_out=pts2)
    deriv = np.linalg.norm(pts2.astype(np.float64) - pts, axis=-1) / du
    valid = truth.lit
    ratio = sigma[valid] / 0.05 / deriv[valid]
    assert np.median(np.abs(ratio - 1)) < 0.02
    assert np.all(np.isfinite(sigma[valid]))
    assert not math.isnan(float(np.median(sigma[valid])))


@pytest.mark.slow
def test_strong_projector_distortion_stays_within_1um() -> None:
    """A strongly distorted projector: one axis through the epipolar table, both through the
    undistortion grid (or Newton where no grid meets its tolerance); every valid pixel within 1 um."""
    strong = PinholeProjector(320, 200, PROJECTOR.K, (0.35, 0.4, 0.002, -0.001, 0.3))
    rig = look_at_rig(CAMERA, strong, BASELINES["u"], (0.0, 0.0, Z0))
    truth = _cast(rig, make_scene("sphere"))
    prep = rig.prepare()
    for v in (None, truth.v.astype(np.float32)):
        res = triangulate_frame(prep, truth.u.astype(np.float32), v, heights=False)
        assert res.points_mm is not None
        err = np.linalg.norm(res.points_mm - truth.points_mm, axis=-1)[truth.lit]
        assert truth.lit.sum() > 1000 and err.max() < TOL_MM


def test_undistortion_grid_matches_newton() -> None:
    from metrology.core.distortion import undistort_pixels
    from metrology.core.geometry.projector_grid import GRID_TOL, UndistortionGrid

    K = np.asarray(PROJECTOR.K)
    rng = np.random.default_rng(5)
    u = rng.uniform(-0.5, 319.5, 20000).astype(np.float32)
    v = rng.uniform(-0.5, 199.5, 20000).astype(np.float32)
    exact = undistort_pixels(K, PROJECTOR.distortion, u.astype(np.float64), v.astype(np.float64), tol_px=1e-10)
    for axis, truth, f in (("u", exact.x, K[0, 0]), ("v", exact.y, K[1, 1])):
        grid = UndistortionGrid.build(K, PROJECTOR.distortion, 320, 200, axis)
        assert grid is not None and grid.error <= GRID_TOL
        q, dq = grid.normalized(u, v, derivative=True)
        assert np.abs(q - truth).max() * f < 2 * GRID_TOL
        assert dq is not None and np.abs(dq * f - 1.0).max() < 0.5  # a slope near 1 / f


def test_triangulate_frame_depth_heights_and_sigma() -> None:
    """Decoded u maps straight to depths (no reference: the points' camera Z), to heights above a
    reference plane's capture, and to sigma."""
    rig = _rig("u")
    obj = _truth("u", "sphere")
    ref = _cast(rig, make_scene("plane", z_mm=0.0))
    u = obj.u.astype(np.float32)
    sigma_u = np.full(u.shape, 0.02, np.float32)
    prep = rig.prepare(rig.shape, (320, 200))
    depth = triangulate_frame(prep, u, None, heights=False, sigma=sigma_u)
    assert prep.axis == "u" and depth.height_mm is None
    assert depth.points_mm is not None
    z_mm = depth.points_mm[..., 2]
    valid = obj.lit
    assert np.abs(z_mm[valid] - obj.points_mm[..., 2][valid]).max() < TOL_MM
    assert depth.sigma_mm is not None
    assert np.all(np.isnan(depth.sigma_mm[np.isnan(z_mm)]))
    assert np.all(depth.sigma_mm[valid] > 0)
    reference = prep.reference(ref.u.astype(np.float32), None)
    heights = triangulate_frame(prep, u, None, reference=reference, points=False)
    assert heights.height_mm is not None
    # the scene's own heights above its reference plane Z = Z0
    assert np.abs(heights.height_mm[valid] - (Z0 - obj.points_mm[..., 2][valid])).max() < TOL_MM
    np.testing.assert_allclose(heights.height_mm[valid], obj.height_mm[valid], rtol=0, atol=TOL_MM)
    with pytest.raises(GeometryError, match="codec's projector is 1280x800"):
        rig.prepare(rig.shape, (1280, 800))


def test_coordinate_sigma_matches_monte_carlo() -> None:
    """sigma_x = P / (2 pi) sqrt(2 / N) sigma_I / B against the scatter of least-squares phases."""
    from metrology.core.uncertainty import coordinate_sigma

    rng = np.random.default_rng(11)
    n, period, b, noise = 8, 16.0, 40.0, 1.5
    x_true = rng.uniform(0, period, 200000)
    k = np.arange(n)[:, None]
    delta = 2 * np.pi * k / n
    images = 100 + b * np.cos(2 * np.pi * x_true / period + delta) + noise * rng.standard_normal((n, x_true.size))
    theta = np.arctan2(-(images * np.sin(delta)).sum(0), (images * np.cos(delta)).sum(0))
    x = period * (theta / (2 * np.pi)) % period
    err = (x - x_true + period / 2) % period - period / 2
    predicted = float(coordinate_sigma(period, n, noise, b))
    assert abs(err.std() / predicted - 1) < 0.02


def test_threaded_frame_of_a_fresh_rig_completes() -> None:
    """A frame of several tiles on two threads, the rig prepared afresh: the tables are built on the
    caller's thread (built lazily inside a tile worker, their own threaded build would wait forever
    for the busy pool)."""
    import threading

    from metrology.core.geometry.pinhole import _prepare_cached

    big = PinholeCamera(512, 384, ((640.0, 0.0, 255.5), (0.0, 641.0, 191.5), (0.0, 0.0, 1.0)), CAMERA.dist)
    rig = look_at_rig(big, PROJECTOR, BASELINES["u"], (0.0, 0.0, Z0))
    _prepare_cached.cache_clear()
    u = np.full(rig.shape, 160.0, np.float32)
    out: dict[str, Any] = {}

    def run() -> None:
        out["res"] = triangulate_frame(rig.prepare(), u, None, heights=False, threads=2)

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(timeout=120)
    assert not worker.is_alive(), "triangulation did not finish"
    assert np.isfinite(out["res"].points_mm[..., 2]).mean() > 0.5


def test_example_pinhole_rig_loads() -> None:
    """examples/pinhole-rig.json (shown to users in docs/) is a valid pinhole rig."""
    from pathlib import Path

    from metrology.core.geometry import model_from_dict

    path = Path(__file__).resolve().parents[2] / "examples" / "pinhole-rig.json"
    rig = model_from_dict(json.loads(path.read_text()))
    assert isinstance(rig, PinholeRig)
    assert rig.shape == (1536, 2048) and rig.auto_axis() == "u"


def _long_focus_rig(axis: str) -> PinholeRig:
    """A 1024x768 camera of focal length 2457.6 px and a 1280x800 projector, both distorted (the
    centre of the benchmark's rig)."""
    camera = PinholeCamera(
        1024, 768, ((2457.6, 0.0, 511.5), (0.0, 2457.6, 383.5), (0.0, 0.0, 1.0)), (-0.1, 0.03, 0.001, -0.0005, 0.0)
    )
    projector = PinholeProjector(
        1280, 800, ((1500.0, 0.0, 640.0), (0.0, 1500.0, 400.0), (0.0, 0.0, 1.0)), (0.06, -0.03, 0.0008, -0.0004, 0.0)
    )
    baseline = (-200.0, 10.0, 15.0) if axis == "u" else (10.0, -200.0, 15.0)
    return look_at_rig(camera, projector, baseline, (0.0, 0.0, 700.0))


@pytest.mark.parametrize("axis", ["u", "v"])
def test_epipolar_table_matches_newton_on_the_line(axis: str) -> None:
    """The tabulated undistortion along the epipolar lines agrees with Newton on each pixel's
    line within the table's tolerance plus float32 rounding, over the whole frame and the whole
    coded range, and the points through it are within 1 um of the truth."""
    from metrology.core.geometry.epipolar_table import LINE_TOL

    rig = _long_focus_rig(axis)
    prep = _prepare(rig, axis)
    assert prep._line is not None and prep._line.error <= LINE_TOL
    h, w = rig.shape
    size = rig.projector.width if axis == "u" else rig.projector.height
    coded = np.random.default_rng(3).uniform(0.0, size - 1.0, (h, w)).astype(np.float32)
    rows = slice(0, h)
    tab = prep.tables()
    q, _ = prep._line.evaluate(coded, tab["line_base"], tab["line_frac"])
    xp, yp, _ = prep._projector_normalized(rows, coded, None)
    exact = xp if axis == "u" else yp
    scale = rig.projector.K[0][0] if axis == "u" else rig.projector.K[1][1]
    err = np.abs(q - exact)[np.isfinite(q)] * scale
    assert np.isfinite(q).mean() > 0.9
    assert err.max() < LINE_TOL + 1e-4, f"{err.max():.2e} projector units"
    truth = _cast(rig, make_scene("sphere"), 700.0)
    c = truth.u if axis == "u" else truth.v
    kwargs = {"u": c.astype(np.float32), "v": None} if axis == "u" else {"u": None, "v": c.astype(np.float32)}
    res = triangulate_frame(prep, kwargs["u"], kwargs["v"], heights=False)
    assert res.points_mm is not None
    err_mm = np.linalg.norm(res.points_mm - truth.points_mm, axis=-1)[truth.lit]
    assert truth.lit.sum() > 10000 and err_mm.max() < TOL_MM


ISSUE_22_RIG = PinholeRig.from_json(
    (Path(__file__).resolve().parents[2] / "examples" / "distorted-pinhole-rig.json").read_text()
)
ISSUE_22_CAMERA, ISSUE_22_PROJECTOR = ISSUE_22_RIG.camera, ISSUE_22_RIG.projector


@pytest.mark.parametrize("device", [ISSUE_22_CAMERA, ISSUE_22_PROJECTOR], ids=["camera", "projector"])
def test_undistortion_round_trip_of_a_strongly_distorted_calibration(device: Any) -> None:
    """Every pixel of the issue-22 camera and projector, corners included (and one pixel
    beyond): undistorted, then distorted again, back within 1e-6 px."""
    from metrology.core.distortion import project_normalized, undistort_pixels

    w, h = (device.width_px, device.height_px) if isinstance(device, PinholeCamera) else (device.width, device.height)
    jj, kk = np.meshgrid(np.arange(-1.0, w + 1.0), np.arange(-1.0, h + 1.0))
    res = undistort_pixels(np.asarray(device.K), device.distortion, jj, kk)
    assert res.n_failed == 0
    u, v = project_normalized(np.asarray(device.K), device.distortion, res.x, res.y)
    assert float(np.hypot(u - jj, v - kk).max()) < 1e-6


def test_camera_tables_start_within_a_tenth_of_the_tolerance_and_meet_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """The issue-22 camera's table (every pixel): the cubic interpolation of the grid of solutions
    is within 1e-7 px of the solution everywhere (its reprojection), so the iteration takes no step
    from it; the grid's own solve, from ``K^-1 (u, v)``, does."""
    from metrology.core import distortion
    from metrology.core.distortion import project_normalized
    from metrology.core.geometry.pinhole import _camera_tables

    _camera_tables.cache_clear()
    steps: list[int] = []
    fast_newton = distortion._fast_newton
    monkeypatch.setattr(distortion, "_fast_newton", lambda *a, **k: steps.append(fast_newton(*a, **k)) or steps[-1])
    xn, yn = _camera_tables(ISSUE_22_CAMERA)
    _camera_tables.cache_clear()
    w, h = ISSUE_22_CAMERA.width_px, ISSUE_22_CAMERA.height_px
    jj, kk = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    u, v = project_normalized(np.asarray(ISSUE_22_CAMERA.K), ISSUE_22_CAMERA.distortion, xn, yn)
    assert float(np.hypot(u - jj, v - kk).max()) < 1e-7
    # the first call is the grid's own solve (from K^-1 (u, v)); the tiles' take no step
    assert steps[0] >= 1 and max(steps[1:]) == 0, steps


def test_prepared_tables_come_back_from_the_local_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second preparation (as in a new process: the in-memory caches cleared) reads the tables
    the first stored, and triangulates to the same numbers."""
    from metrology.core import local_cache
    from metrology.core.geometry.pinhole import _camera_tables, _prepare_cached

    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path))
    rig = _rig("u")
    truth = _truth("u", "sphere")
    _prepare_cached.cache_clear()
    first = triangulate_frame(rig.prepare(), truth.u.astype(np.float32), None, heights=False)
    local_cache.wait()  # the tables are written on a background thread
    assert local_cache.info(tmp_path).kinds["pinhole"][0] == 1
    _prepare_cached.cache_clear()
    _camera_tables.cache_clear()
    monkeypatch.setattr(
        "metrology.core.geometry.pinhole._camera_tables", lambda camera: pytest.fail("tables computed again")
    )
    second = triangulate_frame(rig.prepare(), truth.u.astype(np.float32), None, heights=False)
    np.testing.assert_array_equal(first.points_mm, second.points_mm)
    _prepare_cached.cache_clear()


def test_projector_grid_only_for_codecs_of_both_axes(monkeypatch: pytest.MonkeyPatch) -> None:
    """A u-only codec never builds the projector's undistortion grid; a codec of both axes builds
    it once, when the measurement asks which axes the model reads (on the caller's thread)."""
    from metrology.core.geometry import pinhole
    from metrology.core.geometry.pinhole import _prepare_cached

    built: list[object] = []
    real = pinhole._projector_grid
    monkeypatch.setattr(
        pinhole, "_projector_grid", lambda projector, axis: built.append(projector) or real(projector, axis)
    )
    _prepare_cached.cache_clear()
    rig = _rig("u")
    truth = _truth("u", "sphere")
    prep = rig.prepare()
    assert prep.used_axes(("u",)) == ("u",)
    triangulate_frame(prep, truth.u.astype(np.float32), None, heights=False)
    assert built == [] and prep._grid is None
    assert prep.used_axes(("u", "v")) == ("u", "v")
    assert len(built) == 1
    triangulate_frame(prep, truth.u.astype(np.float32), truth.v.astype(np.float32), heights=False)
    assert len(built) == 1
    _prepare_cached.cache_clear()


@pytest.mark.parametrize("both_axes", [False, True])
def test_compiled_paths_write_any_output_layout(both_axes: bool) -> None:
    """Through a distorted projector the compiled kernels write the points straight into a
    contiguous output; a strided output (a view of a larger array) and float64 decoded maps get
    the same points and sigmas, NaN where the frame is not lit."""
    rig = _rig("u")
    truth = _truth("u", "sphere")
    prep = rig.prepare(rig.shape, (320, 200))
    u = truth.u.astype(np.float32)
    v = truth.v.astype(np.float32) if both_axes else None
    sigma_u = np.full(u.shape, 0.02, np.float32)
    if both_axes:
        prep.used_axes(("u", "v"))
    ref = triangulate_frame(prep, u, v, heights=False, sigma=sigma_u)
    assert ref.points_mm is not None and ref.sigma_mm is not None
    rows = slice(10, 40)
    wide = np.full((rows.stop - rows.start, rig.shape[1], 4), -1.0, np.float32)
    sigma_wide = np.full((rows.stop - rows.start, rig.shape[1], 2), -1.0, np.float32)
    prep.triangulate_rows(
        rows,
        u[rows].astype(np.float64),
        None if v is None else v[rows].astype(np.float64),
        points_out=wide[..., :3],
        sigma_in=sigma_u[rows],
        sigma_out=sigma_wide[..., 0],
    )
    np.testing.assert_allclose(wide[..., :3], ref.points_mm[rows], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(sigma_wide[..., 0], ref.sigma_mm[rows], rtol=1e-6)
    assert np.all(wide[..., 3] == -1.0) and np.all(sigma_wide[..., 1] == -1.0)
    lit = truth.lit[rows]
    assert lit.any() and (~lit).any()
    assert np.isnan(wide[..., 2][~lit & ~np.isfinite(u[rows])]).all()
