"""Write pytest's assertion-rewritten bytecode of every test module and conftest before the workers
start: ``python -m tests.rewritten_bytecode`` (scripts/test.sh runs it beside the kernels' warm-up).

pytest rewrites the ``assert`` statements of the modules it collects and caches the result in
``__pycache__/<name>.cpython-311-pytest-<version>.pyc`` (hash-checked against the source, so it
survives checkouts). On a fresh clone the four pytest-xdist workers start together, none finds
that cache, and each rewrites all the test modules itself: collection took 13-14 s of CPU per
worker instead of 6.5-7.3 s with the cache (2 cores, `pytest --collect-only`, load 2.4-3.8).
Here it is written once, by the same functions pytest uses (pytest's own module, not a public API:
when they are missing or fail, this says so and pytest rewrites the modules itself, as before).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEST_ROOTS = ("tests", "metrology")


def modules_pytest_rewrites(root: Path = ROOT) -> list[Path]:
    """The files pytest rewrites when it collects the suite: ``test_*.py`` (pytest's default
    ``python_files``) and ``conftest.py`` under the test paths."""
    found: set[Path] = set()
    for top in TEST_ROOTS:
        for pattern in ("test_*.py", "conftest.py"):
            found.update(p for p in (root / top).rglob(pattern) if ".venv" not in p.parts)
    return sorted(found)


def write_rewritten_bytecode(paths: list[Path]) -> int:
    """Rewrite and cache each of ``paths`` as pytest would; returns how many were written."""
    from _pytest.assertion import rewrite

    written = 0
    for path in paths:
        pyc = rewrite.get_cache_dir(path) / (path.name[:-3] + rewrite.PYC_TAIL)
        source_hash, code = rewrite._rewrite_test(path, None)  # type: ignore[arg-type]  # no config: pytest's defaults
        pyc.parent.mkdir(exist_ok=True)
        partial = pyc.with_name(f"{pyc.name}.{os.getpid()}")
        with open(partial, "wb") as out:
            rewrite._write_pyc_fp(out, source_hash, code)
        partial.replace(pyc)
        written += 1
    return written


def main() -> int:
    if sys.dont_write_bytecode:
        return 0
    try:
        write_rewritten_bytecode(modules_pytest_rewrites())
    except Exception as exc:  # pytest's private functions changed: the workers rewrite as before
        print(f"tests.rewritten_bytecode: not written ({exc!r}); pytest will rewrite the test modules itself")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
