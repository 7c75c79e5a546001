"""Projector-camera calibration from board captures (docs/procam-calibration.md).

- :mod:`~metrology.core.procam.board`: the ``--board`` spec, board points (mm), detection;
- :mod:`~metrology.core.procam.corners`: corners mapped into the projector by local homographies;
- :mod:`~metrology.core.procam.observe`: one pose from a capture stack of any codec;
- :mod:`~metrology.core.procam.correspondences`: the correspondence file (``gcps-procam-correspondences/1``);
- :mod:`~metrology.core.procam.calibrate`: both devices, the stereo pose, the explaining report:
  :func:`calibrate_procam`, a composition of the steps of the next five modules;
- :mod:`~metrology.core.procam.poses`: a pose as observed, the selection of used poses and corners;
- :mod:`~metrology.core.procam.fit`: the OpenCV fits (each device, stereo, leave-one-pose-out);
- :mod:`~metrology.core.procam.bundle`: the fits' model, residuals and the covariance of every parameter;
- :mod:`~metrology.core.procam.uncertainty`: what the poses cannot determine (each intrinsic's std,
  its correlation with the boards' distances, the leave-one-pose-out spread);
- :mod:`~metrology.core.procam.rejection`: mirrored and flipped poses, outlier corners;
- :mod:`~metrology.core.procam.diagnostics`: coverage and edge gaps, pose diversity, gamma;
- :mod:`~metrology.core.procam.advice`: the report's warnings, one function per cause;
- :mod:`~metrology.core.procam.report`: the report's dict (per pose, per corner);
- :mod:`~metrology.core.procam.figures`: residual and coverage figures of a report (SVG);
- :mod:`~metrology.core.procam.gamma`: projector gamma, pattern pre-compensation, phase correction;
- :mod:`~metrology.core.procam.virtual`: board renders through a pinhole virtual rig (tests, examples).
"""

from metrology.core.procam.board import BoardSpec, detect_board, parse_board
from metrology.core.procam.calibrate import ProcamCalibration, calibrate_procam
from metrology.core.procam.poses import PoseObservation, ProcamCalibrationError

__all__ = [
    "BoardSpec",
    "PoseObservation",
    "ProcamCalibration",
    "ProcamCalibrationError",
    "calibrate_procam",
    "detect_board",
    "parse_board",
]
