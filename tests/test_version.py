"""The software version names the git commit of the running code, +dirty when the tree differs."""

import subprocess
from pathlib import Path

import pytest

from metrology import version


def git(root: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture
def checkout(tmp_path):
    root = tmp_path / "repo"
    root.mkdir()
    git(root, "init", "-q")
    git(root, "config", "user.email", "t@example.org")
    git(root, "config", "user.name", "t")
    (root / "code.py").write_text("x = 1\n")
    git(root, "add", "code.py")
    git(root, "commit", "-qm", "one")
    return root


def test_clean_checkout_reports_its_commit(checkout):
    head = git(checkout, "rev-parse", "HEAD")
    assert version.describe(checkout) == f"gcps-lab {version.package_version()} {head[:12]}"


def test_modified_or_added_file_makes_it_dirty(checkout):
    (checkout / "code.py").write_text("x = 2\n")
    assert version.describe(checkout).endswith(git(checkout, "rev-parse", "HEAD")[:12] + "+dirty")
    git(checkout, "checkout", "code.py")
    (checkout / "new.py").write_text("y = 1\n")
    assert version.describe(checkout).endswith("+dirty")


def test_a_new_commit_is_seen_at_once(checkout):
    first = version.describe(checkout)
    (checkout / "code.py").write_text("x = 3\n")
    git(checkout, "commit", "-qam", "two")
    second = version.describe(checkout)
    assert second != first and second.endswith(git(checkout, "rev-parse", "HEAD")[:12])


def test_outside_a_checkout_says_so(tmp_path, monkeypatch, checkout):
    monkeypatch.delenv("GCPS_GIT_COMMIT", raising=False)
    plain = tmp_path / "plain"
    plain.mkdir()
    assert version.describe(plain).endswith(" unknown commit")
    sub = checkout / "pkg"  # a folder inside someone else's repository is not our checkout
    sub.mkdir()
    assert version.describe(sub).endswith(" unknown commit")
    monkeypatch.setenv("GCPS_GIT_COMMIT", "0123456789abcdef0123")
    assert version.describe(plain).endswith(" 0123456789ab")


def test_running_code_reports_this_checkout():
    root = version.SOURCE_ROOT
    if version.git_revision(root) is None:
        pytest.skip(f"{root} is not a git checkout")
    assert version.software_version().split()[-1].startswith(git(root, "rev-parse", "HEAD")[:12])
    assert len(version.software_version()) <= 64  # fits Job.software_version


def metadata_version(name: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "0+unknown"


@pytest.mark.parametrize("name", ["gcps-lab", "numpy", "opencv-python-headless", "Django", "PyYAML", "not-installed-x"])
def test_the_package_version_is_importlib_metadatas(name):
    """Read without importing importlib.metadata (version._metadata_version), the same version."""
    assert version.package_version() == metadata_version(version.PACKAGE)
    found = version._metadata_version(name)
    assert found in (None, metadata_version(name))
    assert found is not None  # this environment's path holds only folders


def test_the_version_search_follows_the_path_order_and_defers_where_it_differs(tmp_path, monkeypatch):
    first, second = tmp_path / "first", tmp_path / "second"
    (first / "Some_Dist-2.0.dist-info").mkdir(parents=True)
    metadata = "Metadata-Version: 2.1\nName: some-dist\nVersion: 2.0\n"
    (first / "Some_Dist-2.0.dist-info" / "METADATA").write_text(metadata)
    (second / "some.dist.egg-info").mkdir(parents=True)
    (second / "some.dist.egg-info" / "PKG-INFO").write_text("Name: some.dist\nVersion: 1.0b1\n\nVersion: 9\n")
    monkeypatch.setattr("sys.path", [str(tmp_path / "missing"), str(first), str(second)])
    assert version._metadata_version("some-dist") == "2.0" == metadata_version("some-dist")
    monkeypatch.setattr("sys.path", [str(second), str(first)])
    assert version._metadata_version("Some_Dist") == "1.0b1" == metadata_version("Some_Dist")
    assert version._metadata_version("other") == "0+unknown" == metadata_version("other")
    (second / "Some.Dist-1.0.dist-info").mkdir()  # two in one folder: importlib.metadata's listing order
    assert version._metadata_version("some-dist") is None
    (tmp_path / "lib.zip").write_bytes(b"")  # a zip on the path: importlib.metadata reads it
    monkeypatch.setattr("sys.path", [str(tmp_path / "lib.zip"), str(first)])
    assert version._metadata_version("some-dist") is None
