"""``gcps measure`` reads the object's stack from its start, before the rig and the codec are known
(metrology/commands/measure.py, ``read_early``), and takes it only where it is what the commit before
read (``read_capture``: a one-camera gcps-v1 stack of the rig's frame size); else it reads the
capture again, with ``read_capture``'s errors and messages."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.commands.common import BadInputError, read_capture
from metrology.commands.measure import is_exposures, read_early, read_object
from metrology.core.codecs.model import gcps_v1_codec
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import write_stack
from metrology.core.patterns import PATTERN_NAMES


def rig(width: int, height: int) -> Rig:
    return Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=width, height_px=height)


@pytest.fixture
def stack(tmp_path):
    frames = np.random.default_rng(0).integers(0, 256, (len(PATTERN_NAMES), 24, 32), dtype=np.uint8)
    write_stack(frames, tmp_path / "obj")
    return tmp_path / "obj", frames


def test_the_early_read_is_the_stack_read_capture_reads(stack):
    path, frames = stack
    model = rig(32, 24)
    early = read_early(str(path))
    assert early is not None
    taken = read_object(early, str(path), None, model, is_exposures(str(path), model))
    assert taken is early.result()  # the early read itself, not a second read
    np.testing.assert_array_equal(taken, frames)
    np.testing.assert_array_equal(taken, read_capture(str(path), None, model, "object"))
    # gcps-v1 named as a codec: the same stack
    codec = gcps_v1_codec(1024, 768, 128)
    assert read_object(early, str(path), codec, model, is_exposures(str(path), model)) is early.result()


def test_another_frame_size_reads_again_with_read_captures_message(stack):
    path, _ = stack
    model = rig(64, 48)
    with pytest.raises(BadInputError) as before:
        read_capture(str(path), None, model, "object")
    with pytest.raises(BadInputError) as now:
        read_object(read_early(str(path)), str(path), None, model, is_exposures(str(path), model))
    assert str(now.value) == str(before.value) and "object stack" in str(now.value)


def test_a_failed_early_read_reads_again_with_read_captures_message(stack):
    path, _ = stack
    (path / "PS_2.png").unlink()
    early = read_early(str(path))
    assert early is not None and early.exception() is not None
    with pytest.raises(BadInputError) as before:
        read_capture(str(path), None, rig(32, 24), "object")
    with pytest.raises(BadInputError) as now:
        read_object(early, str(path), None, rig(32, 24), is_exposures(str(path), rig(32, 24)))
    assert str(now.value) == str(before.value) and "PS_2" in str(now.value)
    assert read_early(str(path / "nothere")) is None
