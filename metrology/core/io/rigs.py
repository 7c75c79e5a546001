"""Rig files (JSON; docs/file-formats.md)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from metrology.core.geometry.base import GeometryError, GeometryModel
from metrology.core.geometry.crossed_axes import Rig, RigError
from metrology.core.io.atomic import _write_bytes_atomic


def read_rig(path: str | os.PathLike[str]) -> Rig:
    """Read a rig file (docs/file-formats.md).

    Raises
    ------
    RigError
        With the file name, if the file is missing, unreadable, not JSON, lacks a
        required key or holds a value out of range.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(f"rig file {path.name!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RigError(f"rig file {path.name!r} cannot be read ({exc})") from None
    try:
        return Rig.from_json(text)
    except RigError as exc:
        raise RigError(f"rig file {path.name!r}: {exc}") from None


def write_rig(rig: Rig, path: str | os.PathLike[str]) -> None:
    """Write ``rig`` as a rig file (JSON, the seven keys then the extra ones), atomically."""
    text = json.dumps(rig.to_dict(), indent=2, allow_nan=False) + "\n"
    _write_bytes_atomic(path, text.encode("utf-8"))


def read_model(path: str | os.PathLike[str]) -> GeometryModel:
    """Read a rig file of any geometric model (:func:`metrology.core.geometry.model_from_dict`): a
    crossed-axes :class:`Rig` for a file without ``model``.

    Raises
    ------
    GeometryError
        With the file name, if the file is missing, unreadable, not JSON or not a valid rig.
    """
    from metrology.core.geometry import model_from_dict

    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise GeometryError(f"rig file {path.name!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GeometryError(f"rig file {path.name!r} cannot be read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise GeometryError(f"rig file {path.name!r} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    except RecursionError:
        raise GeometryError(f"rig file {path.name!r} is nested too deeply to be a rig file") from None
    try:
        return model_from_dict(data)
    except GeometryError as exc:
        raise GeometryError(f"rig file {path.name!r}: {exc}") from None
