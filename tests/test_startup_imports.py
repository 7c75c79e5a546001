"""Start-up stays light: ``django.setup()`` imports none of the heavy libraries, services import no DRF.

``django.setup()`` runs in every web process, worker, management command and test session; the
measurement libraries (SciPy, OpenCV, Open3D, Plotly) and DRF's serializers are loaded when a
request or a job needs them (the worker loads the job handlers as it starts,
:func:`metrology.jobs.handlers.preload_job_code`). The services raise the domain errors of
:mod:`metrology.errors` and leave HTTP to the API layer, so they import nothing of DRF.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.commands.rigs import RIG as CROSSED_RIG
from tests.import_graph import imported_modules, module_name

ROOT = Path(__file__).resolve().parents[1]

#: Loaded on demand only, never by ``django.setup()``.
HEAVY = ("scipy", "numba", "cv2", "open3d", "plotly", "rest_framework.serializers")

SETUP = "import os, django; os.environ.setdefault('DJANGO_SETTINGS_MODULE', 'metrology.settings'); django.setup()"


def importtime_tree(stderr: str) -> list[tuple[int, str]]:
    """``(depth, module)`` of each ``-X importtime`` line, in its order (a module after its imports)."""
    rows = []
    for line in stderr.splitlines():
        if not line.startswith("import time:") or line.endswith("| imported package"):
            continue
        name = line.rsplit("|", 1)[1]
        rows.append(((len(name) - len(name.lstrip())) // 2, name.strip()))
    return rows


def import_chain(rows: list[tuple[int, str]], index: int) -> list[str]:
    """The modules whose import imported ``rows[index]``, outermost first (a parent follows its
    children, one level less indented)."""
    depth, name = rows[index]
    chain = [name]
    for row_depth, row_name in rows[index + 1 :]:
        if row_depth < depth:
            chain.append(row_name)
            depth = row_depth
    return chain[::-1]


def import_chains(rows: list[tuple[int, str]], names: tuple[str, ...]) -> dict[str, str]:
    """``{module: "importer <- ... <- module"}`` for each of ``names`` found in ``rows``."""
    return {
        name: " <- ".join(reversed(import_chain(rows, index))) for index, (_, name) in enumerate(rows) if name in names
    }


def test_the_import_chain_of_a_module_is_read_from_importtime():
    stderr = "\n".join(
        [
            "import time: self [us] | cumulative | imported package",
            "import time:        10 |         10 |     scipy",
            "import time:        10 |         20 |   metrology.core.fit",
            "import time:        10 |         10 |   json",
            "import time:        10 |         40 | metrology.measurements.services",
        ]
    )
    rows = importtime_tree(stderr)
    assert rows[0] == (2, "scipy")
    assert import_chain(rows, 0) == ["metrology.measurements.services", "metrology.core.fit", "scipy"]


def fresh_interpreter(code: str, *options: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a new interpreter with no environment variable set (but the source path)."""
    env = {"PATH": os.environ.get("PATH", ""), "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, *options, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done


SET_UP_MARK = "django.setup() done"


@pytest.fixture(scope="module")
def setup_then_urlconf() -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """The ``-X importtime`` rows of one fresh interpreter that runs ``django.setup()`` and then
    loads the URLconf: those before :data:`SET_UP_MARK` (what the set-up imported) and all of them
    (the set-up's and the URLconf's: what a web server has imported as it starts). One interpreter
    for both tests below (a Django start is about 1 s of CPU); what each of them reads is what its own
    interpreter read before."""
    done = fresh_interpreter(
        f"{SETUP}; import sys; print({SET_UP_MARK!r}, file=sys.stderr, flush=True); "
        "import django.urls; django.urls.get_resolver().url_patterns; print('ready')",
        "-X",
        "importtime",
    )
    assert done.stdout.strip() == "ready"
    before, mark, _ = done.stderr.partition(f"\n{SET_UP_MARK}\n")
    assert mark, done.stderr[-3000:]
    return importtime_tree(before), importtime_tree(done.stderr)


def test_django_setup_imports_no_heavy_module(setup_then_urlconf):
    """With no environment variable set (the embedded default: ``metrology.settings`` loads)."""
    rows = setup_then_urlconf[0]
    assert any(name == "django" for _, name in rows), "no -X importtime output"
    assert not any(name == "metrology.measurements.api" for _, name in rows), "the URLconf's imports were counted"
    found = import_chains(rows, HEAVY)
    assert not found, "django.setup() imported:\n" + "\n".join(f"{name}: {chain}" for name, chain in found.items())


#: Not loaded by the URLconf that every web server imports as it starts (its views load them on use).
NOT_FOR_URLS = ("scipy", "numba", "open3d", "redis.asyncio")


def test_the_urlconf_imports_no_optimiser_and_no_async_redis(setup_then_urlconf):
    """Every web server process (and ``manage.py check``) imports the URLconf and with it every API
    module; SciPy (0.5 s of CPU, for one sphere fit of the acceptance API) and ``redis.asyncio`` (for
    the projector's long-poll) are imported where they are used."""
    rows = setup_then_urlconf[1]
    assert any(name == "metrology.measurements.api" for _, name in rows), "the URLconf was not loaded"
    found = import_chains(rows, NOT_FOR_URLS)
    assert not found, "the URLconf imported:\n" + "\n".join(f"{name}: {chain}" for name, chain in found.items())


# ----------------------------------------------------------------------------- DRF in the API layer only
API_LAYER_NAMES = {"api.py", "serializers.py", "views.py", "urls.py", "throttling.py"}
"""The modules that speak HTTP through DRF: the API views, their serializers, the pages, the URL
configuration, the throttles and token authentication (``metrology/throttling.py``), with
:func:`in_api_layer`'s ``api_*.py`` and ``*_api.py``."""

DRF_TOKEN_MODEL = "rest_framework.authtoken.models"
"""DRF's ``Token`` model, which the account services and the demo command create (a model of an
installed app, not DRF's HTTP layer)."""

WIRING = {"apps.py"}
"""An app's ``ready()`` may connect the API layer's signal receivers (the login-failure throttle)."""


def in_api_layer(path: Path) -> bool:
    """``api.py``, ``api_*.py`` (the error handler, request parsing, OpenAPI hooks), ``*_api.py``
    and :data:`API_LAYER_NAMES`."""
    name = path.name
    return name in API_LAYER_NAMES or name.startswith("api_") or name.endswith("_api.py")


def api_layer_modules() -> set[str]:
    return {module_name(path) for path in (ROOT / "metrology").rglob("*.py") if in_api_layer(path)}


def refused_imports(filename: str, imported: set[str], api_modules: set[str]) -> list[str]:
    """What a module named ``filename``, outside the API layer, imports of DRF or of the API layer."""
    refused = []
    for name in sorted(imported):
        if name == "rest_framework.authtoken" or name.startswith(DRF_TOKEN_MODEL):
            continue
        drf = name == "rest_framework" or name.startswith("rest_framework.")
        if drf or (name in api_modules and filename not in WIRING):
            refused.append(name)
    return refused


def test_the_api_layer_is_found():
    modules = api_layer_modules()
    assert {"metrology.api_errors", "metrology.rigs.api", "metrology.calibrations.procam_api"} <= modules
    assert {"metrology.jobs.serializers", "metrology.throttling", "metrology.dashboard.views"} <= modules
    assert not modules & {"metrology.rigs.services", "metrology.errors", "metrology.service_errors"}


def test_a_planted_drf_import_is_refused():
    imported = imported_modules(ROOT / "metrology" / "rigs" / "services.py")
    imported |= {"rest_framework", "rest_framework.exceptions", "metrology.api_errors"}
    imported |= {"rest_framework.authtoken.models", "rest_framework.authtoken.models.Token"}
    api_modules = api_layer_modules()
    assert refused_imports("services.py", imported, api_modules) == [
        "metrology.api_errors",
        "rest_framework",
        "rest_framework.exceptions",
    ]
    assert refused_imports("apps.py", {"metrology.throttling"}, api_modules) == []


def test_outside_the_api_layer_nothing_imports_drf():
    """Services, selectors, models, tasks, commands: DRF (but its Token model) and the API layer's
    modules are imported by the API layer only."""
    api_modules = api_layer_modules()
    refused = {}
    for path in sorted((ROOT / "metrology").rglob("*.py")):
        if "migrations" in path.parts or in_api_layer(path):
            continue
        if found := refused_imports(path.name, imported_modules(path), api_modules):
            refused[path.relative_to(ROOT).as_posix()] = found
    assert not refused, f"raise metrology.errors instead, leave HTTP to the API layer: {refused}"


# ----------------------------------------------------------------------------- loaded on demand
def run_fresh(code: str) -> dict:
    """The JSON object that ``code``, run in a fresh interpreter, prints last."""
    return json.loads(fresh_interpreter(code).stdout.strip().splitlines()[-1])


PIPELINE_ON_FIRST_USE = """
import json, sys
import metrology.pipeline.jsonsafe
light = sorted(m for m in ("scipy", "cv2") if m in sys.modules)
import metrology.pipeline.common
common = sorted(m for m in sys.modules if m.startswith("metrology.pipeline"))
import metrology.pipeline.measure
from metrology.pipeline import MeasureOptions, prepare_reference
from metrology.pipeline.calibrate import calibrate
from metrology.pipeline.measure import measure
import metrology.pipeline as pipeline
print(json.dumps({
    "light": light,
    "common": common,
    "functions": [callable(measure), callable(prepare_reference), callable(calibrate)],
    "options": MeasureOptions is metrology.pipeline.measure.MeasureOptions,
    "not_in_dir": sorted(set(pipeline.__all__) - set(dir(pipeline))),
    "all_found": sorted(pipeline._MEMBERS) == sorted(pipeline.__all__),
}))
"""


def test_the_pipeline_package_loads_its_modules_on_first_use():
    found = run_fresh(PIPELINE_ON_FIRST_USE)
    assert found["light"] == []  # json_safe: numpy only
    assert found["common"] == ["metrology.pipeline", "metrology.pipeline.common", "metrology.pipeline.jsonsafe"]
    # the functions are imported from their modules; the package offers the types (and prepare_reference)
    assert found["functions"] == [True, True, True]
    assert found["options"]  # the measure module's (defined in metrology.core.measure)
    assert found["not_in_dir"] == [] and found["all_found"]


def test_every_job_kind_has_a_handler_that_resolves():
    from metrology.jobs.handlers import handler_for, registered_kinds
    from metrology.jobs.models import Job

    assert registered_kinds() == set(Job.Kind)
    for kind in Job.Kind:
        handler = handler_for(kind)
        assert callable(handler) and handler.__module__.startswith("metrology."), (kind, handler)


WORKER_START = f"""
{SETUP}
import json, sys
from celery.signals import worker_init
from metrology.jobs.handlers import preload_job_code
receivers = [ref() for _, ref in worker_init.receivers]
before = sorted(m for m in sys.modules if m.startswith(("metrology.pipeline.", "scipy", "cv2")))
preload_job_code()
after = sorted(m for m in sys.modules if m.startswith(("metrology.", "scipy", "cv2", "plotly")))
warm = bool(sys.modules["metrology.core.codecs.kernels"].phase_sums_u8.signatures)
print(json.dumps({{"connected": preload_job_code in receivers, "before": before, "after": after, "warm": warm}}))
"""


def test_a_worker_loads_the_job_code_as_it_starts():
    """On ``worker_init`` (before the pool forks): the handlers, the pipelines and their libraries."""
    found = run_fresh(WORKER_START)
    assert found["connected"] and found["before"] == []
    after = set(found["after"])
    assert {"scipy.optimize", "cv2", "plotly", "metrology.figures.characterization"} <= after
    assert {"metrology.measurements.services", "metrology.calibrations.procam_services"} <= after
    assert found["warm"]  # the codec decoder's compiled kernel is loaded, not left to the first job
    pipelines = {module_name(path) for path in (ROOT / "metrology" / "pipeline").glob("[!_]*.py")}
    assert pipelines <= after, pipelines - after


# ----------------------------------------------------------------------------- a measurement process
MEASURING_NEEDS_NONE_OF = (
    "scipy.optimize",
    "scipy.ndimage",
    "metrology.core.codecs.render",
    "metrology.core.simulate",
    "open3d",
    "plotly",
    "django",
)
"""Modules a ``gcps measure`` or ``gcps decode`` process must not import (issue 22 item 3): the
renderer and the optimisers, the mesh and figure libraries, Django; each is loaded where it is
used (``--mesh`` loads Open3D, calibration SciPy's optimisers, ``gcps simulate`` the renderer)."""


GCPS_V1_NEEDS_NONE_OF = (
    *MEASURING_NEEDS_NONE_OF,
    "scipy.special",
    "numba",
    "zipfile",
    "secrets",
    "metrology.core.io.points",
    "metrology.core.io.series",
    "metrology.core.distortion",
)
"""A ``gcps measure`` of gcps-v1 captures on the crossed-axes rig needs neither SciPy's special
functions (the codec path's noise model) nor numba (a distorted projector's kernels, stereo's,
the compiled decoding kernel of workers): about 0.15 s of imports each (issue 22); nor, reading
folders and writing a height map of a rig without distortion, zipfile, secrets, the point-map and
stage-series modules or the distortion model (about 8 ms of imports holding the GIL together)."""


PINHOLE_NEEDS_NONE_OF = (*MEASURING_NEEDS_NONE_OF, "numba")
"""A ``gcps measure`` through a distorted projector triangulates with the numpy twins of the compiled
kernels (:mod:`metrology.core.geometry.pinhole_numpy`): numba's start (about 1 s of CPU and 117
MiB with its kernels) would cost more than they save on one frame (issue 22)."""


def gcps_imports(tmp: Path, *args: str, forbidden: tuple[str, ...] = MEASURING_NEEDS_NONE_OF) -> dict[str, str]:
    """``gcps ARGS`` run for real in a fresh interpreter with ``-X importtime``: the import chain of
    each module of ``forbidden`` it imported (empty when it imported none)."""
    code = "import sys; from metrology.cli import main; sys.exit(main(sys.argv[1:]))"
    env = {"PATH": os.environ.get("PATH", ""), "PYTHONPATH": str(ROOT), "GCPS_LOCAL_CACHE_DIR": str(tmp / "cache")}
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code, "--quiet", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    rows = importtime_tree(done.stderr)
    assert any(name == "numpy" for _, name in rows), "no -X importtime output"
    return import_chains(rows, forbidden)


def test_a_planted_import_is_found_in_a_gcps_process(tmp_path: Path) -> None:
    """The check sees a module a command does import: ``gcps simulate`` renders."""
    (tmp_path / "rig.json").write_text(CROSSED_RIG.to_json())
    found = gcps_imports(
        tmp_path,
        *("simulate", "--rig", str(tmp_path / "rig.json"), "--scene", "reference", "--out", str(tmp_path / "ref")),
        *("--preset", "noise-free", "--supersample", "1"),
    )
    assert "metrology.core.codecs.render" in found or "metrology.core.simulate" in found, found


def test_measuring_processes_import_only_what_measuring_needs(tmp_path: Path) -> None:
    """Real ``gcps measure`` runs (gcps-v1 with a reference on the crossed-axes rig; a distorted
    pinhole rig with a u-only codec, its epipolar table built) and a ``gcps decode``, each in a
    fresh interpreter, import none of :data:`MEASURING_NEEDS_NONE_OF` (the first none of
    :data:`GCPS_V1_NEEDS_NONE_OF`, the second none of :data:`PINHOLE_NEEDS_NONE_OF`)."""
    import cv2

    from metrology.core.codecs import codec_from_dict, render_codec
    from tests.pinhole_stacks import CODEC, RIG, cast_scene

    rig = tmp_path / "crossed.json"
    rig.write_text(CROSSED_RIG.to_json())
    for scene in ("reference", "sphere"):  # rendered in this process: the renderer is not under test
        from metrology.cli import main

        assert (
            main(
                [
                    *("--quiet", "simulate", "--rig", str(rig), "--scene", scene, "--out", str(tmp_path / scene)),
                    *("--preset", "noise-free", "--supersample", "1"),
                ]
            )
            == 0
        )
    pinhole_rig = tmp_path / "pinhole.json"
    pinhole_rig.write_text(RIG.to_json())
    capture = tmp_path / "pinhole-sphere"
    capture.mkdir()
    truth = cast_scene("sphere", 600.0)
    for i, image in enumerate(render_codec(codec_from_dict(CODEC), truth.u, None)):
        assert cv2.imwrite(str(capture / f"frame_{i:02d}.png"), image)
    (capture / "codec.json").write_text(json.dumps(CODEC))
    runs = {
        "gcps measure gcps-v1": (
            *("measure", "--rig", str(rig), "--reference", str(tmp_path / "reference")),
            *("--object", str(tmp_path / "sphere"), "--out", str(tmp_path / "h.npy")),
            *("--json", str(tmp_path / "s.json")),
        ),
        "gcps measure pinhole": (
            *("measure", "--rig", str(pinhole_rig), "--object", str(capture), "--out", str(tmp_path / "z.npy")),
            *("--xyz", str(tmp_path / "xyz.npy"), "--sigma", str(tmp_path / "sigma.npy")),
        ),
        "gcps decode": ("decode", "--stack", str(capture), "--out", str(tmp_path / "uv.npy")),
    }
    forbidden = {"gcps measure gcps-v1": GCPS_V1_NEEDS_NONE_OF, "gcps measure pinhole": PINHOLE_NEEDS_NONE_OF}
    found = {
        name: gcps_imports(tmp_path, *args, forbidden=forbidden.get(name, MEASURING_NEEDS_NONE_OF))
        for name, args in runs.items()
    }
    assert np.isfinite(np.load(tmp_path / "z.npy")).mean() > 0.3  # the commands measured
    assert np.isfinite(np.load(tmp_path / "h.npy")).mean() > 0.3
    assert not any(found.values()), "a measurement process imported:\n" + "\n".join(
        f"{run}: {name}: {chain}" for run, chains in found.items() for name, chain in chains.items()
    )
