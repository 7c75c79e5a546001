"""docs/datasets.md says where to get the real captures and how to prepare them: its codec of
kamino410 ``object1`` loads (and is the prepared folder's, when that is present), and every test
that reads a dataset skips (or fails under CI) through ``require_dataset`` and is listed there."""

from __future__ import annotations

import json
import re
from pathlib import Path

from metrology.core.codecs import read_codec
from tests.datasets import dataset_path, require_dataset

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "datasets.md"


def documented_codec() -> dict:
    blocks = re.findall(r"```json\n(.*?)```", PAGE.read_text(), re.S)
    assert len(blocks) == 1, "docs/datasets.md holds one JSON block: the codec of object1"
    return json.loads(blocks[0])


def test_the_documented_codec_loads(tmp_path):
    path = tmp_path / "object1.codec.json"
    path.write_text(json.dumps(documented_codec()))
    codec = read_codec(path)
    assert codec.n_frames == 32 and sorted(codec.axes) == ["u", "v"]
    assert (codec.projector_width, codec.projector_height) == (1920, 1080)


def test_the_documented_codec_is_the_prepared_folders():
    prepared = dataset_path("kamino410-phase-shifting", "object1.codec.json")
    require_dataset(prepared, "the prepared codec of kamino410 object1")
    assert documented_codec() == json.loads(prepared.read_text())


def test_every_test_that_reads_a_dataset_requires_it_and_is_listed():
    page = PAGE.read_text()
    readers = [
        path
        for path in sorted((ROOT / "tests").rglob("*.py"))
        if path.name != "datasets.py" and path != Path(__file__) and "dataset_path(" in path.read_text()
    ]
    assert readers, "no test reads a dataset: this test looks for the wrong name"
    for path in readers:
        assert "require_dataset(" in path.read_text(), f"{path} reads a dataset without require_dataset"
        assert str(path.relative_to(ROOT)) in page, f"docs/datasets.md does not list {path.relative_to(ROOT)}"
