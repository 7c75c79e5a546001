"""Projector-camera calibration from board captures (docs/procam-calibration.md).

- :mod:`~metrology.core.procam.board`: the ``--board`` spec, board points (mm), detection;
- :mod:`~metrology.core.procam.corners`: corners mapped into the projector by local homographies;
- :mod:`~metrology.core.procam.observe`: one pose from a capture stack of any codec;
- :mod:`~metrology.core.procam.correspondences`: the correspondence file (``gcps-procam-correspondences/1``);
- :mod:`~metrology.core.procam.calibrate`: both devices, the stereo pose, the explaining report;
- :mod:`~metrology.core.procam.virtual`: board renders through a pinhole virtual rig (tests, examples).
"""

from metrology.core.procam.board import BoardSpec, detect_board, parse_board
from metrology.core.procam.calibrate import (
    PoseObservation,
    ProcamCalibration,
    ProcamCalibrationError,
    calibrate_procam,
)

__all__ = [
    "BoardSpec",
    "PoseObservation",
    "ProcamCalibration",
    "ProcamCalibrationError",
    "calibrate_procam",
    "detect_board",
    "parse_board",
]
