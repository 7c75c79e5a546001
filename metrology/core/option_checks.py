"""Validators of option objects (frozen dataclasses checked in ``__post_init__``).

Each raises a :class:`ValueError` that names the option and the value it got, in the same words
wherever the option is given (a command-line flag, a JSON request, a job's stored options).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def is_real(value: Any) -> bool:
    """True for an int or float (numpy's included), False for a bool or anything else."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def check_keys(kind: str, data: Mapping[str, Any], allowed: set[str]) -> None:
    """ValueError naming the unknown keys of an options object (and the accepted ones)."""
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"unknown {kind} option(s): {', '.join(unknown)}; accepted: {', '.join(sorted(allowed))}")


def check_bool(name: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}")


def check_int(name: str, value: Any, lower: int, upper: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lower <= value <= upper:
        raise ValueError(f"{name} must be an integer in [{lower}, {upper}], got {value!r}")


def check_positive(name: str, value: Any, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if not is_real(value) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number, got {value!r}")


def check_number(name: str, value: Any, *, allow_none: bool = False, upper: float | None = None) -> None:
    """ValueError naming ``name`` and ``value`` unless ``value`` is a finite number in [0, upper) (or None)."""
    if value is None and allow_none:
        return
    ok = is_real(value) and math.isfinite(value) and value >= 0 and (upper is None or value < upper)
    if not ok:
        bound = f"[0, {upper:g})" if upper is not None else "[0, inf)"
        extra = " or None" if allow_none else ""
        raise ValueError(f"{name} must be a finite number in {bound}{extra}, got {value!r}")
