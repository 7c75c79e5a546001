"""The software version recorded with every result: the package version and the git commit of the code.

``software_version()`` is ``"gcps-lab 0.1.0 3f2a9c1b7d4e"`` in a clean checkout,
``"gcps-lab 0.1.0 3f2a9c1b7d4e+dirty"`` when the working tree differs from that commit
(tracked files modified, or files that git does not ignore added), and
``"gcps-lab 0.1.0 unknown commit"`` outside a git checkout (an installed wheel, a container
built without ``.git``) unless the environment variable ``GCPS_GIT_COMMIT`` names the commit.

The commit is read from git at run time, from the folder the running ``metrology`` package
was imported from, so an editable install reports the commit of the code it actually runs,
never the one it was installed at. It is computed once per process (a worker runs the code
it imported at start-up).
"""

from __future__ import annotations

import os
import re
import subprocess
import threading
from functools import cache
from pathlib import Path

PACKAGE = "gcps-lab"
SOURCE_ROOT = Path(__file__).resolve().parents[1]
"""The folder holding the ``metrology`` package (a git checkout's root, in development)."""
COMMIT_CHARS = 12
"""Hex digits of the commit hash recorded (as ``git rev-parse --short=12``)."""
GIT_TIMEOUT_S = 5.0


def package_version() -> str:
    """The installed distribution's version, or ``"0+unknown"`` when it is not installed: what
    ``importlib.metadata.version`` returns, read by :func:`_metadata_version` where the search path
    holds only folders (importing ``importlib.metadata``, its email parser, zipfile's path support and
    the rest, is 15-30 ms of CPU of every ``gcps`` process, on the version's thread but holding the
    GIL beside the main thread's imports); by ``importlib.metadata`` where it does not."""
    found = _metadata_version(PACKAGE)
    if found is not None:
        return found
    from importlib import metadata

    try:
        return metadata.version(PACKAGE)
    except metadata.PackageNotFoundError:
        return "0+unknown"


def _normalized(name: str) -> str:
    """A distribution name as ``importlib.metadata`` compares it (PEP 503, then ``-`` as ``_``)."""
    return re.sub(r"[-_.]+", "-", name).lower().replace("-", "_")


def _metadata_version(name: str) -> str | None:
    """The ``Version`` of the distribution ``name`` found as ``importlib.metadata`` finds it, where
    ``sys.path`` holds only folders (and missing entries): the first entry, in ``sys.path`` order,
    holding a ``<name>[-<version>].dist-info`` or ``.egg-info`` folder (names compared normalised,
    case-insensitively), its ``METADATA`` or ``PKG-INFO`` headers; ``"0+unknown"`` where none does.
    None where that search is not the one ``importlib.metadata`` does (a zip on the path, another
    distribution finder, a folder holding two such entries, a file it cannot read): the caller then
    asks ``importlib.metadata``."""
    import sys
    from importlib.machinery import PathFinder

    if any(
        getattr(finder, "find_distributions", None) is not None and finder is not PathFinder for finder in sys.meta_path
    ):
        return None
    wanted = _normalized(name)
    for entry in sys.path:
        folder = entry or "."
        try:
            children = os.listdir(folder)
        except NotADirectoryError:
            return None  # a zip: importlib.metadata reads its members
        except OSError:
            continue
        found = [
            child
            for child in children
            if child.lower().endswith((".dist-info", ".egg-info"))
            and _normalized(child.lower().rpartition(".")[0].partition("-")[0]) == wanted
        ]
        if not found:
            continue
        if len(found) > 1:
            return None  # importlib.metadata takes the first that the folder lists
        info = Path(folder, found[0])
        for file in ("METADATA", "PKG-INFO"):
            try:
                text = (info / file).read_text(encoding="utf-8")
            except FileNotFoundError:
                continue
            except (OSError, UnicodeDecodeError):
                return None
            for line in text.split("\n\n", 1)[0].splitlines():
                key, _, value = line.partition(":")
                if key.strip().lower() == "version":
                    return value.strip()
            return None  # no Version header: importlib.metadata says what it says
        return None
    return "0+unknown"


def git_revision(root: Path = SOURCE_ROOT) -> str | None:
    """``"<12 hex digits>"`` or ``"<12 hex digits>+dirty"`` of the checkout at ``root``; None outside one
    (or when git is missing)."""
    try:
        head = _git(root, "rev-parse", "--verify", "HEAD")
        if head is None:
            return None
        # the checkout's top level must be root itself, not a repository that merely contains it
        top = _git(root, "rev-parse", "--show-toplevel")
        if top is None or Path(top).resolve() != root.resolve():
            return None
        status = _git(root, "status", "--porcelain")
    except (OSError, subprocess.SubprocessError):
        return None
    commit = head[:COMMIT_CHARS]
    return f"{commit}+dirty" if status else commit


def _git(root: Path, *args: str) -> str | None:
    done = subprocess.run(
        ["git", "-C", str(root), *args],
        capture_output=True,
        text=True,
        timeout=GIT_TIMEOUT_S,
        check=False,
        env={**os.environ, "GIT_OPTIONAL_LOCKS": "0", "LC_ALL": "C"},
    )
    if done.returncode != 0:
        return None
    return done.stdout.strip()


def describe(root: Path = SOURCE_ROOT) -> str:
    """The version string of the code under ``root`` (see the module docstring); not cached."""
    revision = git_revision(root)
    if revision is None:
        revision = os.environ.get("GCPS_GIT_COMMIT", "").strip()[:COMMIT_CHARS] or "unknown commit"
    return f"{PACKAGE} {package_version()} {revision}"


_LOCK = threading.Lock()


@cache
def _computed() -> str:
    return describe()


def software_version() -> str:
    """The version string of the running code, computed once per process (see the module docstring);
    a caller arriving while another thread computes it waits for that one computation (git runs
    once)."""
    with _LOCK:
        return _computed()


def software_version_soon() -> None:
    """Start computing :func:`software_version` on a daemon thread, so that a later caller finds it
    ready: in a development checkout it runs git three times (30-80 ms of wall time), which a command
    overlaps with reading its files (``gcps measure``: the kept reference's key needs it)."""
    threading.Thread(target=software_version, name="gcps-version", daemon=True).start()
