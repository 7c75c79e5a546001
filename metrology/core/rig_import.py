"""Import a pinhole or a stereo rig from calibration outputs: matrices in text, OpenCV FileStorage,
npz/npy, JSON.

A *source* (``SRC``) names one matrix or vector:

- ``FILE`` (any other extension): a plain-text matrix, numbers separated by spaces, tabs or
  commas, one row per line (CRLF or LF; ``[ ] ;`` are ignored);
- ``FILE.yml#NODE`` / ``FILE.yaml#NODE`` / ``FILE.xml#NODE``: a node of an OpenCV FileStorage
  file (``!!opencv-matrix`` / ``type_id="opencv-matrix"``, or a plain (nested) sequence of
  numbers; float or double); ``NODE`` may be a dotted path into nested maps;
- ``FILE.npz#KEY``: an array of a NumPy ``.npz``; ``FILE.npy``: a NumPy array;
- ``FILE.json#dotted.key``: a number list (or nested lists) inside a JSON document, each dotted
  component a key (or a list index).

A value is read by its element count whatever its shape (:data:`COUNTS`): ``camera_K`` and
``projector_K`` 9 (row-major 3x3), ``camera_dist`` / ``projector_dist`` 4, 5, 8, 12 or 14,
``R`` 9, ``rvec`` 3 (a Rodrigues vector, instead of ``R``), ``T`` 3 (mm); any other count is a
``ValueError`` naming the key, the source and the count. :func:`opencv_sources` recognises the
node names of common FileStorage layouts (:data:`OPENCV_NODE_NAMES`).

Two cameras (a stereo rig, :data:`STEREO_KEYS`): ``camera0_K``, ``camera0_dist``, ``camera1_K``,
``camera1_dist``, ``R``/``rvec`` and ``T`` (camera 1's pose, ``X_c1 = R X_c0 + T``, mm), and
optionally a calibrated projector ``projector_K``, ``projector_dist``, ``projector_R`` /
``projector_rvec`` and ``projector_T`` (``X_p = R_p X_c0 + T_p``). A FileStorage file is a
two-camera file (:func:`opencv_model`) when it has ``M1 D1 M2 D2``, a pose (``R T`` or
``Rlr Tlr``) and no projector node (``M4``, ``D4``, a name starting with ``proj_`` or
``projector_``): then ``M1``/``D1`` are camera 0, ``M2``/``D2`` camera 1 (:data:`STEREO_NODE_NAMES`).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from metrology.core.geometry.base import GeometryError, GeometryModel
from metrology.core.geometry.pinhole import PinholeRig
from metrology.core.geometry.stereo import StereoRig

KEYS: tuple[str, ...] = ("camera_K", "camera_dist", "projector_K", "projector_dist", "R", "rvec", "T")
"""The values ``--set KEY=SRC`` accepts."""

COUNTS: dict[str, tuple[int, ...]] = {
    "camera_K": (9,),
    "projector_K": (9,),
    "camera_dist": (0, 4, 5, 8, 12, 14),
    "projector_dist": (0, 4, 5, 8, 12, 14),
    "R": (9,),
    "rvec": (3,),
    "T": (3,),
}
"""Element counts each key accepts."""

STEREO_KEYS: tuple[str, ...] = (
    "camera0_K",
    "camera0_dist",
    "camera1_K",
    "camera1_dist",
    "R",
    "rvec",
    "T",
    "projector_K",
    "projector_dist",
    "projector_R",
    "projector_rvec",
    "projector_T",
)
"""The values ``--set KEY=SRC`` accepts for a stereo rig (``R``/``rvec``/``T``: camera 1's pose)."""

COUNTS.update(
    {
        "camera0_K": COUNTS["camera_K"],
        "camera1_K": COUNTS["camera_K"],
        "camera0_dist": COUNTS["camera_dist"],
        "camera1_dist": COUNTS["camera_dist"],
        "projector_R": COUNTS["R"],
        "projector_rvec": COUNTS["rvec"],
        "projector_T": COUNTS["T"],
    }
)

PINHOLE = PinholeRig.model
STEREO = StereoRig.model
MODEL_CHOICES: tuple[str, ...] = (PINHOLE, STEREO)
"""The rig models an import writes (``--model``)."""

SET_KEYS: dict[str, tuple[str, ...]] = {PINHOLE: KEYS, STEREO: STEREO_KEYS}
"""The ``--set`` keys of each model."""

ROTATIONS: tuple[tuple[str, str], ...] = (("R", "rvec"), ("projector_R", "projector_rvec"))
"""Keys giving one rotation as a matrix or as a Rodrigues vector (either, not both)."""

OPENCV_NODE_NAMES: dict[str, tuple[str, ...]] = {
    "camera_K": ("cam_int", "camera_matrix", "cameraMatrix", "cam_K", "camera_K", "K1", "M1", "cam_mtx", "mtx_cam"),
    "camera_dist": ("cam_dist", "dist_coeffs", "distCoeffs", "camera_dist", "cam_dist_coeffs", "D1", "dist_cam"),
    "projector_K": ("proj_int", "projector_matrix", "proj_K", "projector_K", "K2", "M2", "M4", "proj_mtx", "mtx_proj"),
    "projector_dist": ("proj_dist", "projector_dist", "proj_dist_coeffs", "D2", "D4", "dist_proj"),
    "R": ("rotation", "R", "rot", "rotation_matrix", "Rlp"),
    "rvec": ("rvec", "rotation_vector", "om"),
    "T": ("translation", "T", "tvec", "trans", "translation_vector", "Tlp"),
}
"""FileStorage node names recognised by ``--opencv`` for each key (exact names). Besides the names
of OpenCV's samples and common stereo scripts, the layout that numbers its devices (``M1 D1``
camera, ``M4 D4`` projector) and names the projector's pose from the camera ``Rlp Tlp``."""

STEREO_NODE_NAMES: dict[str, tuple[str, ...]] = {
    "camera0_K": ("M1", "K1", "cameraMatrix1", "camera_matrix_1"),
    "camera0_dist": ("D1", "distCoeffs1", "dist_coeffs_1"),
    "camera1_K": ("M2", "K2", "cameraMatrix2", "camera_matrix_2"),
    "camera1_dist": ("D2", "distCoeffs2", "dist_coeffs_2"),
    "R": ("R", "Rlr"),
    "rvec": ("rvec", "om"),
    "T": ("T", "Tlr"),
}
"""FileStorage node names of a two-camera file (OpenCV's ``stereo_calib`` sample, ``Rlr Tlr`` of
structured-light suites): camera 1's pose is ``R``/``T``. A stereo file names no projector."""

NODE_NAMES: dict[str, dict[str, tuple[str, ...]]] = {PINHOLE: OPENCV_NODE_NAMES, STEREO: STEREO_NODE_NAMES}
"""The node names recognised for each model."""

STEREO_SIGNATURE: tuple[tuple[str, ...], ...] = (("M1",), ("D1",), ("M2",), ("D2",), ("R", "Rlr"), ("T", "Tlr"))
"""A two-camera file has one name of each group ..."""

PROJECTOR_NODES: tuple[str, ...] = ("M4", "D4")
PROJECTOR_NODE_PREFIXES: tuple[str, ...] = ("proj_", "projector_")
"""... and none of these projector nodes (exact names, or names starting with a prefix)."""

CAMERA_SIZE_NODES: dict[str, str] = {
    "img_shape": "HW",
    "image_shape": "HW",
    "image_size": "WH",
    "imageSize": "WH",
    "img_size": "WH",
    "camera_size": "WH",
    "S": "WH",
}
"""Nodes giving the camera image size: ``HW`` a NumPy shape (rows, cols), ``WH`` an OpenCV Size."""


class RigImportError(ValueError):
    """A source cannot be read or holds the wrong number of values (the message names both)."""


@dataclass(frozen=True)
class ReadValue:
    """A value read from a source: flat float64 values and the source that gave them."""

    values: np.ndarray
    source: str


# --------------------------------------------------------------------------- sources
def read_source(spec: str, key: str = "value") -> ReadValue:
    """Read the matrix or vector ``spec`` names (see the module docstring) as flat float64 values.

    Raises
    ------
    RigImportError
        If the file is missing or malformed, the node/key is absent, or a value is not a
        finite number; the message names ``key`` and ``spec``.
    """
    path_text, _, node = spec.rpartition("#") if "#" in spec else (spec, "", "")
    path = Path(path_text)
    ext = path.suffix.lower()
    where = f"{key} from {spec!r}"
    if not path.is_file():
        raise RigImportError(f"{where}: file {str(path)!r} does not exist")
    try:
        if ext in (".yml", ".yaml", ".xml"):
            if not node:
                raise RigImportError(f"{where}: name the FileStorage node, as {path_text}#NODE")
            values = _read_filestorage(path, node, where)
        elif ext == ".npz":
            if not node:
                raise RigImportError(f"{where}: name the array, as {path_text}#KEY")
            with np.load(path, allow_pickle=False) as archive:
                if node not in archive.files:
                    raise RigImportError(f"{where}: no array {node!r} (the file has {', '.join(archive.files)})")
                values = np.asarray(archive[node])
        elif ext == ".npy":
            if node:
                raise RigImportError(f"{where}: a .npy file holds one array; drop '#{node}'")
            values = np.asarray(np.load(path, allow_pickle=False))
        elif ext == ".json":
            if not node:
                raise RigImportError(f"{where}: name the value, as {path_text}#dotted.key")
            values = _read_json(path, node, where)
        else:
            if node:
                raise RigImportError(f"{where}: a text matrix file takes no '#{node}'")
            values = _read_text(path, where)
    except RigImportError:
        raise
    except (OSError, ValueError, SystemError, cv2.error) as exc:  # cv2 raises SystemError on some bad files
        raise RigImportError(f"{where}: cannot read it ({' '.join(str(exc).split())})") from exc
    if values.dtype.kind not in "fiu":
        raise RigImportError(f"{where}: not numbers (dtype {values.dtype})")
    flat = values.astype(np.float64).ravel()
    if not np.all(np.isfinite(flat)):
        raise RigImportError(f"{where}: holds a value that is not a finite number")
    return ReadValue(values=flat, source=spec)


_TEXT_SEPARATORS = re.compile(r"[\s,;\[\]]+")


def _read_text(path: Path, where: str) -> np.ndarray:
    text = path.read_bytes().decode("utf-8-sig", errors="strict")
    tokens = [t for t in _TEXT_SEPARATORS.split(text) if t]
    if not tokens:
        raise RigImportError(f"{where}: the text file holds no numbers")
    try:
        return np.array([float(t) for t in tokens])
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise RigImportError(f"{where}: {bad!r} is not a number") from None


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_json(path: Path, dotted: str, where: str) -> np.ndarray:
    try:
        node: Any = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise RigImportError(f"{where}: not valid JSON ({exc.msg} at line {exc.lineno})") from exc
    for part in dotted.split("."):
        if isinstance(node, Mapping) and part in node:
            node = node[part]
        elif isinstance(node, list) and part.lstrip("-").isdigit() and -len(node) <= int(part) < len(node):
            node = node[int(part)]
        else:
            raise RigImportError(f"{where}: no key {part!r} at that point of the JSON document")
    try:
        return np.asarray(node, dtype=np.float64)
    except (TypeError, ValueError):
        raise RigImportError(f"{where}: the value is not a number or a (nested) list of numbers") from None


def _read_filestorage(path: Path, dotted: str, where: str) -> np.ndarray:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise RigImportError(f"{where}: not an OpenCV FileStorage file")
        node = fs.root()
        for part in dotted.split("."):
            child = node.getNode(part) if node.isMap() else None
            if child is None or child.empty() or child.isNone():
                names = ", ".join(node.keys()) if node.isMap() else "none"
                raise RigImportError(f"{where}: no node {part!r} (nodes there: {names})")
            node = child
        return _node_values(node, where)
    finally:
        fs.release()


def _node_values(node: Any, where: str) -> np.ndarray:
    if node.isMap():
        mat = node.mat()
        if mat is None:
            raise RigImportError(f"{where}: the node is a map, not a matrix or a sequence of numbers")
        return np.asarray(mat)
    if node.isSeq():
        out: list[float] = []
        for i in range(node.size()):
            out.extend(_node_values(node.at(i), where).ravel().tolist())
        return np.array(out, dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    raise RigImportError(f"{where}: the node is not a matrix, a number or a sequence of numbers")


def check_count(key: str, value: ReadValue) -> np.ndarray:
    """The values of ``key`` after checking their count against :data:`COUNTS`."""
    if key not in COUNTS:
        raise RigImportError(f"unknown key {key!r}; expected one of {', '.join(KEYS)}")
    n = value.values.size
    allowed = COUNTS[key]
    if n not in allowed:
        expect = " or ".join(str(c) for c in allowed if c) + (" (or none)" if 0 in allowed else "")
        raise RigImportError(f"{key} from {value.source!r} has {n} element(s); {key} needs {expect}")
    return value.values


# --------------------------------------------------------------------------- --opencv
@dataclass(frozen=True)
class OpenCVScan:
    """What :func:`opencv_sources` found: the model, sources per key and the camera size if a node gives it."""

    sources: dict[str, str]
    camera_size: tuple[int, int] | None
    camera_size_node: str | None
    model: str = "pinhole"


def _filestorage_names(path: str) -> list[str]:
    """The top-level node names of FileStorage file ``path`` (RigImportError naming ``--opencv``)."""
    p = Path(path)
    if p.suffix.lower() not in (".yml", ".yaml", ".xml"):
        raise RigImportError(f"--opencv {path!r}: expected an OpenCV FileStorage .yml, .yaml or .xml file")
    if not p.is_file():
        raise RigImportError(f"--opencv {path!r}: file does not exist")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (SystemError, cv2.error) as exc:
        detail = " ".join(str(exc).split())
        raise RigImportError(f"--opencv {path!r}: not a readable FileStorage file ({detail})") from exc
    try:
        if not fs.isOpened():
            raise RigImportError(f"--opencv {path!r}: not an OpenCV FileStorage file")
        return list(fs.root().keys())
    finally:
        fs.release()


def opencv_model(names: list[str] | tuple[str, ...]) -> str:
    """:data:`STEREO` for the node names of a two-camera file (:data:`STEREO_SIGNATURE`, no
    projector node), else :data:`PINHOLE`."""
    has_pose_pair = ("R" in names and "T" in names) or ("Rlr" in names and "Tlr" in names)
    has_cameras = all(name in names for name in ("M1", "D1", "M2", "D2"))
    has_projector = any(n in PROJECTOR_NODES or n.startswith(PROJECTOR_NODE_PREFIXES) for n in names)
    return STEREO if has_cameras and has_pose_pair and not has_projector else PINHOLE


def opencv_sources(path: str, model: str | None = None) -> OpenCVScan:
    """Recognise the nodes of a FileStorage file by name: the model (``model`` when given, else
    :func:`opencv_model`) and its values (:data:`OPENCV_NODE_NAMES` for a pinhole rig,
    :data:`STEREO_NODE_NAMES` for a stereo rig).

    A key is taken only when exactly one of its recognised names is present (two names for
    the same key with different values are an error naming both). ``R`` wins over ``rvec``
    when both are present and agree.
    """
    names = _filestorage_names(path)
    chosen = model or opencv_model(names)
    if chosen not in MODEL_CHOICES:
        raise RigImportError(f"--model must be one of {', '.join(MODEL_CHOICES)}, got {chosen!r}")
    sources: dict[str, str] = {}
    for key, candidates in NODE_NAMES[chosen].items():
        found = [name for name in candidates if name in names]
        if len(found) > 1:
            values = [read_source(f"{path}#{name}", key).values for name in found]
            if any(v.shape != values[0].shape or not np.array_equal(v, values[0]) for v in values[1:]):
                raise RigImportError(
                    f"--opencv {path!r}: {key} is ambiguous: nodes {', '.join(found)} differ; give --set {key}=..."
                )
        if found:
            sources[key] = f"{path}#{found[0]}"
    if "R" in sources and "rvec" in sources:
        del sources["rvec"]
    size: tuple[int, int] | None = None
    size_node: str | None = None
    for name, order in CAMERA_SIZE_NODES.items():
        if name in names:
            v = read_source(f"{path}#{name}", "camera size").values
            if v.size == 2 and all(x > 0 and float(x).is_integer() for x in v):
                w, h = (int(v[1]), int(v[0])) if order == "HW" else (int(v[0]), int(v[1]))
                size, size_node = (w, h), f"{path}#{name} ({'rows, cols' if order == 'HW' else 'width, height'})"
                break
    return OpenCVScan(sources=sources, camera_size=size, camera_size_node=size_node, model=chosen)


# --------------------------------------------------------------------------- the rig
def _rotation(values: Mapping[str, np.ndarray], key: str, rvec_key: str) -> np.ndarray | None:
    """``values[key]`` as a (3, 3) matrix, or ``values[rvec_key]`` through ``cv2.Rodrigues``; None if neither."""
    if key in values and rvec_key in values:
        raise RigImportError(f"give {key} or {rvec_key}, not both")
    if key in values:
        return values[key].reshape(3, 3)
    if rvec_key in values:
        return np.asarray(cv2.Rodrigues(values[rvec_key].reshape(3, 1))[0])
    return None


def _check_sizes(**sizes: tuple[float, float]) -> None:
    for name, size in sizes.items():
        if len(size) != 2 or not all(math.isfinite(x) and x > 0 for x in size):
            raise RigImportError(f"{name.replace('_', ' ')} must be two positive numbers W H, got {size!r}")


def _matrix(values: Mapping[str, np.ndarray], key: str) -> list[list[float]]:
    return values[key].reshape(3, 3).tolist()


def _dist(values: Mapping[str, np.ndarray], key: str) -> list[float]:
    return values[key].tolist() if key in values else []


def rig_from_values(
    values: Mapping[str, np.ndarray], camera_size: tuple[int, int], projector_size: tuple[float, float]
) -> PinholeRig:
    """Assemble and validate the pinhole rig from values checked by :func:`check_count`.

    ``camera_size`` is ``(width_px, height_px)``; ``projector_size`` ``(width, height)`` in
    projector units. ``rvec`` (Rodrigues) is turned into ``R`` with ``cv2.Rodrigues``.
    """
    for key in ("camera_K", "projector_K", "T"):
        if key not in values:
            raise RigImportError(f"{key} is missing: give --set {key}=SRC")
    R = _rotation(values, "R", "rvec")
    if R is None:
        raise RigImportError("R is missing: give --set R=SRC (a 3x3 matrix) or --set rvec=SRC (Rodrigues)")
    _check_sizes(camera_size=camera_size, projector_size=projector_size)
    data = {
        "model": PinholeRig.model,
        "camera": {
            "width_px": camera_size[0],
            "height_px": camera_size[1],
            "K": _matrix(values, "camera_K"),
            "dist": _dist(values, "camera_dist"),
        },
        "projector": {
            "width": projector_size[0],
            "height": projector_size[1],
            "K": _matrix(values, "projector_K"),
            "dist": _dist(values, "projector_dist"),
        },
        "R": R.tolist(),
        "T": values["T"].tolist(),
    }
    return PinholeRig.from_dict(data)


def stereo_rig_dict(
    values: Mapping[str, np.ndarray], camera_size: tuple[int, int], projector_size: tuple[float, float]
) -> dict[str, Any]:
    """The stereo rig file's object (``"model": "stereo"``, docs/stereo.md) from values checked by
    :func:`check_count`: both cameras of size ``camera_size`` ``(width_px, height_px)``, camera 1's
    pose ``R``/``rvec``, ``T`` (``X_c1 = R X_c0 + T``, mm) and the projector's size
    ``(width, height)``, with its ``K``, ``dist``, ``R``, ``T`` when ``projector_K`` is given."""
    for key in ("camera0_K", "camera1_K", "T"):
        if key not in values:
            raise RigImportError(f"{key} is missing: give --set {key}=SRC")
    R = _rotation(values, "R", "rvec")
    if R is None:
        raise RigImportError("R is missing: give --set R=SRC (a 3x3 matrix) or --set rvec=SRC (Rodrigues)")
    _check_sizes(camera_size=camera_size, projector_size=projector_size)
    w, h = camera_size
    projector: dict[str, Any] = {"width": projector_size[0], "height": projector_size[1]}
    R_p = _rotation(values, "projector_R", "projector_rvec")
    calibrated = [key for key in ("projector_K", "projector_T") if key in values]
    calibrated += ["projector_R"] if R_p is not None else []
    if calibrated:
        for key in ("projector_K", "projector_R", "projector_T"):
            if key not in calibrated:
                raise RigImportError(
                    f"{key} is missing: a calibrated projector needs projector_K, projector_R (or projector_rvec) "
                    f"and projector_T; give --set {key}=SRC"
                )
        assert R_p is not None
        projector.update(
            {"K": _matrix(values, "projector_K"), "dist": _dist(values, "projector_dist"), "R": R_p.tolist()}
        )
        projector["T"] = values["projector_T"].tolist()
    elif "projector_dist" in values:
        raise RigImportError("projector_dist without projector_K: give --set projector_K=SRC too")
    return {
        "model": STEREO,
        "cameras": [
            {"width_px": w, "height_px": h, "K": _matrix(values, "camera0_K"), "dist": _dist(values, "camera0_dist")},
            {
                "width_px": w,
                "height_px": h,
                "K": _matrix(values, "camera1_K"),
                "dist": _dist(values, "camera1_dist"),
                "R": R.tolist(),
                "T": values["T"].tolist(),
            },
        ],
        "projector": projector,
    }


def stereo_from_values(
    values: Mapping[str, np.ndarray], camera_size: tuple[int, int], projector_size: tuple[float, float]
) -> GeometryModel:
    """The stereo rig of :func:`stereo_rig_dict`, validated by its model
    (:meth:`StereoRig.from_dict`; its errors become :class:`RigImportError`)."""
    try:
        return StereoRig.from_dict(stereo_rig_dict(values, camera_size, projector_size))
    except GeometryError as exc:
        raise RigImportError(str(exc)) from exc


BUILDERS: dict[str, Callable[[Mapping[str, np.ndarray], tuple[int, int], tuple[float, float]], GeometryModel]] = {
    PINHOLE: rig_from_values,
    STEREO: stereo_from_values,
}
"""The rig of each model from its values, its camera size and its projector size."""


@dataclass(frozen=True)
class ImportedRig:
    """What :func:`import_rig` read: the rig, the source of each value, the camera size and where it came from."""

    rig: GeometryModel
    sources: dict[str, str]
    camera_size: tuple[int, int]
    camera_size_from: str | None

    def summary(self) -> dict[str, Any]:
        """``model``, ``read`` (each value's source), ``camera_size`` (value and where it came from) and,
        for a pinhole rig, the axis ``triangulate auto`` picks: what ``gcps rig import`` prints and the
        rig page shows."""
        out: dict[str, Any] = {
            "model": self.rig.model,
            "read": dict(self.sources),
            "camera_size": {"value": list(self.camera_size), "from": self.camera_size_from},
        }
        auto_axis = getattr(self.rig, "auto_axis", None)
        if auto_axis is not None:
            out["triangulate_auto"] = auto_axis()
        return out


def _implied_model(sets: tuple[str, ...] | list[str]) -> str | None:
    """:data:`STEREO` when a ``--set`` names a key only a stereo rig has, else None."""
    stereo_only = set(STEREO_KEYS) - set(KEYS)
    return STEREO if any(item.partition("=")[0] in stereo_only for item in sets) else None


def import_rig(
    *,
    projector_size: tuple[float, float],
    camera_size: tuple[int, int] | None = None,
    opencv: str | None = None,
    sets: tuple[str, ...] | list[str] = (),
    model: str | None = None,
) -> ImportedRig:
    """A pinhole or stereo rig from calibration outputs: the values an OpenCV FileStorage file
    holds under the recognised node names (``opencv``, :func:`opencv_sources`) and the ``KEY=SRC``
    items of ``sets`` (:func:`read_source`; a ``--set`` overrides what ``--opencv`` found, ``R``
    and ``rvec`` replacing each other). The one import of ``gcps rig import`` and of the rig page.

    The model is ``model`` when given (``--model``), else stereo when a ``--set`` names a stereo
    key (``camera0_K``...), else what :func:`opencv_model` recognises in the ``opencv`` file,
    else pinhole. Both cameras of a stereo rig have ``camera_size``.

    Raises
    ------
    RigImportError
        Naming the source, the key or the missing value (the messages speak of ``--opencv`` and
        ``--set`` as the command's options).
    """
    if model is not None and model not in MODEL_CHOICES:
        raise RigImportError(f"--model must be one of {', '.join(MODEL_CHOICES)}, got {model!r}")
    chosen = model or _implied_model(sets)
    sources: dict[str, str] = {}
    size_from = "--camera-size" if camera_size else None
    if opencv:
        scan = opencv_sources(opencv, chosen)
        chosen = scan.model
        sources.update(scan.sources)
        if camera_size is None and scan.camera_size is not None:
            camera_size, size_from = scan.camera_size, scan.camera_size_node
    chosen = chosen or PINHOLE
    allowed = SET_KEYS[chosen]
    set_keys: set[str] = set()
    for item in sets:
        key, sep, spec = item.partition("=")
        if not sep or not spec:
            raise RigImportError(f"--set takes KEY=SRC, got {item!r}")
        if key not in allowed:
            raise RigImportError(f"--set: unknown key {key!r} for a {chosen} rig; expected one of {', '.join(allowed)}")
        sources[key] = spec
        set_keys.add(key)
    for matrix_key, rvec_key in ROTATIONS:
        if matrix_key in set_keys and rvec_key not in set_keys:
            sources.pop(rvec_key, None)  # --set R overrides a rotation vector found by --opencv
        if rvec_key in set_keys and matrix_key not in set_keys:
            sources.pop(matrix_key, None)
    if camera_size is None:
        raise RigImportError("--camera-size W H is required (no image size node was found)")
    values = {key: check_count(key, read_source(spec, key)) for key, spec in sources.items()}
    size = (int(camera_size[0]), int(camera_size[1]))
    rig = BUILDERS[chosen](values, size, (float(projector_size[0]), float(projector_size[1])))
    return ImportedRig(rig=rig, sources=sources, camera_size=size, camera_size_from=size_from)
