"""Stored files go through Django's storage API only, so the storage can be an S3 bucket (issue 23 item 3).

No code under ``metrology/`` calls ``.path(...)`` (``Storage.path``: local storages only) nor reads
``.path`` of a file field (``FieldFile.path``, ``<field>.file.path``). The per-host local cache
(``core/local_cache.py``) uses plain ``pathlib`` paths, which this test does not forbid: it looks
for method calls named ``path`` and for ``.path`` on the model's file fields.
"""

from __future__ import annotations

import ast
from pathlib import Path

from django.apps import apps
from django.db import models

ROOT = Path(__file__).resolve().parents[1]


def file_field_names() -> set[str]:
    """Names of every FileField of the project's models (``height_npy``, ``file``, ``html`` ...)."""
    names = set()
    for model in apps.get_models():
        if model.__module__.startswith("metrology."):
            names.update(f.name for f in model._meta.get_fields() if isinstance(f, models.FileField))
    return names


def storage_path_uses(source: str, fields: set[str]) -> list[tuple[int, str]]:
    """``(line, snippet)`` of each ``x.path(...)`` call and each ``<file field>.path`` in ``source``."""
    found = []
    tree = ast.parse(source)
    calls = {id(node.func) for node in ast.walk(tree) if isinstance(node, ast.Call)}
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and node.attr == "path"):
            continue
        receiver = node.value
        called = id(node) in calls
        on_field = isinstance(receiver, ast.Attribute) and receiver.attr in fields | {"file"}
        on_field_name = isinstance(receiver, ast.Name) and receiver.id in fields
        if called or on_field or on_field_name:
            found.append((node.lineno, ast.unparse(node)))
    return sorted(found)


def test_the_check_finds_storage_paths():
    fields = {"height_npy"}
    code = "a = default_storage.path('x')\nb = m.height_npy.path\nc = capture.file.path\nd = os.path.join('a')\n"
    assert [line for line, _ in storage_path_uses(code, fields)] == [1, 2, 3]


def test_no_storage_or_field_file_path_under_metrology():
    fields = file_field_names()
    assert {"height_npy", "file", "html"} <= fields, fields
    offenders = []
    for path in sorted((ROOT / "metrology").rglob("*.py")):
        for line, snippet in storage_path_uses(path.read_text(), fields):
            offenders.append(f"{path.relative_to(ROOT)}:{line}: {snippet}")
    assert offenders == [], "use the storage API (open/save/size/url), not local paths:\n" + "\n".join(offenders)
