"""Fixtures for the whole test suite: rate limits raised so that no test is throttled by accident,
a fast password hasher, a temporary MEDIA_ROOT for every test, two users with passwords, logged-in
clients, a small rig, and the headless-Chromium page of the browser tests.

The tests of the rate limits themselves (tests/app/test_throttling.py) lower them again; the
application tests (tests/app/conftest.py) add API clients and make their rig through the API; the
integration tests (tests/app/integration/conftest.py) keep the media root out of the settings.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
from contextlib import closing
from pathlib import Path

import pytest
from django.test import Client

from metrology.accounts.services import create_user_with_token
from metrology.devserver import disable_nagle
from metrology.rigs.services import create_rig
from tests.app.stacks import SMALL_RIG
from tests.browser import TIMEOUT_MS, shared_browser
from tests.shared_run import migrations_digest, run_folder, run_lock

disable_nagle()  # pytest-django's live server is Django's development server (metrology/devserver.py)

#: Far above anything a test does (the suite's fastest loops make a few hundred requests).
RAISED_RATE = "1000000/hour"
#: The password of the users made here (the log-in tests type it).
PASSWORD = "a-long-test-password-42"

#: Thread pools of the native libraries, one thread each when the suite runs on several pytest-xdist
#: workers: each worker is a process of its own, and OpenBLAS's threads spin while they wait, so
#: that four workers with two BLAS threads each on two cores spent most of their time spinning
#: (a procam calibration: 1.0 s with one thread, 1.4-2.1 s with the default, on the shared machine).
SINGLE_THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
#: Markers of the long tests, which the scheduling below starts first.
LONG_MARKERS = ("slow", "integration", "browser")
WAITING_MARKERS = ("integration", "browser")
"""Long tests that mostly wait (on servers, Celery workers, Redis, Chromium): a fault test uses
about a fifth of its wall time's CPU in its processes, a slow core test nearly all of it."""


