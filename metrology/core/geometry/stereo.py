"""The stereo model: two calibrated pinhole cameras and a projector that only labels the surface.

Rig file (``"model": "stereo"``; see docs/stereo.md)::

    {"model": "stereo",
     "cameras": [
       {"width_px": 1280, "height_px": 1024, "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
        "dist": [k1, k2, p1, p2, k3]},
       {"width_px": 1280, "height_px": 1024, "K": [[...]], "dist": [...],
        "R": [[...], [...], [...]], "T": [tx, ty, tz]}],
     "projector": {"width": 1920, "height": 1080}}

Camera 0's frame is the model frame (mm, OpenCV's axes); camera 0 has no ``R``, ``T``. Camera 1's
pose is ``X_c1 = R X_c0 + T`` (OpenCV's ``stereoCalibrate``), ``T`` in mm and not zero. Pixel
centres at integer coordinates; ``K`` and ``dist`` as in pinhole rig files
(:mod:`metrology.core.geometry.rig_file`). The ``projector`` holds at least its size in the
codec's units (``width``, ``height``); with ``K`` (and optionally ``dist``), ``R`` and ``T``
(``X_p = R X_c0 + T``) it is calibrated too (the depth never needs it: the two cameras
triangulate; the virtual rig lights its scenes with it, and measurement fuses the camera-projector
pairs with the camera pair: :mod:`metrology.core.geometry.stereo_fusion`).

Measurement (:class:`PreparedStereo`) is in :mod:`metrology.core.geometry.stereo_match`.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from metrology.core.geometry.base import (
    GeometryError,
    GeometryModel,
    GeometryOptions,
    PreparedGeometry,
    short_number,
)
from metrology.core.geometry.pinhole import PinholeCamera
from metrology.core.geometry.rig_file import (
    Matrix3,
    RigFileError,
    check_coded_axis,
    check_projector_size,
    check_rotation,
    checked_keys,
    distortion_coefficients,
    image_side,
    intrinsics,
    matrix3,
    positive,
    translation,
)

MODEL_NAME = "stereo"
TOP_KEYS: tuple[str, ...] = ("model", "cameras", "projector")
CAMERA0_KEYS: tuple[str, ...] = ("width_px", "height_px", "K", "dist")
CAMERA1_KEYS: tuple[str, ...] = ("width_px", "height_px", "K", "dist", "R", "T")
PROJECTOR_KEYS: tuple[str, ...] = ("width", "height", "K", "dist", "R", "T")
CAMERA_COUNT = 2
"""Cameras of a stereo rig file (the list leaves room for more later)."""
MIN_BASELINE_MM = 1e-6
"""Smallest ``|T|`` of camera 1 (two cameras at one place see no depth)."""


@dataclass(frozen=True)
class StereoProjector:
    """The projector: its size in projector units (the codec's), and optionally its calibration
    (``K``, ``dist``, and its pose ``X_p = R X_c0 + T`` mm): all of ``K``, ``R``, ``T`` or none."""

    width: float
    height: float
    K: Matrix3 | None = None
    dist: tuple[float, ...] = ()
    R: Matrix3 | None = None
    T: tuple[float, float, float] | None = None

    @property
    def calibrated(self) -> bool:
        """True when ``K``, ``R`` and ``T`` are given."""
        return self.K is not None and self.R is not None and self.T is not None


def _camera(data: Any, index: int) -> tuple[PinholeCamera, Matrix3 | None, tuple[float, float, float] | None]:
    where = f"cameras[{index}]"
    if index == 0 and isinstance(data, Mapping):
        posed = [key for key in ("R", "T") if key in data]
        if posed:
            raise RigFileError(
                f"{where} has unknown key {posed[0]!r}: camera 0's frame is the rig's frame "
                "(only camera 1 has a pose R, T)"
            )
    keys = CAMERA0_KEYS if index == 0 else CAMERA1_KEYS
    required = ("width_px", "height_px", "K") if index == 0 else ("width_px", "height_px", "K", "R", "T")
    cam = checked_keys(data, keys, required, where)
    camera = PinholeCamera(
        width_px=image_side(cam["width_px"], f"{where} width_px"),
        height_px=image_side(cam["height_px"], f"{where} height_px"),
        K=intrinsics(cam["K"], f"{where} K"),
        dist=distortion_coefficients(cam.get("dist"), f"{where} dist"),
    )
    if index == 0:
        return camera, None, None
    R = matrix3(cam["R"], f"{where} R")
    check_rotation(R, f"{where} R")
    return camera, R, translation(cam["T"], f"{where} T")


def _projector(data: Any) -> StereoProjector:
    proj = checked_keys(data, PROJECTOR_KEYS, ("width", "height"), "projector")
    given = [key for key in ("K", "R", "T") if key in proj]
    if given and len(given) < 3:
        missing = next(key for key in ("K", "R", "T") if key not in proj)
        raise RigFileError(
            f"projector is missing key {missing!r}: a calibrated projector has K, R and T "
            f"(it has {', '.join(given)}); a projector with its size alone is not calibrated"
        )
    if "dist" in proj and not given:
        raise RigFileError("projector has 'dist' without K, R, T: give its whole calibration or its size alone")
    R = None
    if "R" in proj:
        R = matrix3(proj["R"], "projector R")
        check_rotation(R, "projector R")
    return StereoProjector(
        width=positive(proj["width"], "projector width"),
        height=positive(proj["height"], "projector height"),
        K=intrinsics(proj["K"], "projector K") if "K" in proj else None,
        dist=distortion_coefficients(proj.get("dist"), "projector dist"),
        R=R,
        T=translation(proj["T"], "projector T") if "T" in proj else None,
    )


def _rows(matrix: Matrix3) -> list[list[float]]:
    return [list(row) for row in matrix]


def _size(x: float) -> float | int:
    return int(x) if float(x).is_integer() else float(x)


def _camera_dict(camera: PinholeCamera) -> dict[str, Any]:
    data: dict[str, Any] = {"width_px": camera.width_px, "height_px": camera.height_px, "K": _rows(camera.K)}
    if camera.dist:
        data["dist"] = list(camera.dist)
    return data


@dataclass(frozen=True)
class StereoRig(GeometryModel):
    """Two calibrated cameras and a projector (see the module docstring); immutable and hashable.

    Attributes
    ----------
    camera0, camera1 : PinholeCamera
    R, T : camera 1's pose, ``X_c1 = R X_c0 + T`` (mm)
    projector : StereoProjector
    """

    camera0: PinholeCamera
    camera1: PinholeCamera
    R: Matrix3
    T: tuple[float, float, float]
    projector: StereoProjector

    model: ClassVar[str] = MODEL_NAME
    label: ClassVar[str] = "Two calibrated cameras and a projector (stereo)"
    short_label: ClassVar[str] = "stereo"
    requires_reference: ClassVar[bool] = False
    unreferenced_result: ClassVar[str] = "depth"
    frame: ClassVar[str] = "camera"
    sigma_direction: ClassVar[str] = "camera ray"
    cameras: ClassVar[int] = CAMERA_COUNT

    def __post_init__(self) -> None:
        check_rotation(self.R, "cameras[1] R")
        if math.sqrt(sum(t * t for t in self.T)) < MIN_BASELINE_MM:
            raise RigFileError(f"cameras[1] T must not be zero (the baseline between the cameras), got {list(self.T)}")

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StereoRig:
        """Parse and validate a rig file's JSON object; :class:`RigFileError` names the bad key."""
        data = checked_keys(data, TOP_KEYS, TOP_KEYS, "stereo rig")
        if data["model"] != MODEL_NAME:
            raise RigFileError(f"rig model must be {MODEL_NAME!r} here, got {data['model']!r}")
        cameras = data["cameras"]
        if not isinstance(cameras, (list, tuple)) or len(cameras) != CAMERA_COUNT:
            got = f"{len(cameras)} cameras" if isinstance(cameras, (list, tuple)) else repr(cameras)
            raise RigFileError(f"cameras must be a list of exactly {CAMERA_COUNT} cameras, got {got}")
        camera0, _, _ = _camera(cameras[0], 0)
        camera1, R, T = _camera(cameras[1], 1)
        assert R is not None and T is not None
        return cls(camera0=camera0, camera1=camera1, R=R, T=T, projector=_projector(data["projector"]))

    def to_dict(self) -> dict[str, Any]:
        """The rig file's JSON object (keys in the contract's order; ``dist`` omitted when empty)."""
        camera1 = {**_camera_dict(self.camera1), "R": _rows(self.R), "T": list(self.T)}
        proj = self.projector
        projector: dict[str, Any] = {"width": _size(proj.width), "height": _size(proj.height)}
        if proj.K is not None:
            projector["K"] = _rows(proj.K)
        if proj.dist:
            projector["dist"] = list(proj.dist)
        if proj.R is not None:
            projector["R"] = _rows(proj.R)
        if proj.T is not None:
            projector["T"] = list(proj.T)
        return {"model": MODEL_NAME, "cameras": [_camera_dict(self.camera0), camera1], "projector": projector}

    # ------------------------------------------------------------------ what the model says
    @property
    def shape(self) -> tuple[int, int]:
        """Camera 0's frame ``(height_px, width_px)``: results lie on its pixel grid."""
        return (self.camera0.height_px, self.camera0.width_px)

    @property
    def projector_size(self) -> tuple[float, float]:
        """The projector's ``(width, height)`` in projector units (the codec's)."""
        return (self.projector.width, self.projector.height)

    @property
    def camera_shapes(self) -> tuple[tuple[int, int], ...]:
        """Every camera's frame ``(height_px, width_px)``, camera 0 first."""
        return tuple((c.height_px, c.width_px) for c in (self.camera0, self.camera1))

    @property
    def camera_centre_mm(self) -> np.ndarray:
        """The origin: camera 0's frame is the model frame."""
        return np.zeros(3)

    @property
    def baseline_mm(self) -> float:
        """``|T|``: the distance between the cameras' centres, mm."""
        return math.sqrt(sum(t * t for t in self.T))

    def scene_distance_mm(self, field_width_mm: float) -> float:
        """``fx FW / W`` of camera 0 (pinhole approximation)."""
        return self.camera0.K[0][0] * field_width_mm / self.camera0.width_px

    def auto_axis(self) -> str:
        """The projector axis matched along the epipolar lines: ``u``, the projector's columns
        (the cameras sit side by side, as stereo rigs are built)."""
        return "u"

    def check_projector(self, projector_size: tuple[float, float]) -> None:
        """:class:`GeometryError` naming both sizes unless the codec's projector is the rig's."""
        check_projector_size(projector_size, self.projector.width, self.projector.height)

    def check_codec(
        self, projector_size: tuple[float, float], coded_axes: Collection[str], options: GeometryOptions | None = None
    ) -> None:
        """The codec's projector must be the rig's, and it must code the axis matched between the cameras."""
        self.check_projector(projector_size)
        options = options or GeometryOptions()
        if options.method != "plane":
            raise GeometryError(
                f"a stereo rig triangulates the two cameras' rays; method {options.method!r} is not one of its "
                "options (leave it at 'plane')"
            )
        axis = self.auto_axis() if options.triangulate == "auto" else options.triangulate
        check_coded_axis(axis, options.triangulate, coded_axes, "stereo rig matches between its cameras")
        if options.match == "2d":
            missing = [a for a in ("u", "v") if a not in coded_axes]
            if missing:
                raise GeometryError(
                    f"the 2-D match (match '2d') needs both projector axes coded; the codec lacks {', '.join(missing)}"
                )

    def value_rows(self) -> list[tuple[str, str]]:
        """Each camera (size, K, distortion), camera 1's pose, the baseline and the projector."""
        rows = []
        for i, cam in enumerate((self.camera0, self.camera1)):
            text = f"{cam.width_px} x {cam.height_px} px, K {short_number(cam.K)}"
            rows.append((f"camera {i}", text + (f", dist {short_number(cam.dist, 4)}" if cam.dist else "")))
        rows += [
            ("camera 1 R", short_number(self.R)),
            ("camera 1 T", f"{short_number(self.T)} mm"),
            ("baseline", f"{short_number(self.baseline_mm)} mm"),
        ]
        proj = self.projector
        text = f"{short_number(proj.width)} x {short_number(proj.height)}"
        if proj.calibrated:
            text += f", K {short_number(proj.K)}, R {short_number(proj.R)}, T {short_number(proj.T)} mm"
        else:
            text += " (not calibrated)"
        rows.append(("projector", text))
        return rows

    def summary(self) -> str:
        """Both cameras' focal lengths and the baseline, in one line."""
        return (
            f"stereo: camera 0 fx {self.camera0.K[0][0]:.2f} px, camera 1 fx {self.camera1.K[0][0]:.2f} px, "
            f"baseline {self.baseline_mm:.2f} mm" + ("" if self.projector.calibrated else ", projector not calibrated")
        )

    def prepare(
        self,
        shape: tuple[int, int] | None = None,
        projector_size: tuple[float, float] | None = None,
        options: GeometryOptions | None = None,
    ) -> PreparedGeometry:
        """The model prepared for camera 0's frame (see :mod:`.stereo_match`): cached per rig and
        matched axis (tables built once)."""
        from metrology.core.geometry.stereo_match import prepare_stereo

        options = options or GeometryOptions()
        if shape is not None and tuple(shape) != self.shape:
            raise GeometryError(
                f"camera 0's frames are {shape[1]}x{shape[0]} px but the rig's camera 0 is "
                f"{self.camera0.width_px}x{self.camera0.height_px} px"
            )
        if projector_size is not None:
            self.check_projector(projector_size)
        self.check_codec((self.projector.width, self.projector.height), ("u", "v"), options)
        axis = self.auto_axis() if options.triangulate == "auto" else options.triangulate
        return prepare_stereo(self, axis, options.match)
