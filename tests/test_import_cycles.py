"""No package imports another in a cycle (static imports, at package granularity).

The packages are ``metrology.<name>`` (an app, ``metrology.core``, or a top-level module such as
``metrology.settings``) and ``workers``. Every import counts, also those inside functions: a lazy
import hides a cycle from Python at start-up, not from a reader.
"""

from __future__ import annotations

import pytest

from tests.import_graph import find_cycle, module_graph, package_graph

# one worker reads the project's imports once for every test here (tests/import_graph.py caches them)
pytestmark = pytest.mark.xdist_group("import-graph")


def test_the_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycle(graph) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_the_graph_sees_imports_inside_functions():
    graph = package_graph()
    assert "metrology.jobs" in graph["metrology.measurements"]  # a service creates jobs
    assert "metrology.core" in graph["workers"]  # worker_init: metrology.core.allocation, inside a function
    assert {"metrology.jobs", "metrology.captures", "metrology.core", "workers"} <= set(graph)


def test_no_package_imports_another_in_a_cycle():
    cycle = find_cycle(package_graph())
    assert cycle is None, "import cycle between packages: " + " -> ".join(cycle or [])


def test_the_jobs_and_the_workers_do_not_import_each_other_both_ways():
    graph = package_graph()
    assert not ("workers" in graph["metrology.jobs"] and "metrology.jobs" in graph["workers"])
    assert graph["workers"] <= {"metrology.core"}, graph["workers"]  # workers/ holds only the Celery app


def test_the_module_graph_resolves_submodules_and_names():
    graph = module_graph()
    # ``from metrology.core.codecs.model import Codec``: the module; ``from metrology.core import mesh``: the submodule
    assert "metrology.core.codecs.model" in graph["metrology.captures.codecs"]
    assert "metrology.jobs.models" in graph["metrology.jobs.services"]
    assert all(target in graph for targets in graph.values() for target in targets)


JOBS = "metrology.jobs."
"""The job queue's own modules: its service, task and sweeper call each other by design (a task
runs a service, the service enqueues the task, the sweeper requeues both), through imports made
when called."""


def test_no_module_imports_another_in_a_cycle_outside_the_job_queue():
    graph = {
        m: {t for t in targets if not t.startswith(JOBS)}
        for m, targets in module_graph().items()
        if not m.startswith(JOBS)
    }
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle between modules: " + " -> ".join(cycle or [])