def runs_on_xdist_workers(config: pytest.Config) -> bool:
    """True in the controller of a ``-n N`` run (N > 0) and in its workers."""
    return hasattr(config, "workerinput") or bool(config.getoption("numprocesses", default=None))


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist, the native thread pools of the workers (and of every process a test
    starts) are set to one thread before the workers start: the environment is inherited, and read
    when numpy and OpenCV are first imported. A value already in the environment is kept."""
    if runs_on_xdist_workers(config):
        for name in SINGLE_THREAD_ENV:
            os.environ.setdefault(name, "1")


def shared_setup_group(item: pytest.Item) -> str | None:
    """The module of ``item`` when it uses a fixture of module or class scope (a render, a decoded
    stack, a calibration made once for the module's tests), else None."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:  # doctests
        return None
    module = item.nodeid.split("::")[0]
    if "module_browser" in getattr(item, "fixturenames", ()):  # the module's Chromium (browser_page)
        return f"module-fixtures:{module}"
    for definitions in info.name2fixturedefs.values():
        # the module's own fixtures (plugins' autouse class fixtures have another baseid)
        if definitions and definitions[-1].scope in ("module", "class") and definitions[-1].baseid == module:
            return f"module-fixtures:{module}"
    return None


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's own hook reads the xdist_group marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under pytest-xdist (``--dist loadgroup``):

    - the tests of a module that use one of its module- or class-scoped fixtures share an
      ``xdist_group``, so that they run on one worker and the fixture is made once, not once per
      worker (tests grouped by hand keep their group);
    - the long tests (marked ``slow``, ``integration`` or ``browser``) come first, the others after:
      xdist hands the work out in this order (with ``--no-loadscope-reorder``), so the long ones
      start at once instead of being the last ones running while the other workers idle. Among the
      long ones, those that mostly wait (:data:`WAITING_MARKERS`) are spread evenly between those
      that compute (:func:`long_tests_first`): in collection order, the integration tests came
      together and for about a minute all four workers waited on their servers with the two cores
      40-60 % idle.

    Every worker sorts the same collection the same way, as xdist requires."""
    if not runs_on_xdist_workers(config):
        return
    for item in items:
        if item.get_closest_marker("xdist_group") is None and (group := shared_setup_group(item)):
            item.add_marker(pytest.mark.xdist_group(group))
        if config.getoption("dist", default="no") == "loadgroup" or getattr(config.option, "loadgroup", False):
            name_group_in_nodeid(item)
    items[:] = long_tests_first(items)


def long_tests_first(items: list[pytest.Item]) -> list[pytest.Item]:
    """``items`` with the long tests first, the waiting ones (:data:`WAITING_MARKERS`) and the
    computing ones each kept in collection order and merged by their fraction of their own list
    (test ``k`` of ``n`` at ``(k + 1/2) / n``), then the others in collection order."""

    def marked(item: pytest.Item, names: tuple[str, ...]) -> bool:
        return any(item.get_closest_marker(name) for name in names)

    long_items = [item for item in items if marked(item, LONG_MARKERS)]
    waiting = [item for item in long_items if marked(item, WAITING_MARKERS)]
    computing = [item for item in long_items if not marked(item, WAITING_MARKERS)]
    place = {id(item): (k + 0.5) / len(part) for part in (waiting, computing) for k, item in enumerate(part)}
    return sorted(long_items, key=lambda item: place[id(item)]) + [
        item for item in items if not marked(item, LONG_MARKERS)
    ]


def name_group_in_nodeid(item: pytest.Item) -> None:
    """``nodeid@group`` for an item with ``xdist_group`` marks, which is how ``--dist loadgroup``
    finds the groups. pytest-xdist 3.8 writes it to ``item._nodeid``, which pytest 9 no longer reads
    (the node id is ``item._id``, a ``NodeId``): without this every group was split over the workers
    (a module fixture of 90 s made on four of them)."""
    names = sorted(
        {
            str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
            for mark in item.iter_markers("xdist_group")
        }
    )
    nodeid = item.nodeid
    if not names or nodeid.rfind("@") > nodeid.rfind("]"):
        return
    suffixed = f"{nodeid}@{'_'.join(names)}"
    node_id = getattr(item, "_id", None)
    if node_id is not None and type(node_id).__name__ == "NodeId":
        item._id = type(node_id).parse(suffixed)  # type: ignore[attr-defined]
    else:
        item._nodeid = suffixed  # type: ignore[attr-defined]


def pytest_sessionfinish(session: pytest.Session) -> None:
    """In the run's controller (or the only process, without xdist), after every worker has
    finished: drop the PostgreSQL template that the integration tests' workers shared
    (tests/app/integration/harness.py, ``migrated_template``)."""
    if not hasattr(session.config, "workerinput"):
        from tests.app.integration.harness import drop_run_templates

        drop_run_templates(run_folder(session.config))


@pytest.fixture(autouse=True, scope="session")
def shared_run_folder(request):
    """``GCPS_TEST_RUN_FOLDER``: the folder the run's workers share (tests/shared_run.py), where the
    integration harness finds the migrated PostgreSQL template one of them made."""
    from tests.app.integration.harness import RUN_FOLDER_ENV

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(RUN_FOLDER_ENV, str(run_folder(request.config)))
        yield


@pytest.fixture(autouse=True, scope="session")
def local_cache_dir(tmp_path_factory):
    """The local cache of prepared tables (metrology.core.local_cache) in a folder of the session,
    never the user's ~/.cache/gcps; processes started by the tests inherit it."""
    with pytest.MonkeyPatch.context() as mp:
        root = tmp_path_factory.mktemp("local-cache")
        mp.setenv("GCPS_LOCAL_CACHE_DIR", str(root))
        yield root


@pytest.fixture(scope="session")
def django_db_setup(
    request, django_test_environment, django_db_blocker, django_db_keepdb, django_db_use_migrations,
    django_db_modify_db_settings,
):  # fmt: skip
    """pytest-django's ``django_db_setup`` (the test database made before the first test that needs
    one, dropped after the last), except that the embedded SQLite database is migrated once per run
    and copied: the first pytest-xdist worker to need it migrates its own and leaves a copy, keyed by
    :func:`migrations_digest`, in the run's temporary folder; the others copy that file and find
    nothing to migrate. ``manage.py migrate`` of the 47 migrations takes about 4 s of CPU, once per
    worker before. PostgreSQL test databases (``DATABASE_URL``) are made as pytest-django makes them.
    ``--reuse-db`` keeps the database as pytest-django does; ``--nomigrations`` is not supported (the
    suite tests its migrations)."""
    from django.db import connections
    from django.test.utils import setup_databases, teardown_databases

    if not django_db_use_migrations:
        raise pytest.UsageError("--nomigrations: the suite runs (and tests) its migrations")
    connection = connections["default"]
    test_name = connection.settings_dict.get("TEST", {}).get("NAME")
    verbosity = request.config.option.verbose

    def setup(keepdb: bool):  # type: ignore[no-untyped-def]
        with django_db_blocker.unblock():
            return setup_databases(verbosity=verbosity, interactive=False, keepdb=keepdb, serialized_aliases=set())

    if connection.vendor != "sqlite" or not test_name or str(test_name) == ":memory:" or django_db_keepdb:
        config = setup(keepdb=django_db_keepdb)
    else:
        root = run_folder(request.config)
        template = root / f"migrated-{migrations_digest()}.sqlite3"
        with run_lock(root, "migrated-sqlite"):
            made_here = not template.exists()
            if made_here:
                config = setup(keepdb=False)
                partial = template.with_suffix(".partial")
                with closing(sqlite3.connect(test_name)) as source, closing(sqlite3.connect(partial)) as copy:
                    source.backup(copy)  # the pages of the database and of its write-ahead log
                os.replace(partial, template)
        if not made_here:
            for stale in (f"{test_name}-wal", f"{test_name}-shm"):  # a dead process's log would be replayed
                Path(stale).unlink(missing_ok=True)
            shutil.copyfile(template, test_name)
            config = setup(keepdb=True)  # finds the copy, every migration applied
    yield
    if not django_db_keepdb:
        with django_db_blocker.unblock():
            teardown_databases(config, verbosity=verbosity)
        if connection.vendor == "sqlite" and test_name and str(test_name) != ":memory:":
            for log in (f"{test_name}-wal", f"{test_name}-shm"):  # Django removes the database file only
                Path(log).unlink(missing_ok=True)


@pytest.fixture(scope="session")
def s3(tmp_path_factory):
    """A real S3-protocol server (moto_server, its own process) for the session: tests/s3.py."""
    from tests.s3 import s3_server

    with s3_server(tmp_path_factory.mktemp("s3") / "moto.log") as server:
        yield server


@pytest.fixture(autouse=True)
def raised_throttle_rates(settings) -> None:
    settings.GCPS_THROTTLE_RATES = dict.fromkeys(settings.GCPS_THROTTLE_RATES, RAISED_RATE)


@pytest.fixture(autouse=True)
def jobs_run_inline(settings) -> None:
    """On the embedded default, a job runs in the request that created it (``GCPS_EMBEDDED_JOBS=inline``),
    so that a test finds it finished when the request returns; the tests of the background thread
    (tests/app/test_embedded_jobs.py) and the browser tests' ``worker`` set their own way."""
    settings.GCPS_EMBEDDED_JOBS = "inline"


@pytest.fixture(autouse=True)
def fast_password_hasher(settings) -> None:
    """Passwords hashed with MD5, not PBKDF2's million rounds (a quarter of a second for each user
    made with a password, each password log-in and each failed one): the tests check who may log
    in, not the hasher's cost. Processes started by the tests keep the settings' hashers."""
    settings.PASSWORD_HASHERS = ["django.contrib.auth.hashers.MD5PasswordHasher"]


@pytest.fixture(autouse=True)
def media_root(settings, tmp_path_factory) -> Path:
    """Every test stores files in its own temporary folder (not inside ``tmp_path``, which some tests
    expect to hold only what they wrote there)."""
    root = tmp_path_factory.mktemp("media")
    settings.MEDIA_ROOT = root
    return root


def stored_files(root: Path) -> list[Path]:
    return sorted(path for path in root.rglob("*") if path.is_file())


@pytest.fixture
def alice_token(db):
    """The user alice and her API token."""
    return create_user_with_token(username="alice", password=PASSWORD)


@pytest.fixture
def alice(alice_token):
    return alice_token[0]


@pytest.fixture
def bob(db):
    return create_user_with_token(username="bob", password=PASSWORD)[0]


def logged_in(user) -> Client:
    client = Client()
    client.force_login(user)
    return client


def log_page_in(page, user, base_url: str) -> None:
    """Give a Playwright ``page`` ``user``'s session on the server at ``base_url`` (a session cookie
    made by :func:`logged_in`, without going through the login form)."""
    session = logged_in(user).cookies["sessionid"].value
    page.context.add_cookies([{"name": "sessionid", "value": session, "url": base_url}])


@pytest.fixture
def client_alice(alice) -> Client:
    return logged_in(alice)


@pytest.fixture
def client_bob(bob) -> Client:
    return logged_in(bob)


@pytest.fixture
def rig(alice):
    """Alice's small crossed-axes rig (SMALL_RIG), made through the services."""
    return create_rig(owner=alice, data={**SMALL_RIG, "name": "bench"})


@pytest.fixture(scope="module")
def module_browser():
    """One headless Chromium for a test module's browser tests (tests/browser.py, ``SharedBrowser``):
    a launch costs about 1.4 s of CPU. Between the tests no event loop is marked running in the
    thread, and the browser stops at the module's end, so that the tests after it (browser or not)
    run as without it. ``shared_setup_group`` keeps a module's tests that use it on one worker."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with shared_browser(sync_api) as shared:
        yield shared


@pytest.fixture
def browser_page(module_browser):
    """A page of headless Chromium (1280 x 900) in a browser context of its own (its own cookies and
    storage) that collects the page's JavaScript errors in ``js_errors``."""
    module_browser.resume()
    context = module_browser.browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    page = context.new_page()
    page.set_default_timeout(TIMEOUT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.js_errors = errors
    yield page
    module_browser.resume()  # a test may have cleared the mark (asyncio.run does on its way out)
    context.close()
    module_browser.idle()
