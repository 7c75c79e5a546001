"""The example codecs of the new families, through the virtual rig (``render_capture``, a pinhole rig).

``examples/multilevel-gray.codec.json`` (4-level gray codes + 8-step phases, both axes) and
``examples/three-frequency.codec.json`` (64/58/53 and 48/44/41 periods, beats of beats, no gray
code) rendered noise-free (16-bit) on a sphere decode to the true (u, v) within 0.01 projector
px wherever the point is lit and away from depth edges.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from metrology.core.codecs import read_codec
from metrology.core.codecs.decode import decode_codec
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import ScenePlacement, render_capture

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
CAMERA = PinholeCamera(128, 96, ((320.0, 0.0, 63.5), (0.0, 321.0, 47.5), (0.0, 0.0, 1.0)), (-0.1, 0.03, 0.0, 0.0, 0.0))
PROJECTOR = PinholeProjector(1280, 800, ((1500.0, 0.0, 640.3), (0.0, 1501.0, 399.6), (0.0, 0.0, 1.0)), (0.0,) * 5)
Z0 = 600.0


@pytest.mark.parametrize("name", ["multilevel-gray.codec.json", "three-frequency.codec.json"])
def test_example_codec_round_trips_through_the_virtual_rig(name: str) -> None:
    codec = read_codec(EXAMPLES / name)
    rig = look_at_rig(CAMERA, PROJECTOR, (-250.0, 10.0, 20.0), (0.0, 0.0, Z0))
    truth = render_capture(rig, make_scene("sphere"), codec, placement=ScenePlacement.facing_camera(Z0))
    decoded = decode_codec(truth.images, codec)
    for axis_name, true in (("u", truth.u), ("v", truth.v)):
        axis = decoded.axes[axis_name]
        judged = truth.lit & ~truth.edges
        assert judged.mean() > 0.5
        assert axis.valid[judged].mean() > 0.999
        error = np.abs(axis.coordinate[judged & axis.valid] - true[judged & axis.valid])
        assert error.max() < 0.01, (axis_name, error.max())
