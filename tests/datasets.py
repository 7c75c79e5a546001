"""The real-capture datasets the tests use: ``$GCPS_SHARED_DATASETS`` when set, else the
``shared/datasets`` folder beside the project (a git worktree one level deeper also finds it).

They are MIT licensed and never copied into the repository. A test that needs one is skipped,
naming the folder, when it is absent, except under ``CI=true``, where its absence fails.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def datasets_root() -> Path:
    """The datasets folder (it may not exist)."""
    if os.environ.get("GCPS_SHARED_DATASETS"):
        return Path(os.environ["GCPS_SHARED_DATASETS"])
    candidates = [ROOT.parent / "shared" / "datasets", ROOT.parent.parent / "shared" / "datasets"]
    return next((c for c in candidates if c.is_dir()), candidates[0])


def dataset_path(*parts: str) -> Path:
    """A path inside the datasets folder."""
    return datasets_root().joinpath(*parts)


def require_dataset(path: Path, what: str) -> None:
    """Skip the calling test, or fail it under ``CI=true``, unless ``path`` (a folder or file the
    test reads, e.g. a dataset's first capture) exists; ``what`` names the dataset in the message."""
    if path.exists():
        return
    message = (
        f"{what} not found: {path} is missing (docs/datasets.md says where to get it and how to prepare it); "
        "real-capture test skipped"
    )
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(message.replace("skipped", "required under CI=true"))
    pytest.skip(message)
