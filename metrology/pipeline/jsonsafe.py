"""The JSON-safe form of a pipeline result, for the files and the database (:func:`json_safe`).

A light module (numpy only, none of the pipelines' SciPy or OpenCV): the services, the job and
the command line import it at start-up.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def json_safe(value: Any) -> Any:
    """``value`` with numpy scalars/arrays turned into Python and NaN/inf into ``None`` (JSON has neither)."""
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    if hasattr(value, "to_dict"):
        return json_safe(value.to_dict())
    return str(value)
