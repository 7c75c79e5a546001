"""The virtual rig's stereo captures: two cameras of a stereo rig and a projector that lights the scene.

A stereo rig's file may hold its projector's size alone (the projector only labels the surface),
but rendering needs the projector's place and lens: :func:`render_stereo_capture` takes them
separately (:class:`ProjectorPlacement`; by default the rig's calibrated projector, or a pinhole
projector half-way between the cameras, aimed at the centre of camera 0's field on the scene's plane).

Each camera is rendered as a pinhole rig of that camera and the projector (the scene placed in
camera 0's frame, moved into camera 1's by ``X_c1 = R X_c0 + T``), through the same caster and codec
renderer as every model (:mod:`metrology.core.simulate.cast`): lens distortion on every device,
shadows of the projector's light, and each camera's own occlusions (a point one camera cannot see
is simply not in its image). The ground truth is camera 0's, per pixel, in camera 0's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.model import Codec
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, PinholeRig, look_at_rig
from metrology.core.geometry.rig_file import Matrix3
from metrology.core.geometry.stereo import StereoRig
from metrology.core.scenes import Scene
from metrology.core.simulate.cast import CastTruth, ScenePlacement, cast_truth
from metrology.core.simulate.frames import RenderedCapture, _from_cast
from metrology.core.simulate.options import SimulationOptions
from metrology.core.simulate.series import stack_seed

PROJECTOR_FIELD_MARGIN = 1.25
"""The default projector's image spans this many times camera 0's field at the scene."""


@dataclass(frozen=True)
class ProjectorPlacement:
    """A projector for rendering: its lens (``projector``: size in the codec's units, ``K``, ``dist``)
    and its pose ``X_p = R X_c0 + T`` (mm) relative to camera 0."""

    projector: PinholeProjector
    R: Matrix3
    T: tuple[float, float, float]

    def pinhole_rig(self, camera: PinholeCamera, R_c: np.ndarray, T_c: np.ndarray) -> PinholeRig:
        """The pinhole rig of ``camera`` (posed ``X_c = R_c X_c0 + T_c``) and this projector:
        ``X_p = R R_c^T X_c + T - R R_c^T T_c``."""
        Rp, Tp = np.asarray(self.R, np.float64), np.asarray(self.T, np.float64)
        R = Rp @ R_c.T
        T = Tp - R @ T_c
        return PinholeRig(camera=camera, projector=self.projector, R=_matrix(R), T=_triple(T))


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2]))


def _matrix(R: np.ndarray) -> Matrix3:
    return (_triple(R[0]), _triple(R[1]), _triple(R[2]))


def field_centre(placement: ScenePlacement) -> np.ndarray:
    """``(3,)`` float64 mm: where camera 0's optical axis ``t (0, 0, 1)`` meets the scene's
    reference plane, ``t = (e_n . o) / e_n_z`` (``o`` the placement's origin): the centre of camera
    0's field on the plane. The scene's origin itself may lie far outside that field (the scenes are
    laid out around ``X = 352 mm``, the paper's field centre). A plane along the axis gives the
    origin."""
    normal = np.asarray(placement.e_n, np.float64)
    origin = np.asarray(placement.origin_mm, np.float64)
    if abs(normal[2]) < 1e-9:
        return origin
    return np.array([0.0, 0.0, float(normal @ origin) / normal[2]])


def default_projector(rig: StereoRig, placement: ScenePlacement, field_width_mm: float) -> ProjectorPlacement:
    """The rig's calibrated projector, else a distortion-free pinhole projector of the rig's
    projector size centred half-way between the cameras (a tenth of the baseline above them),
    aimed at camera 0's field (:func:`field_centre`), its image :data:`PROJECTOR_FIELD_MARGIN`
    times the field."""
    proj = rig.projector
    if proj.calibrated:
        assert proj.K is not None and proj.R is not None and proj.T is not None
        lens = PinholeProjector(width=proj.width, height=proj.height, K=proj.K, dist=proj.dist)
        return ProjectorPlacement(projector=lens, R=proj.R, T=proj.T)
    R, T = np.asarray(rig.R), np.asarray(rig.T)
    c1 = -R.T @ T
    centre = 0.5 * c1 + np.array([0.0, -0.1 * rig.baseline_mm, 0.0])
    target = field_centre(placement)
    distance = float(np.linalg.norm(target - centre))
    fx = proj.width * distance / (PROJECTOR_FIELD_MARGIN * field_width_mm)
    K = ((fx, 0.0, (proj.width - 1) / 2), (0.0, fx, (proj.height - 1) / 2), (0.0, 0.0, 1.0))
    lens = PinholeProjector(width=proj.width, height=proj.height, K=K)
    aimed = look_at_rig(rig.camera0, lens, _triple(centre), _triple(target))
    return ProjectorPlacement(projector=lens, R=aimed.R, T=aimed.T)


def lighting_projector(
    rig: StereoRig,
    placement: ScenePlacement,
    projector: ProjectorPlacement | None = None,
    field_width_mm: float | None = None,
) -> ProjectorPlacement:
    """``projector``, else :func:`default_projector` for ``placement`` (``field_width_mm`` default:
    camera 0's field on the scene's plane, ``W0 * |c| / fx0`` with ``c`` its :func:`field_centre`)."""
    if projector is not None:
        return projector
    distance = float(np.linalg.norm(field_centre(placement)))
    width = field_width_mm or rig.camera0.width_px * distance / rig.camera0.K[0][0]
    return default_projector(rig, placement, width)


def camera_rigs(
    rig: StereoRig, placement: ScenePlacement, projector: ProjectorPlacement
) -> tuple[tuple[PinholeRig, ScenePlacement], tuple[PinholeRig, ScenePlacement]]:
    """Per camera, camera 0 first: the pinhole rig of that camera and ``projector``, and the scene's
    placement moved into that camera's frame (``X_c1 = R X_c0 + T``): what every stereo render casts."""
    poses = ((np.eye(3), np.zeros(3)), (np.asarray(rig.R, np.float64), np.asarray(rig.T, np.float64)))
    first, second = (
        (projector.pinhole_rig(camera, R_c, T_c), placement.in_frame(R_c, T_c))
        for camera, (R_c, T_c) in zip((rig.camera0, rig.camera1), poses, strict=True)
    )
    return first, second


@dataclass(frozen=True, eq=False)
class StereoCapture:
    """A rendered stereo capture.

    Attributes
    ----------
    cameras : (RenderedCapture, RenderedCapture)
        Each camera's capture (its images, and the truth of its pixels in its own frame).
    projector : ProjectorPlacement
        The projector that lit it.
    """

    cameras: tuple[RenderedCapture, RenderedCapture]
    projector: ProjectorPlacement

    @property
    def images(self) -> tuple[np.ndarray, np.ndarray]:
        """Each camera's ``(frames, H_c, W_c)`` stack, camera 0 first (what :func:`~metrology.core.measure.measure`
        takes)."""
        return (self.cameras[0].images, self.cameras[1].images)

    @property
    def points_mm(self) -> npt.NDArray[np.float64]:
        """``(H0, W0, 3)`` float64: the point each camera-0 pixel centre sees, camera 0's frame, mm
        (NaN where not lit)."""
        return self.cameras[0].points_mm


@dataclass(frozen=True, eq=False)
class StereoCast:
    """Both cameras' ray-cast ground truth of a placed scene (:func:`cast_stereo`): what
    :func:`render_stereo_capture` renders frames from (kept to render many noisy captures of one scene).

    Attributes
    ----------
    placements : (ScenePlacement, ScenePlacement)
        The scene's placement in each camera's frame.
    truths : (CastTruth, CastTruth)
        Each camera's pixel centres' truth.
    sub_rays : (CastTruth, CastTruth)
        Each camera's sub-pixel rays' truth (``supersample`` per pixel and axis; the truths when 1).
    projector : ProjectorPlacement
    supersample : int
    """

    placements: tuple[ScenePlacement, ScenePlacement]
    truths: tuple[CastTruth, CastTruth]
    sub_rays: tuple[CastTruth, CastTruth]
    projector: ProjectorPlacement
    supersample: int

    def check_supersample(self, supersample: int) -> None:
        """Raise ValueError unless this cast has ``supersample`` rays per pixel side (a kept cast
        handed to a render with its options)."""
        if self.supersample != supersample:
            raise ValueError(f"the cast has {self.supersample} rays per pixel side, the options {supersample}")


def cast_stereo(
    rig: StereoRig,
    scene: Scene,
    codec: Codec,
    placement: ScenePlacement,
    *,
    projector: ProjectorPlacement | None = None,
    supersample: int = 1,
    field_width_mm: float | None = None,
) -> StereoCast:
    """Ray-cast ``scene`` (placed by ``placement`` in camera 0's frame) through each camera of ``rig``
    with ``projector``'s light (default :func:`default_projector`; ``field_width_mm`` default:
    camera 0's field at the placement's distance). ``codec`` gives the projector's size, which must
    be the rig's."""
    rig.check_projector((codec.projector_width, codec.projector_height))
    projector = lighting_projector(rig, placement, projector, field_width_mm)
    placements, truths, sub_rays = [], [], []
    for pinhole, where in camera_rigs(rig, placement, projector):
        prepared = pinhole.prepare(pinhole.shape, (codec.projector_width, codec.projector_height))
        truth = cast_truth(prepared, scene, where)
        placements.append(where)
        truths.append(truth)
        sub_rays.append(truth if supersample == 1 else cast_truth(prepared, scene, where, supersample=supersample))
    return StereoCast(
        placements=(placements[0], placements[1]),
        truths=(truths[0], truths[1]),
        sub_rays=(sub_rays[0], sub_rays[1]),
        projector=projector,
        supersample=supersample,
    )


def render_stereo_capture(
    rig: StereoRig,
    scene: Scene,
    codec: Codec,
    options: SimulationOptions | None = None,
    *,
    placement: ScenePlacement,
    projector: ProjectorPlacement | None = None,
    field_width_mm: float | None = None,
    cast: StereoCast | None = None,
) -> StereoCapture:
    """Render ``scene`` placed by ``placement`` (camera 0's frame) as seen by both cameras of ``rig``
    under ``codec``'s patterns (module docstring).

    Parameters
    ----------
    rig : StereoRig
    scene : Scene
    codec : Codec
        Its projector size must be the rig's.
    options : SimulationOptions, optional
        Default noise-free 16-bit; each camera gets its own noise (seeded from the options, the
        scene and the camera's index).
    placement : ScenePlacement
        Where the scene's reference plane sits in camera 0's frame.
    projector : ProjectorPlacement, optional
        Default :func:`default_projector` (``field_width_mm`` default: camera 0's field at the
        placement's distance).
    cast : StereoCast, optional
        The scene already cast (:func:`cast_stereo` with ``options.supersample``): only the frames
        are rendered.
    """
    opts = options if options is not None else SimulationOptions()
    if cast is None:
        cast = cast_stereo(
            rig,
            scene,
            codec,
            placement,
            projector=projector,
            supersample=opts.supersample,
            field_width_mm=field_width_mm,
        )
    else:
        cast.check_supersample(opts.supersample)
    seed = stack_seed(opts, scene)
    rendered = []
    for index in range(2):
        camera_seed = np.random.SeedSequence([*seed.entropy, index]) if index else seed  # type: ignore[misc]
        rendered.append(
            _from_cast(
                scene, cast.placements[index], cast.truths[index], cast.sub_rays[index], codec, opts, camera_seed
            )
        )
    return StereoCapture(cameras=(rendered[0], rendered[1]), projector=cast.projector)
