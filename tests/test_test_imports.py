"""No file under tests/ imports a test module (a ``test_*.py`` file), statically.

Importing one runs its module body again under the importer's name and ties the importer to tests
it does not run; shared helpers and constants live in modules not named ``test_*`` (such as
tests/app/stacks.py), and shared fixtures in a conftest.py, where pytest finds them. Every import
counts, also those inside functions and relative ones.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_test_module(name: str) -> bool:
    """Whether the dotted ``name`` is a ``test_*.py`` file of this repository."""
    path = ROOT.joinpath(*name.split(".")).with_suffix(".py")
    return path.name.startswith("test_") and path.is_file()


def imported_test_modules(path: Path, source: str | None = None) -> list[str]:
    """``lineno: module`` for each test module that ``path`` (or ``source`` as if it were at
    ``path``) imports; ``from a import b`` names the module ``a.b`` when ``b`` is one."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text() if source is None else source, filename=str(path))
    found: list[str] = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            names = [origin, *(f"{origin}.{alias.name}" for alias in node.names)]
        found += [f"{node.lineno}: {name}" for name in names if is_test_module(name)]
    return sorted(set(found), key=lambda item: int(item.partition(":")[0]))


def test_the_finder_finds_planted_imports_of_test_modules():
    planted = "\n".join(
        [
            "from tests.commands.test_cli import main",
            "import tests.pipeline.test_pipeline",
            "from tests import test_version",
            "def f():",
            "    from .test_joint_refinement import calibrate",
            "from tests.app.stacks import SMALL_RIG",
            "from .virtual_rig import RIG",
            "from tests.app.uploads import upload as test_upload",
        ]
    )
    found = imported_test_modules(TESTS / "core" / "procam" / "planted.py", planted)
    assert found == [
        "1: tests.commands.test_cli",
        "2: tests.pipeline.test_pipeline",
        "3: tests.test_version",
        "5: tests.core.procam.test_joint_refinement",
    ]


def test_no_file_under_tests_imports_a_test_module():
    offending = {
        str(path.relative_to(ROOT)): found
        for path in sorted(TESTS.rglob("*.py"))
        if (found := imported_test_modules(path))
    }
    assert not offending, (
        f"test modules imported (move what they share to a helper module or a conftest.py): {offending}"
    )
