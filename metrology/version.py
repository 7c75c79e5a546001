"""The software version recorded with every result."""

from __future__ import annotations

from functools import cache
from importlib import metadata


@cache
def software_version() -> str:
    try:
        return f"gcps-lab {metadata.version('gcps-lab')}"
    except metadata.PackageNotFoundError:
        return "gcps-lab (not installed)"
