"""The project's import graph, read statically (``ast``): who imports whom, at package and module
granularity, and a cycle finder. The fitness tests of imports (``tests/test_import_cycles.py``,
``tests/test_startup_imports.py``) use it.

Every import counts, also those inside functions: a lazy import hides a cycle from Python at
start-up, not from a reader.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOPS = ("metrology", "workers")


def package_of(module: str) -> str | None:
    """``metrology.jobs.services`` -> ``metrology.jobs``; ``workers.celery`` -> ``workers``; else None."""
    parts = module.split(".")
    if parts[0] == "workers":
        return "workers"
    if parts[0] == "metrology":
        return ".".join(parts[:2])
    return None


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path) -> set[str]:
    """Absolute names of the modules ``path`` imports (relative imports resolved; ``from a import b``
    counts as both ``a`` and ``a.b``, since ``b`` may be a submodule)."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            found.add(source)
            found.update(f"{source}.{alias.name}" for alias in node.names)
    return found


def package_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for top in TOPS:
        for path in sorted((ROOT / top).rglob("*.py")):
            if "migrations" in path.parts:  # generated; they name apps by label, not by import
                continue
            source = package_of(module_name(path))
            assert source is not None
            graph.setdefault(source, set())
            for target in map(package_of, imported_modules(path)):
                # "metrology" alone is the namespace itself (``from metrology import x`` names x)
                if target is not None and target not in (source, "metrology"):
                    graph[source].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as a list of packages (first == last), or None (depth-first search, three colours)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                return [*stack[stack.index(target) :], target]
            if target not in state and (cycle := visit(target)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None
