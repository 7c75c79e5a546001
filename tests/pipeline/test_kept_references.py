"""Kept references (metrology.pipeline.kept_references): hits, misses, eviction by bytes, same heights."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.measure import prepare_reference
from metrology.core.synthetic import exact_codes
from metrology.pipeline.kept_references import KeptReferences, reference_nbytes
from metrology.pipeline.measure import measure
from tests.app.stacks import SMALL_RIG, render_images

RIG = Rig.from_dict(SMALL_RIG)  # 160 x 120 px


@pytest.fixture(scope="module")
def reference_images() -> np.ndarray:
    return render_images(RIG, 0.0, bit_depth=16)


def test_reference_nbytes_counts_every_array_once(reference_images) -> None:
    reference = prepare_reference(RIG, reference_images)
    n = reference_nbytes(reference)
    gray_codes = reference.gray_surface.codes  # type: ignore[union-attr]
    assert n >= reference.codes.nbytes + gray_codes.nbytes + reference.unreliable.nbytes  # type: ignore[union-attr]
    assert n < 40 * RIG.width_px * RIG.height_px  # no array counted twice (about 20 B/px here)
    base = np.zeros(1000)
    assert reference_nbytes({"a": base, "b": base[:10], "c": (base,)}) == 8000


def test_hits_misses_and_eviction_by_bytes(reference_images) -> None:
    calls: list[str] = []

    def prepare(name: str):
        def run():
            calls.append(name)
            return prepare_reference(RIG, reference_images)

        return run

    size = reference_nbytes(prepare("probe")())
    kept = KeptReferences(max_bytes=2 * size + size // 2)  # room for two
    a, hit = kept.get("a", prepare("a"))
    assert not hit and kept.stats.misses == 1
    again, hit = kept.get("a", prepare("a"))
    assert hit and again is a and calls.count("a") == 1
    kept.get("b", prepare("b"))
    kept.get("a", prepare("a"))  # a becomes the most recently used
    kept.get("c", prepare("c"))  # evicts b, the least recently used
    assert "a" in kept and "c" in kept and "b" not in kept
    assert kept.stats.evictions == 1 and kept.nbytes == 2 * size
    _, hit = kept.get("b", prepare("b"))
    assert not hit and calls.count("b") == 2
    assert (kept.stats.hits, kept.stats.misses) == (2, 4)


def test_a_reference_larger_than_the_bound_is_kept_alone(reference_images) -> None:
    kept = KeptReferences(max_bytes=1000)
    reference, hit = kept.get("a", lambda: prepare_reference(RIG, reference_images))
    assert not hit and len(kept) == 1 and reference.codes.shape == RIG.shape
    assert kept.get("a", lambda: None)[1]  # type: ignore[arg-type,return-value]
    kept.get("b", lambda: prepare_reference(RIG, reference_images))
    assert "b" in kept and "a" not in kept and kept.stats.evictions == 1
    none = KeptReferences(max_bytes=0)
    none.get("a", lambda: prepare_reference(RIG, reference_images))
    assert len(none) == 0
    with pytest.raises(ValueError, match="max_bytes must be a non-negative integer, got -5"):
        KeptReferences(-5)


def test_kept_reference_gives_the_heights_of_a_fresh_decode(reference_images) -> None:
    z_true = np.zeros(RIG.shape)
    z_true[30:90, 40:120] = 15.0
    obj = render_images(RIG, z_true, bit_depth=16)
    kept = KeptReferences(max_bytes=10**9)
    reference, _ = kept.get("r", lambda: prepare_reference(RIG, reference_images))
    fresh = measure(RIG, reference_images, obj).z_mm
    for _ in range(2):
        again = measure(RIG, kept.get("r", lambda: None)[0], obj).z_mm  # type: ignore[arg-type,return-value]
        np.testing.assert_array_equal(again, fresh)
    assert reference is kept.get("r", lambda: None)[0]  # type: ignore[arg-type,return-value]
    inside = np.isfinite(fresh) & np.isfinite(exact_codes(RIG, z_true))
    assert inside.mean() > 0.5
    assert np.median(np.abs(fresh[inside] - z_true[inside])) < 0.001


def test_a_12_mp_reference_is_kept_by_the_workers_default_bound(settings) -> None:
    """4000 x 3000 px (about 195 MiB decoded, gcps-v1): kept under GCPS_REFERENCE_CACHE_BYTES's default."""
    from metrology.captures.references import kept_references
    from metrology.core.geometry.crossed_axes import camera_ray_point, codes_of_points
    from metrology.core.patterns import PATTERN_NAMES, pattern_intensity

    rig = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=4000, height_px=3000)
    x_h, _ = camera_ray_point(rig, rig.column_x_mm(), 0.0, 0.0)
    codes = codes_of_points(rig, x_h, 0.0)
    rows = np.stack([np.round(12 + 200 * pattern_intensity(codes, n)) for n in PATTERN_NAMES]).astype(np.uint8)
    images = np.ascontiguousarray(np.broadcast_to(rows[:, None, :], (11, 3000, 4000)))
    kept = kept_references()
    assert kept.max_bytes == settings.GCPS_REFERENCE_CACHE_BYTES
    kept.clear()
    try:
        reference, hit = kept.get("12mp", lambda: prepare_reference(rig, images))
        assert not hit and reference.shape == (3000, 4000) and reference_nbytes(reference) > 150 * 2**20
        again, hit = kept.get("12mp", lambda: prepare_reference(rig, images))
        assert hit and again is reference
    finally:
        kept.clear()
