"""The high-dynamic-range scene of issue 26's must-show (docs/exposures.md), shared by
tests/core/test_exposure_measure.py and tests/acquisition/test_bracketing.py: a pinhole rig of
240x180 px looking at a plane 600 mm away, an 8-step phase of period 16 projector px with gray
code, 8-bit renders with 1.5 grey levels of noise."""

from __future__ import annotations

import math
from typing import Any

from metrology.core.codecs import codec_from_dict
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.io.exposures import Exposure

PROJ_W, PROJ_H = 1280, 800
CAMERA = PinholeCamera(
    240, 180, ((600.0, 0.0, 119.5), (0.0, 601.0, 89.5), (0.0, 0.0, 1.0)), (-0.12, 0.04, 0.0008, -0.0006, 0.01)
)
PROJECTOR = PinholeProjector(
    PROJ_W, PROJ_H, ((1500.0, 0.0, 640.3), (0.0, 1501.0, 399.6), (0.0, 0.0, 1.0)), (0.05, -0.03, 0.0004, 0.0003, 0.0)
)
Z0 = 600.0
RIG = look_at_rig(CAMERA, PROJECTOR, (-250.0, 10.0, 20.0), (0.0, 0.0, Z0))
NOISE_GREY = 1.5
EXPOSURES = (Exposure("exp0", 1000.0), Exposure("exp1", 10000.0), Exposure("exp2", 100000.0))


def _codec() -> Any:
    """8-step sinusoid of period 16 projector px, gray code of 16-px words, white and black."""
    bits = math.ceil(math.log2((PROJ_W + 1) / 16))
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 8 + bits + 2,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "white": [8 + bits],
            "black": [8 + bits + 1],
            "axes": {
                "u": {
                    "phase": [{"frames": list(range(8)), "period": 16.0, "origin": -0.5}],
                    "gray": {"frames": list(range(8, 8 + bits)), "word": 16.0, "origin": -0.5},
                }
            },
        }
    )


CODEC = _codec()
