"""JSON that a client or a person typed, checked before anything uses it (no Django, no DRF).

The API's JSON bodies (:class:`metrology.api_input.BoundedJSONParser`), the pages' JSON fields and
uploaded rig files (``dashboard/forms.py``, ``acquisition/forms.py``) and an agent's multipart
``frames`` all go through these checks: nesting at most :data:`MAX_JSON_DEPTH` levels (deeper is
refused, never a ``RecursionError``), no NUL character (PostgreSQL cannot store it), and only
finite numbers (``1e400`` and ``-1e400``, which Python's parser reads as infinities, and the
non-standard ``NaN``/``Infinity``), a refusal naming the key by its JSON path (``extra.a.b``,
``codec.axes.u.phase[0].period``).
"""

from __future__ import annotations

import json
import math
from typing import Any

#: Deepest nesting of arrays and objects a request body (or a typed JSON value) may have.
MAX_JSON_DEPTH = 32


def _child_path(path: str, key: str | int) -> str:
    """The JSON path of ``key`` inside the value at ``path``: ``a.b``, ``a[0]``, ``$`` at the top."""
    if isinstance(key, int):
        return f"{path}[{key}]"
    return key if path == "$" else f"{path}.{key}"


def json_problem(value: Any, max_depth: int) -> str | None:
    """What is wrong with a parsed JSON ``value``, or None: arrays/objects nested deeper than
    ``max_depth`` levels, a NUL character in a key or string (PostgreSQL cannot store it), or a
    number that is not finite (named by its JSON path, e.g. ``extra.a.b`` or ``axes.u.phase[0].period``;
    ``$`` is the whole body). Iterative, so it cannot itself run out of stack; the first problem
    in document order is reported."""
    stack: list[tuple[Any, int, str]] = [(value, 1, "$")]
    while stack:
        item, depth, path = stack.pop()
        if isinstance(item, str):
            if "\x00" in item:
                return "a string holds a NUL character (\\u0000)"
        elif isinstance(item, float):
            if not math.isfinite(item):
                return f"{path} must be a finite number, got {_number_text(item)}"
        elif isinstance(item, dict | list):
            if depth > max_depth:
                return f"nested deeper than {max_depth} levels"
            if isinstance(item, dict):
                children = [(child, depth + 1, _child_path(path, key)) for key, child in item.items()]
                children += [(key, depth, path) for key in item]
            else:
                children = [(child, depth + 1, _child_path(path, index)) for index, child in enumerate(item)]
            stack.extend(reversed(children))
    return None


def _number_text(number: float) -> str:
    """How a non-finite number is named in a message: NaN, Infinity or -Infinity (out of range)."""
    if math.isnan(number):
        return "NaN"
    return "Infinity (or a number out of range)" if number > 0 else "-Infinity (or a number out of range)"


def load_json_text(text: str | bytes) -> Any:
    """Parse JSON that a person or a client typed outside a JSON body (a form's field, an uploaded
    rig file, a multipart field) with the checks of :class:`BoundedJSONParser`.

    Raises
    ------
    json.JSONDecodeError, UnicodeDecodeError
        When it is not JSON.
    ValueError
        Naming the problem (:func:`json_problem`): nested deeper than :data:`MAX_JSON_DEPTH`
        levels, a NUL character, a number that is not finite (by its JSON path).
    """
    try:
        value = json.loads(text, parse_constant=float)
    except RecursionError:
        raise ValueError(f"nested deeper than {MAX_JSON_DEPTH} levels") from None
    problem = json_problem(value, MAX_JSON_DEPTH)
    if problem:
        raise ValueError(problem)
    return value
