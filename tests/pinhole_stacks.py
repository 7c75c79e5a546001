"""The pinhole rig and codec that the pinhole tests share (command line, pipeline, app, pages), and
noise-free captures of it zipped in memory."""

from __future__ import annotations

import json

import numpy as np

from metrology.core.codecs import codec_from_dict, render_codec
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import CastTruth, ScenePlacement, cast_truth
from tests.app.stacks import png, zip_bytes

PROJ_W, PROJ_H = 640, 400
CAMERA = PinholeCamera(
    160, 120, ((420.0, 0.0, 79.5), (0.0, 421.0, 59.5), (0.0, 0.0, 1.0)), (-0.1, 0.03, 0.0005, -0.0004, 0.0)
)
PROJECTOR = PinholeProjector(
    PROJ_W, PROJ_H, ((750.0, 0.0, 320.2), (0.0, 751.0, 199.7), (0.0, 0.0, 1.0)), (0.04, -0.02, 0.0003, 0.0002)
)
RIG = look_at_rig(CAMERA, PROJECTOR, (-220.0, 6.0, 15.0), (0.0, 0.0, 600.0))
CODEC = {
    "codec": "gcps-codec/1",
    "frames": 16,
    "projector": {"width": PROJ_W, "height": PROJ_H},
    "white": [14],
    "black": [15],
    "axes": {
        "u": {
            "phase": [{"frames": list(range(8)), "period": 16.0, "shift": 1, "origin": -0.5, "waveform": "sine"}],
            "gray": {"frames": list(range(8, 14)), "word": 16.0, "order": "msb_first", "origin": -0.5},
        }
    },
}


def cast_scene(scene: str, distance_mm: float = 600.0, *, supersample: int = 1, **params: float) -> CastTruth:
    """The ground truth of scene ``scene`` (``make_scene(scene, **params)``) facing the camera at
    ``distance_mm`` (its reference plane ``Z = distance_mm``), ``supersample`` rays per pixel and axis."""
    prepared = RIG.prepare(RIG.shape, (PROJ_W, PROJ_H))
    placement = ScenePlacement.facing_camera(distance_mm)
    return cast_truth(prepared, make_scene(scene, **params), placement, supersample=supersample)


def capture_zip(scene: str, codec: dict = CODEC, **params: float) -> tuple[bytes, np.ndarray]:
    """Noise-free 16-bit frames of ``codec`` of a scene placed 600 mm in front of the camera, and the truth points."""
    prepared = RIG.prepare(RIG.shape, (PROJ_W, PROJ_H))
    truth = cast_truth(prepared, make_scene(scene, **params), ScenePlacement.facing_camera(600.0))
    images = render_codec(codec_from_dict(codec), truth.u, None)
    members = {f"frame_{i:02d}.png": png(image) for i, image in enumerate(images)}
    members["codec.json"] = json.dumps(codec).encode()
    return zip_bytes(members), truth.points_mm


STEREO_SCRIPT_NODES = {
    "size": "img_shape",
    "camera_K": "cam_int",
    "camera_dist": "cam_dist",
    "projector_K": "proj_int",
    "projector_dist": "proj_dist",
    "R": "rotation",
    "T": "translation",
}
"""The node names of a stereo calibration script (the image size as (height, width))."""

NUMBERED_DEVICE_NODES = {
    "size": "S",
    "camera_K": "M1",
    "camera_dist": "D1",
    "projector_K": "M4",
    "projector_dist": "D4",
    "R": "Rlp",
    "T": "Tlp",
}
"""The node names of a layout that numbers its devices (the image size ``S`` as (width, height))."""


def write_filestorage_yaml(path, nodes: dict[str, str] = STEREO_SCRIPT_NODES) -> None:
    """The pinhole test rig written as an OpenCV FileStorage YAML with the node names ``nodes``
    (:data:`STEREO_SCRIPT_NODES` by default: ``cam_int``, ``cam_dist``, ``proj_int``, ``proj_dist``,
    ``rotation``, ``translation`` and the image size as ``img_shape`` (height, width))."""
    import cv2

    rig = RIG
    size = [rig.camera.width_px, rig.camera.height_px]
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write(nodes["size"], np.array([size if nodes["size"] == "S" else size[::-1]], dtype=np.float64))
    fs.write(nodes["camera_K"], np.asarray(rig.camera.K, dtype=np.float64))
    fs.write(nodes["camera_dist"], np.asarray(rig.camera.dist, dtype=np.float64).reshape(1, -1))
    fs.write(nodes["projector_K"], np.asarray(rig.projector.K, dtype=np.float64))
    fs.write(nodes["projector_dist"], np.asarray(rig.projector.dist, dtype=np.float64).reshape(1, -1))
    fs.write(nodes["R"], np.asarray(rig.R, dtype=np.float64))
    fs.write(nodes["T"], np.asarray(rig.T, dtype=np.float64).reshape(3, 1))
    fs.release()
