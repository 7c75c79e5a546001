"""Stage series files (``SERIES.json``: stage positions and their captures; docs/file-formats.md)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from metrology.core.io.atomic import _write_bytes_atomic
from metrology.core.io.errors import StackError


@dataclass(frozen=True)
class StagePosition:
    """One stage position of a characterization series.

    Parameters
    ----------
    z_in_mm : float
        Stage height of the plane above R, mm.
    captures : tuple of Path
        The capture stacks (folders or zips) taken at this position, one per repeat.
    """

    z_in_mm: float
    captures: tuple[Path, ...]


@dataclass(frozen=True)
class StageSeries:
    """A characterization series (SERIES.json, docs/file-formats.md), positions in file order."""

    positions: tuple[StagePosition, ...]

    @property
    def z_in_mm(self) -> np.ndarray:
        """Stage heights: ``(n_positions,)`` float64, mm."""
        return np.array([position.z_in_mm for position in self.positions], dtype=np.float64)


def series_capture_name(z_in_mm: float, repeat: int) -> str:
    """Conventional relative path of a stage capture: ``z004/r00`` for 4 mm, repeat 0.

    Integral heights give ``zNNN``; others ``zNNNpFFF`` (4.5 mm -> ``z004p500``); negative
    heights start with ``zm``.

    Examples
    --------
    >>> series_capture_name(4.0, 0), series_capture_name(80, 29), series_capture_name(-2.25, 1)
    ('z004/r00', 'z080/r29', 'zm002p250/r01')
    """
    if not math.isfinite(z_in_mm) or repeat < 0:
        raise ValueError(f"z_in_mm must be finite and repeat >= 0, got {z_in_mm!r}, {repeat!r}")
    sign = "m" if z_in_mm < 0 else ""
    magnitude = abs(float(z_in_mm))
    z_part = f"{int(magnitude):03d}" if magnitude.is_integer() else f"{magnitude:07.3f}".replace(".", "p")
    return f"z{sign}{z_part}/r{repeat:02d}"


def _resolve_capture(base: Path, label: str, where: str, ref: str, check_exists: bool) -> Path:
    pure = PurePosixPath(ref.replace("\\", "/"))
    if pure.is_absolute() or (len(ref) > 1 and ref[1] == ":") or ".." in pure.parts:
        raise StackError(f"series {label} {where}: capture {ref!r} must be a relative path inside the series folder")
    path = base.joinpath(*pure.parts)
    if not check_exists:
        return path
    if path.exists():
        return path
    zipped = path.with_name(path.name + ".zip")
    if zipped.is_file():
        return zipped
    raise StackError(f"series {label} {where}: capture {ref!r} not found (neither a folder nor a .zip)")


def read_series(path: str | os.PathLike[str], *, check_exists: bool = True) -> StageSeries:
    """Read a stage series file (SERIES.json, docs/file-formats.md).

    The file is ``{"positions": [{"z_in_mm": 4.0, "captures": ["z004/r00", ...]}, ...]}``
    with capture paths relative to the file's folder, each a folder or a zip (given with or
    without ``.zip``). Other keys are allowed and ignored.

    Parameters
    ----------
    path : path
        The series file.
    check_exists : bool
        Require every capture to exist (and resolve ``name`` to ``name.zip`` when only
        the zip exists).

    Returns
    -------
    StageSeries
        Capture paths resolved against the file's folder.

    Raises
    ------
    StackError
        On a missing or unreadable file, invalid JSON, a wrong structure, a non-finite or
        repeated ``z_in_mm``, an empty or repeated capture list entry, an absolute or
        ``..`` capture path, or a capture that does not exist.
    """
    path = Path(path)
    label = repr(path.name)
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StackError(f"series file {label} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StackError(f"series file {label} cannot be read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise StackError(f"series file {label} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(data, dict) or not isinstance(data.get("positions"), list):
        raise StackError(f"series {label} must be a JSON object with a list 'positions'")
    if not data["positions"]:
        raise StackError(f"series {label} has no positions")
    base = path.parent
    positions: list[StagePosition] = []
    seen_z: set[float] = set()
    seen_captures: set[Path] = set()
    for number, item in enumerate(data["positions"]):
        where = f"position {number}"
        if not isinstance(item, dict):
            raise StackError(f"series {label} {where} must be an object with 'z_in_mm' and 'captures'")
        z = item.get("z_in_mm")
        if isinstance(z, bool) or not isinstance(z, (int, float)) or not math.isfinite(z):
            raise StackError(f"series {label} {where}: 'z_in_mm' must be a finite number, got {z!r}")
        z = float(z)
        if z in seen_z:
            raise StackError(f"series {label} {where}: z_in_mm {z} appears more than once")
        seen_z.add(z)
        where = f"position {number} (z_in_mm={z:g})"
        captures = item.get("captures")
        if not isinstance(captures, list) or not captures:
            raise StackError(f"series {label} {where}: 'captures' must be a non-empty list of paths")
        resolved = []
        for ref in captures:
            if not isinstance(ref, str) or not ref.strip():
                raise StackError(f"series {label} {where}: capture {ref!r} must be a non-empty path string")
            capture = _resolve_capture(base, label, where, ref, check_exists)
            if capture in seen_captures:
                raise StackError(f"series {label} {where}: capture {ref!r} is listed more than once")
            seen_captures.add(capture)
            resolved.append(capture)
        positions.append(StagePosition(z_in_mm=z, captures=tuple(resolved)))
    return StageSeries(positions=tuple(positions))


def write_series(
    series: StageSeries | Mapping[float, Sequence[str | os.PathLike[str]]],
    path: str | os.PathLike[str],
) -> None:
    """Write a stage series file (SERIES.json, docs/file-formats.md), atomically.

    Parameters
    ----------
    series : StageSeries or mapping
        Positions, or ``{z_in_mm: [capture, ...]}``. Captures are paths relative to the
        file's folder, or absolute paths inside it (written relative, '/'-separated).
    path : path
        Destination file.

    Raises
    ------
    ValueError
        If a capture lies outside the file's folder or a height is not finite.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "SERIES.json"
    >>> write_series({4.0: ["z004/r00", "z004/r01"]}, out)
    >>> read_series(out, check_exists=False).positions[0].z_in_mm
    4.0
    """
    path = Path(path)
    base = path.parent.resolve()
    items: list[tuple[float, Sequence[str | os.PathLike[str]]]]
    if isinstance(series, StageSeries):
        items = [(position.z_in_mm, position.captures) for position in series.positions]
    else:
        items = list(series.items())
    positions = []
    for z, captures in items:
        z = float(z)
        if not math.isfinite(z):
            raise ValueError(f"z_in_mm must be finite, got {z!r}")
        refs = []
        for capture in captures:
            capture_path = Path(capture)
            if capture_path.is_absolute():
                try:
                    capture_path = capture_path.resolve().relative_to(base)
                except ValueError:
                    raise ValueError(f"capture {str(capture)!r} lies outside the series folder {str(base)!r}") from None
            refs.append(capture_path.as_posix())
        positions.append({"z_in_mm": z, "captures": refs})
    text = json.dumps({"positions": positions}, indent=2) + "\n"
    _write_bytes_atomic(path, text.encode("utf-8"))
