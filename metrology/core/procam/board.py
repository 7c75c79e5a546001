"""Calibration boards: the ``--board`` spec, the board's points in mm, and their detection in an image.

Spec (docs/procam-calibration.md)::

    chessboard:COLSxROWS:SQUARE_MM     inner corners, points per row first (OpenCV's pattern size)
    circles:COLSxROWS:SPACING_MM       symmetric circle grid, centre spacing
    acircles:COLSxROWS:SPACING_MM      asymmetric circle grid (OpenCV's layout, odd rows shifted)

Board frame: the board plane is ``Z = 0``, point ``(c, r)`` of a chessboard or symmetric grid at
``(c s, r s, 0)`` mm (``s`` the square or spacing), row-major order (index ``r * cols + c``), as
OpenCV's detectors return them. An asymmetric grid's point ``(c, r)`` is at
``((2 c + r % 2) s, r s, 0)``, ``s`` the spacing written in the spec being the distance between
neighbouring points of one row divided by two (OpenCV's ``squareSize`` convention for
``acircles``, as in its calibration sample).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

BOARD_KINDS: tuple[str, ...] = ("chessboard", "circles", "acircles")
_SPEC = re.compile(r"^(?P<kind>[a-z]+):(?P<cols>\d+)x(?P<rows>\d+):(?P<size>[0-9.eE+-]+)$")


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board: kind, points per row (``cols``), rows, square or spacing (mm)."""

    kind: str
    cols: int
    rows: int
    size_mm: float

    def __post_init__(self) -> None:
        if self.kind not in BOARD_KINDS:
            raise ValueError(f"--board: kind must be one of {', '.join(BOARD_KINDS)}, got {self.kind!r}")
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"--board: needs at least 2x2 points, got {self.cols}x{self.rows}")
        if self.kind == "chessboard" and (self.cols < 3 or self.rows < 3):
            raise ValueError(f"--board: a chessboard needs at least 3x3 inner corners, got {self.cols}x{self.rows}")
        if not (math.isfinite(self.size_mm) and self.size_mm > 0):
            raise ValueError(f"--board: square size / spacing must be a positive number of mm, got {self.size_mm!r}")

    @property
    def count(self) -> int:
        """Number of points (corners or circles)."""
        return self.cols * self.rows

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's pattern size ``(points per row, rows)``."""
        return (self.cols, self.rows)

    def object_points(self) -> npt.NDArray[np.float64]:
        """``(rows * cols, 3)`` float64 board points, mm, row-major (see the module docstring)."""
        r, c = np.mgrid[0 : self.rows, 0 : self.cols]
        x = (2 * c + r % 2) if self.kind == "acircles" else c
        pts = np.zeros((self.count, 3))
        pts[:, 0] = x.ravel() * self.size_mm
        pts[:, 1] = r.ravel() * self.size_mm
        return pts

    def spec(self) -> str:
        """The spec string, e.g. ``chessboard:9x7:75``."""
        size = int(self.size_mm) if float(self.size_mm).is_integer() else self.size_mm
        return f"{self.kind}:{self.cols}x{self.rows}:{size}"


def parse_board(text: str) -> BoardSpec:
    """Parse ``KIND:COLSxROWS:SIZE_MM``; ValueError naming ``--board`` and the value on any problem."""
    m = _SPEC.match(text.strip()) if isinstance(text, str) else None
    if m is None:
        raise ValueError(
            f"--board {text!r}: expected chessboard:COLSxROWS:SQUARE_MM, circles:COLSxROWS:SPACING_MM "
            "or acircles:COLSxROWS:SPACING_MM (e.g. chessboard:9x7:25)"
        )
    try:
        size = float(m["size"])
    except ValueError:
        raise ValueError(f"--board {text!r}: size {m['size']!r} is not a number (mm)") from None
    return BoardSpec(kind=m["kind"], cols=int(m["cols"]), rows=int(m["rows"]), size_mm=size)


def to_grey8(image: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """An (H, W) image of any dtype scaled to uint8 (min-max stretch of its 0.1..99.9 percentiles)."""
    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"board image must be (H, W), got shape {a.shape}")
    finite = np.isfinite(a)
    if not finite.any():
        return np.zeros(a.shape, np.uint8)
    lo, hi = np.percentile(a[finite], [0.1, 99.9])
    scale = 255.0 / (hi - lo) if hi > lo else 1.0
    return np.clip(np.nan_to_num((a - lo) * scale, nan=0.0), 0, 255).astype(np.uint8)


def detect_board(image: npt.ArrayLike, board: BoardSpec) -> npt.NDArray[np.float64] | None:
    """Board points in a camera image, ``(count, 2)`` float64 pixels (centres at integers), or None.

    Chessboards: the sector-based detector ``cv2.findChessboardCornersSB``, refined by
    :func:`refine_corners`, falling back to ``cv2.findChessboardCorners`` + ``cornerSubPix``.
    Circle grids: ``cv2.findCirclesGrid`` (symmetric or asymmetric). Points come in the board's
    row-major order.
    """
    grey = to_grey8(image)
    if board.kind == "chessboard":
        found, corners = cv2.findChessboardCornersSB(
            grey, board.pattern_size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
        )
        if found:
            return refine_corners(image, np.asarray(corners, dtype=np.float64).reshape(-1, 2), board)
        if not found:
            found, corners = cv2.findChessboardCorners(
                grey, board.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            )
            if not found:
                return None
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
            corners = cv2.cornerSubPix(grey, corners, (7, 7), (-1, -1), criteria)
    else:
        flags = cv2.CALIB_CB_SYMMETRIC_GRID if board.kind == "circles" else cv2.CALIB_CB_ASYMMETRIC_GRID
        found, corners = cv2.findCirclesGrid(grey, board.pattern_size, flags=flags)
        if not found:
            return None
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    return pts if pts.shape[0] == board.count else None


def refine_corners(image: npt.ArrayLike, corners: npt.NDArray[np.float64], board: BoardSpec) -> npt.NDArray[np.float64]:
    """Chessboard corners refined by ``cv2.cornerSubPix`` on the float image smoothed by a Gaussian.

    With ``d`` the median distance between neighbouring corners (pixels): Gaussian sigma
    ``clip(d / 20, 0.5, 2)`` px, search half-window ``clip(0.3 d, 3, 15)`` px. On realistic 8-bit
    renders this halves the sector detector's error (0.02 px RMS instead of 0.04).
    """
    img = np.asarray(image, dtype=np.float32)
    pts = corners.reshape(board.rows, board.cols, 2)
    spacing = float(np.median(np.linalg.norm(np.diff(pts, axis=1), axis=-1)))
    sigma = float(np.clip(spacing / 20, 0.5, 2.0))
    half = int(np.clip(0.3 * spacing, 3, 15))
    smooth = cv2.GaussianBlur(img, (0, 0), sigma)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5)
    start = np.ascontiguousarray(corners.reshape(-1, 1, 2), dtype=np.float32)
    refined = cv2.cornerSubPix(smooth, start, (half, half), (-1, -1), criteria)
    out = np.asarray(refined, dtype=np.float64).reshape(-1, 2)
    # a corner that moved by more than a quarter of the spacing was pulled off: keep the detector's
    moved = np.linalg.norm(out - corners, axis=1) > 0.25 * spacing
    out[moved] = corners[moved]
    return out
