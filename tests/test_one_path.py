"""One path for every codec and every geometric model (issue 20), checked on the source.

A geometric model is named in one place: its file in ``metrology/core/geometry/`` (the registry,
:data:`metrology.core.geometry.MODELS`) and :meth:`metrology.rigs.models.Rig.to_core`. Everything
else asks the model what it can do (``requires_reference``, ``light_codes``, ``frame``,
``calibration_parameters``...), so that a third model is one file plus a registry entry, and no
caller grows a branch per model.

The checks read the source statically (``ast`` for Python, the text for templates): a comparison
with a model's name (``==``, ``!=``, ``in``, ``not in``, also inside a tuple, list or set literal
compared with), ``is_pinhole``, a ``Rig.Model`` member, and the names of the removed twins.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from tests.import_graph import ROOT

MODEL_NAMES = frozenset({"crossed_axes", "pinhole", "stereo"})
"""The strings no caller may compare with: the models' registry names (and the next one's)."""

ALLOWED = ("metrology/core/geometry/", "metrology/rigs/models.py")
"""Where a model may be named: its own file and the registry, and the one place that builds it."""

REMOVED_NAMES = (
    "measure_pinhole_stacks",
    "characterize_pinhole",
    "acceptance_pinhole",
    "PinholeMeasureResult",
    "run_pinhole_measurement",
    "run_codec_measurement",
    "is_pinhole",
)
"""Twins removed by issue 20: none may come back under metrology/ (migrations included)."""


def python_files() -> list[Path]:
    return [p for p in sorted((ROOT / "metrology").rglob("*.py")) if "migrations" not in p.parts]


def relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def model_comparisons(source: str, filename: str = "<source>") -> list[tuple[int, str]]:
    """``(line, model name)`` of every comparison of ``source`` with a model name."""

    def names_in(node: ast.expr) -> set[str]:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return {node.value} & MODEL_NAMES
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            return set().union(*(names_in(e) for e in node.elts)) if node.elts else set()
        return set()

    found = []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if isinstance(node, ast.Compare) and any(
            isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)) for op in node.ops
        ):
            for name in sorted(set().union(*(names_in(e) for e in [node.left, *node.comparators]))):
                found.append((node.lineno, name))
        if (
            isinstance(node, ast.MatchValue)
            and isinstance(node.value, ast.Constant)
            and node.value.value in MODEL_NAMES
        ):
            found.append((node.lineno, str(node.value.value)))
    return sorted(found)


def rig_model_members(source: str, filename: str = "<source>") -> list[int]:
    """Lines naming ``Rig.Model`` (the removed choices of the rig's model)."""
    lines = []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if isinstance(node, ast.Attribute) and node.attr == "Model":
            value = node.value
            if (isinstance(value, ast.Name) and value.id == "Rig") or (
                isinstance(value, ast.Attribute) and value.attr == "Rig"
            ):
                lines.append(node.lineno)
    return sorted(lines)


TEMPLATE_COMPARISON = re.compile(
    r"""(==|!=|\bin\b)\s*["'](?:crossed_axes|pinhole|stereo)["']|["'](?:crossed_axes|pinhole|stereo)["']\s*(==|!=|\bin\b)"""
)


def test_the_checks_find_planted_comparisons():
    planted = (
        "if rig.model == 'pinhole': pass\n"
        "x = kind != 'crossed_axes'\n"
        "y = name in ('a', 'stereo')\n"
        "z = 'pinhole' in names\n"
        "match m:\n    case 'pinhole': pass\n"
        "ok = rig.model == other.model\n"
        "label = {'pinhole': 1}\n"
    )
    assert model_comparisons(planted) == [
        (1, "pinhole"),
        (2, "crossed_axes"),
        (3, "stereo"),
        (4, "pinhole"),
        (6, "pinhole"),
    ]
    assert rig_model_members("a = Rig.Model.PINHOLE\nb = models.Rig.Model\nc = rig.model\n") == [1, 2]
    assert TEMPLATE_COMPARISON.search('{% if rig.model == "pinhole" %}')
    assert not TEMPLATE_COMPARISON.search("{% if rig.capabilities.simulate %}")


@pytest.mark.parametrize("path", python_files(), ids=relative)
def test_no_caller_compares_with_a_model_name(path):
    if relative(path).startswith(ALLOWED):
        return
    source = path.read_text()
    found = model_comparisons(source, str(path))
    assert not found, f"{relative(path)} compares with a model's name (ask the model instead): {found}"
    assert not rig_model_members(source, str(path)), f"{relative(path)} names Rig.Model"


def test_no_template_compares_with_a_model_name():
    offenders = []
    for path in sorted((ROOT / "templates").rglob("*.html")) + sorted((ROOT / "metrology").rglob("*.html")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if TEMPLATE_COMPARISON.search(line):
                offenders.append(f"{relative(path)}:{number}")
    assert not offenders, "templates compare with a model's name: " + ", ".join(offenders)


def test_the_removed_twins_stay_removed():
    offenders = []
    for path in sorted((ROOT / "metrology").rglob("*")):
        if path.suffix not in (".py", ".html", ".js") or not path.is_file():
            continue
        text = path.read_text()
        offenders += [f"{relative(path)}: {name}" for name in REMOVED_NAMES if name in text]
    assert not offenders, offenders


@pytest.mark.parametrize(
    "module",
    [
        "core/rig.py",
        "core/triangulate.py",
        "core/codec_measure.py",
        "core/pinhole_measure.py",
        "core/simulate_pinhole.py",
        "pipeline/measure_pinhole.py",
        "measurements/codecs.py",
        "measurements/pinhole.py",
        "commands/measure_pinhole.py",
        "commands/pinhole_acceptance.py",
    ],
)
def test_the_twin_modules_are_gone(module):
    assert not (ROOT / "metrology" / module).exists(), f"metrology/{module} came back"


def test_every_model_is_in_the_registry():
    from metrology.core.geometry import MODELS
    from metrology.core.geometry.base import GeometryModel

    assert MODELS, "no geometric model is registered"
    for name, cls in MODELS.items():
        assert issubclass(cls, GeometryModel) and cls.model == name
        assert cls.label and cls.short_label and cls.frame in ("paper", "camera")


APPLICATION_LAYERS = ("metrology/core/", "metrology/pipeline/", "metrology/commands/", "metrology/cli.py")
"""Not the application: the core and what runs it without Django (these may build a model they
compute for, e.g. the paper's calibration fits a crossed-axes rig)."""


def test_the_application_builds_a_rig_model_only_in_rig_to_core():
    """Stored values become a model through ``Rig.to_core`` (or the registry's ``model_from_dict`` of
    the values a result was made with), never by constructing a model class in a caller."""
    construction = re.compile(r"\b(PinholeRig|CoreRig|Rig)(\.from_dict)?\(")
    offenders = []
    for path in python_files():
        name = relative(path)
        if name.startswith(APPLICATION_LAYERS) or name == "metrology/rigs/models.py":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if construction.search(line) and "Rig.objects" not in line:
                offenders.append(f"{name}:{number}: {line.strip()}")
    assert not offenders, offenders


@pytest.mark.django_db
def test_one_job_handler_measures_every_model():
    from metrology.jobs.handlers import handler_for
    from metrology.jobs.models import Job

    handler = handler_for(Job.Kind.MEASUREMENT)
    assert f"{handler.__module__}.{handler.__name__}" == "metrology.measurements.services.run_measurement"
    measurement_kinds = [kind for kind in Job.Kind if "MEASURE" in kind.name]
    assert measurement_kinds == [Job.Kind.MEASUREMENT], measurement_kinds
