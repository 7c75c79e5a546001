"""The correspondence file: board, camera and projector points per pose, for users who have them.

Format (``gcps-procam-correspondences/1``, docs/procam-calibration.md)::

    {"format": "gcps-procam-correspondences/1",
     "camera_size": [W, H],                 camera image, pixels
     "projector_size": [W, H],              projector, projector units
     "poses": [{"name": "pose1",
                "camera_px":    [[x, y], ...],      N points, pixel centres at integers
                "projector_px": [[u, v], ...],      the same N points in the projector (null: not mapped)
                "object_mm":    [[X, Y, Z], ...]},  optional; default the --board points, row-major
               ...]}

Points are in the board's order (row by row, points per row first), the same order in all lists.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from metrology.core.procam.board import BoardSpec
from metrology.core.procam.poses import PoseObservation

CORRESPONDENCES_FORMAT = "gcps-procam-correspondences/1"
_TOP = ("format", "camera_size", "projector_size", "poses")
_POSE = ("name", "camera_px", "projector_px", "object_mm")


def _size(value: Any, key: str) -> tuple[int, int]:
    if (
        not isinstance(value, list)
        or len(value) != 2
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in value)
    ):
        raise ValueError(f"--correspondences: {key} must be [width, height] (positive numbers), got {value!r}")
    return round(value[0]), round(value[1])


def _points(value: Any, n_cols: int, where: str, allow_null: bool = False) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ValueError(f"--correspondences: {where} must be a non-empty list of points")
    out = np.full((len(value), n_cols), np.nan)
    for k, p in enumerate(value):
        if p is None and allow_null:
            continue
        if (
            not isinstance(p, list)
            or len(p) != n_cols
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in p)
        ):
            raise ValueError(f"--correspondences: {where}[{k}] must be a list of {n_cols} finite numbers, got {p!r}")
        out[k] = p
    return out


def read_correspondences(
    path: str | Path, board: BoardSpec
) -> tuple[list[PoseObservation], tuple[int, int], tuple[int, int]]:
    """Read a correspondence file: the poses, the camera size and the projector size.

    Raises ValueError naming ``--correspondences`` and the bad key.
    """
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"--correspondences {path}: cannot read ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"--correspondences {path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--correspondences {path}: must hold a JSON object")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise ValueError(f"--correspondences: unknown key(s) {unknown}; allowed {list(_TOP)}")
    if data.get("format") != CORRESPONDENCES_FORMAT:
        raise ValueError(f"--correspondences: format must be {CORRESPONDENCES_FORMAT!r}, got {data.get('format')!r}")
    camera_size = _size(data.get("camera_size"), "camera_size")
    projector_size = _size(data.get("projector_size"), "projector_size")
    poses_raw = data.get("poses")
    if not isinstance(poses_raw, list) or not poses_raw:
        raise ValueError("--correspondences: poses must be a non-empty list")
    poses: list[PoseObservation] = []
    for i, raw in enumerate(poses_raw):
        if not isinstance(raw, dict):
            raise ValueError(f"--correspondences: poses[{i}] must be an object")
        bad = sorted(set(raw) - set(_POSE))
        if bad:
            raise ValueError(f"--correspondences: poses[{i}] has unknown key(s) {bad}; allowed {list(_POSE)}")
        name = raw.get("name", f"pose{i + 1}")
        if not isinstance(name, str) or not name:
            raise ValueError(f"--correspondences: poses[{i}].name must be a non-empty string")
        cam = _points(raw.get("camera_px"), 2, f"poses[{i}].camera_px")
        prj = _points(raw.get("projector_px"), 2, f"poses[{i}].projector_px", allow_null=True)
        obj = _points(raw["object_mm"], 3, f"poses[{i}].object_mm") if "object_mm" in raw else None
        n = board.count if obj is None else obj.shape[0]
        if cam.shape[0] != n or prj.shape[0] != n:
            raise ValueError(
                f"--correspondences: poses[{i}] ({name}) has {cam.shape[0]} camera and "
                f"{prj.shape[0]} projector points; "
                f"expected {n} (the board {board.spec()} has {board.count})"
            )
        poses.append(PoseObservation(name=name, camera_px=cam, projector_px=prj, object_mm=obj))
    return poses, camera_size, projector_size


def correspondences_dict(
    poses: list[PoseObservation], camera_size: tuple[int, int], projector_size: tuple[int, int]
) -> dict[str, Any]:
    """The correspondence file's JSON object for poses whose board was found."""

    def pts(a: np.ndarray) -> list[list[float] | None]:
        return [[float(x) for x in row] if np.isfinite(row).all() else None for row in a]

    out = []
    for p in poses:
        if p.camera_px is None or p.projector_px is None:
            continue
        entry: dict[str, Any] = {"name": p.name, "camera_px": pts(p.camera_px), "projector_px": pts(p.projector_px)}
        if p.object_mm is not None:
            entry["object_mm"] = pts(p.object_mm)
        out.append(entry)
    return {
        "format": CORRESPONDENCES_FORMAT,
        "camera_size": list(camera_size),
        "projector_size": list(projector_size),
        "poses": out,
    }
