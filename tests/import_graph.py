"""The project's import graph, read statically (``ast``): who imports whom, at package and module
granularity, and a cycle finder. The fitness tests of imports (``tests/test_import_cycles.py``,
``tests/test_startup_imports.py``) use it.

Every import counts, also those inside functions: a lazy import hides a cycle from Python at
start-up, not from a reader.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
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


def import_statements(
    path: Path, source: str | None = None, *, type_checking: bool = True
) -> Iterator[tuple[int, str, list[str]]]:
    """``(line, origin, names)`` of every import of ``path`` (or of ``source`` as if it were at
    ``path``): ``import a.b`` gives ``("a.b", [])``, ``from .x import y, z`` the absolute origin
    (relative imports resolved) and ``["y", "z"]``. The bodies of ``if TYPE_CHECKING:`` (never
    run) count only with ``type_checking``. A file's statements are parsed once per process
    (the fitness tests read every module several times: 1.5 s of CPU per reading of the project)."""
    if source is None:
        for line, origin, names in _file_import_statements(path, type_checking):
            yield line, origin, list(names)
    else:
        yield from _parse_import_statements(path, source, type_checking)


@functools.cache
def _file_import_statements(path: Path, type_checking: bool) -> tuple[tuple[int, str, tuple[str, ...]], ...]:
    return tuple(
        (line, origin, tuple(names))
        for line, origin, names in _parse_import_statements(path, path.read_text(), type_checking)
    )


def _parse_import_statements(path: Path, source: str, type_checking: bool) -> Iterator[tuple[int, str, list[str]]]:
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(source, filename=str(path))
    if not type_checking:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                node.body = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, []
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            yield node.lineno, origin, [alias.name for alias in node.names]


def imported_modules(path: Path) -> set[str]:
    """Absolute names of the modules ``path`` imports (relative imports resolved; ``from a import b``
    counts as both ``a`` and ``a.b``, since ``b`` may be a submodule)."""
    found: set[str] = set()
    for _line, origin, names in import_statements(path):
        found.add(origin)
        found.update(f"{origin}.{name}" for name in names)
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


def project_modules() -> dict[str, Path]:
    """Every module of the project (migrations excepted) by its dotted name."""
    modules: dict[str, Path] = {}
    for top in TOPS:
        for path in sorted((ROOT / top).rglob("*.py")):
            if "migrations" not in path.parts:
                modules[module_name(path)] = path
    return modules


def module_graph(*, type_checking: bool = False) -> dict[str, set[str]]:
    """Module -> the project's modules it imports, file granularity.

    ``from a import b`` is an edge to ``a.b`` where that is a module, else to ``a`` (a name defined
    in ``a``); importing ``a.b.c`` runs ``a`` and ``a.b`` first, but those package edges are not
    counted (a package's ``__init__`` is a module of its own, with its own edges). Imports under
    ``if TYPE_CHECKING:`` are never run: they count only with ``type_checking=True``.
    """
    modules = project_modules()
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        targets: set[str] = set()
        for _line, origin, names in import_statements(path, type_checking=type_checking):
            for imported in [f"{origin}.{n}" for n in names] or [origin]:
                if imported in modules:
                    targets.add(imported)
                elif origin in modules:  # a name defined in the origin module
                    targets.add(origin)
        graph[module] = targets - {module}
    return graph


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )
