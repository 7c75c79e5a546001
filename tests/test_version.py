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
