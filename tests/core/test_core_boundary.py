"""The measurement core imports no Django, Celery or plotly, and open3d only in mesh.py."""

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[2] / "metrology" / "core"
FORBIDDEN = {"django", "celery", "plotly", "rest_framework", "redis", "workers"}


def imported_roots(path: Path) -> set[str]:
    roots = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.mark.parametrize("path", sorted(CORE.rglob("*.py")), ids=lambda p: str(p.relative_to(CORE)))
def test_core_module_imports_no_application_layer(path):
    roots = imported_roots(path)
    assert not roots & FORBIDDEN, f"{path.name} imports {sorted(roots & FORBIDDEN)}"
    if path.name != "mesh.py":
        assert "open3d" not in roots, f"{path.name} imports open3d"
