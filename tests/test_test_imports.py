"""No file under tests/ imports a test module (a ``test_*.py`` file), statically.

Importing one runs its module body again under the importer's name and ties the importer to tests
it does not run; shared helpers and constants live in modules not named ``test_*`` (such as
tests/app/stacks.py), and shared fixtures in a conftest.py, where pytest finds them. Every import
counts, also those inside functions and relative ones.
"""

from __future__ import annotations

from pathlib import Path

from tests.import_graph import ROOT, import_statements

TESTS = ROOT / "tests"


def is_test_module(name: str) -> bool:
    """Whether the dotted ``name`` is a ``test_*.py`` file of this repository."""
    path = ROOT.joinpath(*name.split(".")).with_suffix(".py")
    return path.name.startswith("test_") and path.is_file()


def imported_test_modules(path: Path, source: str | None = None) -> list[str]:
    """``lineno: module`` for each test module that ``path`` (or ``source`` as if it were at
    ``path``) imports; ``from a import b`` names the module ``a.b`` when ``b`` is one."""
    found: list[str] = []
    for line, origin, names in import_statements(path, source):
        candidates = [origin, *(f"{origin}.{name}" for name in names)]
        found += [f"{line}: {name}" for name in candidates if is_test_module(name)]
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
