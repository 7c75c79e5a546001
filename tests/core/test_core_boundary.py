"""The measurement core imports no Django, Celery or plotly, no app of the project, and open3d only
in mesh.py, the mesh reader (io/meshes.py) and the inspection's distances and registration."""

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[2] / "metrology" / "core"
FORBIDDEN = {"django", "celery", "plotly", "rest_framework", "redis", "workers"}
OPEN3D_USERS = {"mesh.py", "io/meshes.py", "inspection/distance.py", "inspection/alignment.py"}
"""Core modules that may import open3d (meshes, RaycastingScene, registration pipelines)."""


def imported_modules(path: Path) -> set[str]:
    """Absolute names of what ``path`` imports (``from a import b`` gives ``a`` and ``a.b``); relative
    imports stay inside the core's own package by construction, so only absolute ones are listed."""
    modules = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules.add(node.module)
            modules.update(f"{node.module}.{alias.name}" for alias in node.names)
    return modules


def imported_roots(path: Path) -> set[str]:
    return {module.split(".")[0] for module in imported_modules(path)}


APPS = {path.parent.name for path in CORE.parent.glob("*/__init__.py")} - {"core"}


def application_imports(path: Path) -> set[str]:
    """The ``metrology.<app>`` modules ``path`` imports (``metrology.jobs``, ``metrology.captures``, ...)."""
    prefixes = [["metrology", app] for app in APPS]
    return {module for module in imported_modules(path) if module.split(".")[:2] in prefixes}


CORE_MODULES = sorted(CORE.rglob("*.py"))


@pytest.mark.parametrize("path", CORE_MODULES, ids=lambda p: str(p.relative_to(CORE)))
def test_core_module_imports_no_application_layer(path):
    roots = imported_roots(path)
    assert not roots & FORBIDDEN, f"{path.name} imports {sorted(roots & FORBIDDEN)}"
    if path.relative_to(CORE).as_posix() not in OPEN3D_USERS:
        assert "open3d" not in roots, f"{path.name} imports open3d"


@pytest.mark.parametrize("path", CORE_MODULES, ids=lambda p: str(p.relative_to(CORE)))
def test_core_module_imports_no_app_of_the_project(path):
    assert not application_imports(path), f"{path.name} imports {sorted(application_imports(path))}"


def test_the_app_import_check_catches_one(tmp_path):
    module = tmp_path / "planted.py"
    module.write_text("import numpy\nfrom metrology.core import rig\nfrom metrology.jobs.models import Job\n")
    assert application_imports(module) == {"metrology.jobs.models", "metrology.jobs.models.Job"}
