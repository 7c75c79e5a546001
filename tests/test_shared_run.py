"""The arrays that one process of a test run makes for the others (tests/shared_run.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.shared_run import RUN_FOLDER_ENV, arrays_made_once


def test_arrays_are_made_once_per_run_folder_and_read_back_bit_for_bit(tmp_path, monkeypatch):
    monkeypatch.setenv(RUN_FOLDER_ENV, str(tmp_path))
    made: list[int] = []
    rng = np.random.default_rng(3)
    arrays = (rng.integers(0, 256, (4, 5, 6), dtype=np.uint8), rng.normal(size=(7,)).astype(np.float32))

    def make() -> tuple[np.ndarray, ...]:
        made.append(1)
        return arrays

    first = arrays_made_once("things", make)
    again = arrays_made_once("things", make)  # as another worker of the run would ask
    assert len(made) == 1
    assert len(again) == 2
    for original, read in zip(arrays, again, strict=True):
        assert read.dtype == original.dtype and read.shape == original.shape
        assert np.array_equal(read, original)
    assert first is arrays
    arrays_made_once("other things", make)  # another name is made on its own
    assert len(made) == 2


def test_without_a_run_folder_the_arrays_are_made_each_time(monkeypatch):
    monkeypatch.delenv(RUN_FOLDER_ENV, raising=False)
    made: list[int] = []

    def make() -> tuple[np.ndarray, ...]:
        made.append(1)
        return (np.zeros(2),)

    arrays_made_once("things", make)
    arrays_made_once("things", make)
    assert made == [1, 1]


@pytest.mark.parametrize("count", [0, 3])
def test_a_maker_that_died_before_writing_the_index_is_made_again(tmp_path, monkeypatch, count):
    """The index (``<name>.count``) is written last: arrays without it are made again."""
    monkeypatch.setenv(RUN_FOLDER_ENV, str(tmp_path))
    for i in range(count):
        np.save(tmp_path / f"things-{i}.npy", np.full(3, 9.0))  # a dead maker's partial output
    read = arrays_made_once("things", lambda: (np.arange(3.0),))
    assert len(read) == 1 and np.array_equal(read[0], np.arange(3.0))
    assert (tmp_path / "things.count").read_text() == "1"
