"""The per-host local cache of prepared tables: keys, atomic writes, checksums, eviction, and
failures that warn instead of failing."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from metrology.core import local_cache
from metrology.core.local_cache import LocalCacheWarning


def _arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "xn": rng.standard_normal((7, 5)),
        "base": np.arange(12, dtype=np.int32).reshape(3, 4),
        "frac": rng.random(9).astype(np.float32),
        "empty": np.zeros((0, 8), np.float32),
        "flags": np.array([True, False, True]),
    }


def test_round_trip_keeps_values_dtypes_and_shapes(tmp_path: Path) -> None:
    arrays = _arrays()
    assert local_cache.store("kind", "k1", arrays, tmp_path)
    got = local_cache.load("kind", "k1", tmp_path)
    assert got is not None and set(got) == set(arrays)
    for name, a in arrays.items():
        assert got[name].dtype == a.dtype and got[name].shape == a.shape
        np.testing.assert_array_equal(got[name], a)
    assert got["xn"].flags.writeable
    assert [p.name for p in (tmp_path / "kind").iterdir()] == ["k1.gcpsc"]  # no temporary file left
    assert local_cache.load("kind", "absent", tmp_path) is None


@pytest.mark.parametrize("where", ["payload", "header", "truncated"])
def test_corruption_is_detected_warned_and_removed(tmp_path: Path, where: str) -> None:
    local_cache.store("kind", "k", _arrays(), tmp_path)
    path = tmp_path / "kind" / "k.gcpsc"
    data = bytearray(path.read_bytes())
    if where == "payload":
        data[-3] ^= 0x01  # one bit of the last array
    elif where == "header":
        data[60] ^= 0x20
    else:
        data = data[: len(data) // 2]
    path.write_bytes(bytes(data))
    with pytest.warns(LocalCacheWarning, match="corrupted"):
        assert local_cache.load("kind", "k", tmp_path) is None
    assert not path.exists()


def test_unwritable_cache_warns_and_goes_on(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with pytest.warns(LocalCacheWarning, match="cannot write"):
        assert local_cache.store("kind", "k", _arrays(), blocker / "cache") is False
    with pytest.warns(LocalCacheWarning, match="cannot read"):
        assert local_cache.load("kind", "k", blocker / "cache") is None


def test_size_bound_evicts_the_least_recently_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blob = {"a": np.zeros(10_000, np.float64)}  # ~80 kB per entry
    for i, key in enumerate(("old", "used", "new")):
        local_cache.store("kind", key, blob, tmp_path)
        os.utime(tmp_path / "kind" / f"{key}.gcpsc", (time.time() - 100 + i, time.time() - 100 + i))
    assert local_cache.load("kind", "used", tmp_path) is not None  # a hit makes it the most recent
    monkeypatch.setenv(local_cache.MAX_BYTES_ENV, str(200_000))
    local_cache.store("kind", "newest", blob, tmp_path)
    left = sorted(p.stem for p in (tmp_path / "kind").iterdir())
    assert left == ["newest", "used"]
    info = local_cache.info(tmp_path)
    assert info.entries == 2 and info.bytes <= 200_000 and info.kinds["kind"][0] == 2
    assert local_cache.clear(tmp_path) == 2 and local_cache.info(tmp_path).entries == 0


def test_folder_from_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path / "explicit"))
    assert local_cache.cache_dir() == tmp_path / "explicit"
    monkeypatch.delenv(local_cache.DIR_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert local_cache.cache_dir() == tmp_path / "xdg" / "gcps"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert local_cache.cache_dir() == Path.home() / ".cache" / "gcps"


def test_keys_depend_on_every_part() -> None:
    base = {"rig": {"T": [1, 2, 3]}, "shape": [4, 5]}
    key = local_cache.entry_key("pinhole", base)
    assert key == local_cache.entry_key("pinhole", dict(reversed(list(base.items()))))
    assert key != local_cache.entry_key("pinhole", {**base, "shape": [5, 4]})
    assert key != local_cache.entry_key("other", base)


def test_cache_command_info_and_clear(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    from metrology.cli import main

    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path))
    local_cache.store("pinhole", "k", _arrays(), tmp_path)
    assert main(["cache", "info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["path"] == str(tmp_path) and info["entries"] == 1 and info["kinds"]["pinhole"]["entries"] == 1
    assert main(["cache", "clear"]) == 0
    assert json.loads(capsys.readouterr().out)["removed"] == 1
    assert local_cache.info(tmp_path).entries == 0
