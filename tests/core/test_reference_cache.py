"""Decoded references on local disk (metrology.core.reference_cache): stored and read back bit for
bit, the same heights, a hit for the same stack and a miss for any other."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core import local_cache
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.geometry.pinhole import PinholeReference
from metrology.core.io import read_stack, write_stack
from metrology.core.io.digests import capture_files_digest
from metrology.core.measure import MeasureOptions, measure, prepare_reference
from metrology.core.reference_cache import (
    KIND,
    cached_reference,
    cached_reference_of_files,
    reference_arrays,
    reference_from_arrays,
    reference_key,
    stack_digest,
)
from tests.app.stacks import SMALL_RIG, render_images

RIG = Rig.from_dict(SMALL_RIG)  # 160 x 120 px


@pytest.fixture(scope="module")
def stacks() -> tuple[np.ndarray, np.ndarray]:
    z_true = np.zeros(RIG.shape)
    z_true[30:90, 40:120] = 15.0
    return render_images(RIG, 0.0, bit_depth=16), render_images(RIG, z_true, bit_depth=16)


def _same(a: np.ndarray | None, b: np.ndarray | None) -> None:
    assert (a is None) == (b is None)
    if a is not None:
        assert a.dtype == b.dtype and a.shape == b.shape  # type: ignore[union-attr]
        np.testing.assert_array_equal(a, b)


def test_arrays_round_trip_bit_for_bit(stacks) -> None:
    reference = prepare_reference(RIG, stacks[0])
    options = MeasureOptions()
    arrays = {name: a.copy() for name, a in reference_arrays(reference).items()}
    assert arrays["unreliable_bits"].nbytes * 8 >= reference.unreliable.size  # type: ignore[union-attr]
    assert "surface.codes" not in arrays  # the surface's codes are the reference's: stored once
    back = reference_from_arrays(arrays, RIG, None, options)
    _same(back.codes, reference.codes)
    _same(back.unreliable, reference.unreliable)
    for got, want in ((back.surface, reference.surface), (back.gray_surface, reference.gray_surface)):
        assert type(got) is type(want)
        _same(got.codes, want.codes)  # type: ignore[union-attr]
        _same(got.slope_mm, want.slope_mm)  # type: ignore[union-attr]
    assert back.blur_variance_px2 == reference.blur_variance_px2
    np.testing.assert_array_equal(
        measure(RIG, stacks[1], reference=back).z_mm, measure(RIG, stacks[1], reference=reference).z_mm
    )


def test_a_fitted_plane_round_trips() -> None:
    plane = PinholeReference(
        frame_shape=(120, 160), centroid=np.array([1.0, 2.0, 600.0]), normal=np.array([0, 0, -1.0]), n_points=42
    )
    reference = prepare_reference(RIG, render_images(RIG, 0.0))
    arrays = reference_arrays(type(reference)(**{**reference.__dict__, "surface": plane, "unreliable": None}))
    back = reference_from_arrays(arrays, RIG, None, MeasureOptions())
    assert back.surface == plane or (
        back.surface.frame_shape == (120, 160)  # type: ignore[attr-defined]
        and back.surface.n_points == 42  # type: ignore[attr-defined]
        and np.array_equal(back.surface.normal, plane.normal)  # type: ignore[attr-defined]
    )
    assert back.unreliable is None
    with pytest.raises(ValueError, match="not a stored reference"):
        reference_from_arrays({"meta": np.frombuffer(b"{}", np.uint8)}, RIG, None, MeasureOptions())


def test_second_call_hits_and_another_stack_or_option_misses(stacks, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path))
    reference, first = cached_reference(RIG, stacks[0])
    local_cache.wait()
    assert not first["hit"] and local_cache.info().kinds[KIND][0] == 1
    again, second = cached_reference(RIG, stacks[0])
    assert second["hit"]
    _same(again.codes, reference.codes)
    np.testing.assert_array_equal(
        measure(RIG, stacks[1], reference=again).z_mm, measure(RIG, stacks[1], reference=stacks[0]).z_mm
    )
    other = stacks[0].copy()
    other[0, 0, 0] ^= 1
    assert stack_digest(other) != stack_digest(stacks[0])
    assert not cached_reference(RIG, other)[1]["hit"]
    changed = MeasureOptions(gray_only=False)
    assert reference_key(RIG, stack_digest(stacks[0]), None, changed) != reference_key(
        RIG, stack_digest(stacks[0]), None, MeasureOptions()
    )
    assert not cached_reference(RIG, stacks[0], None, changed)[1]["hit"]
    local_cache.wait()


def test_files_key_hits_without_reading_and_any_changed_file_misses(stacks, tmp_path, monkeypatch) -> None:
    """Keyed by the capture's files: a hit reads no image (``read`` is never called); a changed,
    added or renamed file, another reader or another option misses."""
    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path / "cache"))
    capture = tmp_path / "reference"
    write_stack(stacks[0], capture)
    reads: list[int] = []

    def read() -> np.ndarray:
        reads.append(1)
        return read_stack(capture, rig=RIG).images

    def never() -> np.ndarray:
        raise AssertionError("a hit must not read the capture's images")

    reader = {"reader": "test/1"}
    reference, first = cached_reference_of_files(RIG, capture, read, reader)
    local_cache.wait()
    assert not first["hit"] and first["key"] == "files" and first["read_s"] > 0 and reads == [1]
    kept, second = cached_reference_of_files(RIG, capture, never, reader)
    assert second["hit"] and "read_s" not in second
    # the files' digest computed beforehand (gcps measure starts it with the command): the same key;
    # another digest is another key
    early = capture_files_digest(capture)
    assert cached_reference_of_files(RIG, capture, never, reader, digest=lambda: early)[1]["hit"]
    assert not cached_reference_of_files(RIG, capture, read, reader, digest=lambda: "0" * 64)[1]["hit"]
    local_cache.wait()
    del reads[1:]
    _same(kept.codes, reference.codes)
    _same(kept.surface.slope_mm, reference.surface.slope_mm)  # type: ignore[attr-defined]
    assert not cached_reference_of_files(RIG, capture, read, {"reader": "test/2"})[1]["hit"]
    assert not cached_reference_of_files(RIG, capture, read, reader, None, MeasureOptions(gray_only=False))[1]["hit"]

    digest = capture_files_digest(capture)
    (capture / "notes.txt").write_text("x")  # an added file
    assert capture_files_digest(capture) != digest
    (capture / "notes.txt").rename(capture / "notes2.txt")  # a renamed one
    renamed = capture_files_digest(capture)
    assert renamed != digest
    (capture / "notes2.txt").unlink()
    assert capture_files_digest(capture) == digest
    changed = stacks[0].copy()
    changed[7, 5, 5] ^= 1  # one grey level of one pixel of PS_0
    write_stack(changed, capture)
    assert capture_files_digest(capture) != digest
    local_cache.wait()
    missed, third = cached_reference_of_files(RIG, capture, read, reader)
    assert not third["hit"] and len(reads) == 4
    assert missed.codes.shape == RIG.shape
    local_cache.wait()  # the miss's entry is written on a background thread
    assert cached_reference_of_files(RIG, capture, never, reader)[1]["hit"]


def test_without_gray_only_the_gray_surface_is_not_kept(stacks, tmp_path, monkeypatch) -> None:
    """The options (in the key) ask for no gray-code-only heights: the entry leaves out the gray
    surface, and the heights measured against the kept reference are the same."""
    monkeypatch.setenv(local_cache.DIR_ENV, str(tmp_path))
    options = MeasureOptions(gray_only=False)
    reference, first = cached_reference(RIG, stacks[0], None, options)
    local_cache.wait()
    kept, second = cached_reference(RIG, stacks[0], None, options)
    assert not first["hit"] and second["hit"]
    assert reference.gray_surface is not None and kept.gray_surface is None
    np.testing.assert_array_equal(
        measure(RIG, stacks[1], reference=kept, options=options).z_mm,
        measure(RIG, stacks[1], reference=reference, options=options).z_mm,
    )
