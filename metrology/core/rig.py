"""The crossed-optical-axes rig (the paper's model), under its historical name.

The model lives in :mod:`metrology.core.geometry.crossed_axes`; this module keeps
``from metrology.core.rig import Rig`` working.
"""

from __future__ import annotations

from metrology.core.geometry.crossed_axes import PAPER_RIG, REQUIRED_KEYS, MobiusMap, Rig, RigError

__all__ = ["PAPER_RIG", "REQUIRED_KEYS", "MobiusMap", "Rig", "RigError"]
