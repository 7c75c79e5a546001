"""``gcps cache``: the per-host local cache of prepared tables (docs/operations.md).

::

    gcps cache info     # the folder, its size bound, entries and bytes per kind
    gcps cache clear    # remove every entry

The folder is ``$GCPS_LOCAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/gcps``, else ``~/.cache/gcps``
(:mod:`metrology.core.local_cache`).
"""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    """Add ``cache`` to the ``gcps`` subcommands."""
    p = subparsers.add_parser("cache", help="show or clear the local cache of prepared tables")
    p.add_argument("action", choices=["info", "clear"], help="info: what it holds; clear: remove every entry")
    p.set_defaults(func=cmd_cache)


def cmd_cache(args: argparse.Namespace) -> dict[str, Any]:
    """``info``: the folder, bound, entries and bytes (per kind); ``clear``: the entries removed."""
    from metrology.core import local_cache

    if args.action == "clear":
        return {"path": str(local_cache.cache_dir()), "removed": local_cache.clear()}
    found = local_cache.info()
    return {
        "path": str(found.path),
        "max_bytes": found.max_bytes,
        "entries": found.entries,
        "bytes": found.bytes,
        "kinds": {kind: {"entries": n, "bytes": b} for kind, (n, b) in sorted(found.kinds.items())},
    }
