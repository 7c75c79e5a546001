"""A small distorted stereo rig, its projector and codecs, shared by the stereo tests (not a test module).

Two 320x256 cameras 150 mm apart (camera 1 at x = +150 mm, turned towards the scene), both with
lens distortion; a distorted pinhole projector of 1280x800 between them, which the rig file does
not calibrate (the rig file holds its size alone). Scenes face camera 0 at :data:`Z0` mm (a field
about 160 mm wide: pixels of 0.5 mm).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.geometry.stereo import StereoProjector, StereoRig
from metrology.core.scenes import Scene
from metrology.core.simulate.cast import ScenePlacement
from metrology.core.simulate.stereo import ProjectorPlacement

PROJ_W, PROJ_H = 1280, 800
Z0 = 500.0
CAMERA0 = PinholeCamera(
    320, 256, ((1000.0, 0.0, 159.3), (0.0, 1001.0, 127.8), (0.0, 0.0, 1.0)), (-0.1, 0.05, 0.0006, -0.0004, 0.0)
)
CAMERA1 = PinholeCamera(
    320, 256, ((995.0, 0.0, 161.2), (0.0, 996.0, 126.1), (0.0, 0.0, 1.0)), (-0.08, 0.03, -0.0003, 0.0005, 0.0)
)
LENS = PinholeProjector(
    PROJ_W, PROJ_H, ((1400.0, 0.0, 640.3), (0.0, 1401.0, 399.6), (0.0, 0.0, 1.0)), (0.04, -0.02, 0.0003, 0.0002, 0.0)
)
_POSE1 = look_at_rig(CAMERA1, LENS, (150.0, 4.0, 8.0), (0.0, 0.0, Z0))
RIG = StereoRig(camera0=CAMERA0, camera1=CAMERA1, R=_POSE1.R, T=_POSE1.T, projector=StereoProjector(PROJ_W, PROJ_H))
_PROJ = look_at_rig(CAMERA0, LENS, (75.0, -30.0, 0.0), (0.0, 0.0, Z0))
PROJECTOR = ProjectorPlacement(projector=LENS, R=_PROJ.R, T=_PROJ.T)
"""The projector that lights the renders: between the cameras, 30 mm above them."""
PLACEMENT = ScenePlacement.facing_camera(Z0)


def turned_projector(angle_deg: float) -> ProjectorPlacement:
    """:data:`PROJECTOR` turned by ``angle_deg`` about its optical axis (its centre kept): at 45 degrees
    both axes' fringes cross the cameras' epipolar lines obliquely."""
    a = math.radians(angle_deg)
    R0 = np.asarray(PROJECTOR.R, np.float64)
    centre = -R0.T @ np.asarray(PROJECTOR.T, np.float64)
    turned = np.stack([math.cos(a) * R0[0] + math.sin(a) * R0[1], -math.sin(a) * R0[0] + math.cos(a) * R0[1], R0[2]])
    return ProjectorPlacement(projector=PROJECTOR.projector, R=turned, T=-turned @ centre)


CAMERA1_CENTRE = -np.asarray(RIG.R).T @ np.asarray(RIG.T)


def _axis(first: int, extent: int, period: float = 16.0) -> tuple[dict[str, Any], int]:
    """8-step sinusoid of ``period`` projector px (16 unless given), gray code of words of that width
    (MSB first)."""
    bits = math.ceil(math.log2((extent + 1) / period))
    phase = {"frames": list(range(first, first + 8)), "period": period, "shift": 1, "origin": -0.5, "waveform": "sine"}
    gray = {
        "frames": list(range(first + 8, first + 8 + bits)),
        "word": period,
        "order": "msb_first",
        "origin": -0.5,
        "inverse_frames": None,
        "inverted": False,
    }
    return {"phase": [phase], "gray": gray}, first + 8 + bits


def codec_dict(axes: str, periods: dict[str, float] | None = None) -> dict[str, Any]:
    """The codec of ``axes`` (``"u"``: vertical fringes only; ``"uv"``: both axes), white and black
    last; ``periods`` the phase period of an axis other than 16 projector px."""
    spec: dict[str, Any] = {}
    n = 0
    for axis in axes:
        spec[axis], n = _axis(n, PROJ_W if axis == "u" else PROJ_H, (periods or {}).get(axis, 16.0))
    return {
        "codec": "gcps-codec/1",
        "frames": n + 2,
        "projector": {"width": PROJ_W, "height": PROJ_H},
        "white": [n],
        "black": [n + 1],
        "axes": spec,
    }


def codec(axes: str, periods: dict[str, float] | None = None) -> Any:
    return codec_from_dict(codec_dict(axes, periods))


def facing_both(scene: Scene, points_mm: np.ndarray, max_angle_deg: float = 60.0) -> np.ndarray:
    """``(H, W)`` bool: points whose surface normal is within ``max_angle_deg`` of the direction to
    each camera's centre (the normal from the scene's height field, by central differences)."""
    X, Y, _ = PLACEMENT.scene_coordinates(points_mm)
    step = 1e-4
    with np.errstate(invalid="ignore"):
        hx = (scene.height_mm(X + step, Y) - scene.height_mm(X - step, Y)) / (2 * step)
        hy = (scene.height_mm(X, Y + step) - scene.height_mm(X, Y - step)) / (2 * step)
    normal = -hx[..., None] * PLACEMENT.e_x - hy[..., None] * PLACEMENT.e_y + PLACEMENT.e_n
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    limit = math.cos(math.radians(max_angle_deg))
    facing = np.ones(points_mm.shape[:2], bool)
    for centre in (np.zeros(3), CAMERA1_CENTRE):
        view = centre - points_mm
        view /= np.linalg.norm(view, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore"):
            facing &= (normal * view).sum(axis=-1) > limit
    return facing


def lit_in_both(points_mm: np.ndarray, lit0: np.ndarray, lit1: np.ndarray, rig: StereoRig | None = None) -> np.ndarray:
    """``(H0, W0)`` bool: camera-0 pixels lit (``lit0``) whose true point ``points_mm`` (camera 0's
    frame, mm) projects into camera 1 of ``rig`` (default :data:`RIG`; nearest pixel, 1 px inside
    its border) on a pixel lit there (``lit1``): the pixels a stereo measurement can reach."""
    import cv2

    rig = rig or RIG
    ok = np.isfinite(points_mm).all(axis=-1) & lit0
    rvec, _ = cv2.Rodrigues(np.asarray(rig.R, np.float64))
    cam1 = rig.camera1
    xy, _ = cv2.projectPoints(
        np.where(ok[..., None], points_mm, 0.0).reshape(-1, 1, 3),
        rvec,
        np.asarray(rig.T, np.float64),
        np.asarray(cam1.K, np.float64),
        np.asarray(cam1.dist, np.float64),
    )
    x, y = np.rint(xy.reshape(*points_mm.shape[:2], 2)).astype(int).transpose(2, 0, 1)
    both = ok & (x >= 1) & (x < cam1.width_px - 1) & (y >= 1) & (y < cam1.height_px - 1)
    both[both] = lit1[y[both], x[both]]
    return both


CALIBRATED_RIG = StereoRig(
    camera0=CAMERA0,
    camera1=CAMERA1,
    R=_POSE1.R,
    T=_POSE1.T,
    projector=StereoProjector(PROJ_W, PROJ_H, K=LENS.K, dist=LENS.dist, R=_PROJ.R, T=_PROJ.T),
)
""":data:`RIG` with its projector calibrated: :data:`PROJECTOR`, which lights the renders."""
