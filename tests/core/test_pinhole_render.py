"""Full chain through a distorted pinhole rig: codec render -> decode -> triangulate (noise-free 16-bit).

Needs the codec package (metrology.core.codecs); skipped, saying so, where it is absent.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metrology.core.geometry.base import triangulate_frame
from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector
from metrology.core.scenes import make_scene
from metrology.core.simulate_pinhole import PlacedScene, cast_truth, look_at_rig

codecs = pytest.importorskip("metrology.core.codecs", reason="the codec package (issue 11) is not in this tree")

PROJ_W, PROJ_H = 1280, 800
CAMERA = PinholeCamera(
    240, 180, ((600.0, 0.0, 119.5), (0.0, 601.0, 89.5), (0.0, 0.0, 1.0)), (-0.12, 0.04, 0.0008, -0.0006, 0.01)
)
PROJECTOR = PinholeProjector(
    PROJ_W, PROJ_H, ((1500.0, 0.0, 640.3), (0.0, 1501.0, 399.6), (0.0, 0.0, 1.0)), (0.05, -0.03, 0.0004, 0.0003, 0.0)
)
BASELINES = {"u": (-250.0, 10.0, 20.0), "v": (8.0, -250.0, 20.0)}
Z0 = 600.0


def _axis(first: int, extent: int) -> tuple[dict[str, Any], int]:
    """8-step sinusoid of period 16 projector px, gray code of 16-px words (MSB first)."""
    bits = math.ceil(math.log2((extent + 1) / 16))
    phase = {"frames": list(range(first, first + 8)), "period": 16.0, "shift": 1, "origin": -0.5, "waveform": "sine"}
    gray = {
        "frames": list(range(first + 8, first + 8 + bits)),
        "word": 16.0,
        "order": "msb_first",
        "origin": -0.5,
        "inverse_frames": None,
        "inverted": False,
    }
    return {"phase": [phase], "gray": gray}, first + 8 + bits


def _codec(axis: str) -> Any:
    spec, n = _axis(0, PROJ_W if axis == "u" else PROJ_H)
    return codecs.codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": n + 2,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "white": [n],
            "black": [n + 1],
            "axes": {axis: spec},
        }
    )


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["plane", "sphere", "staircase"])
@pytest.mark.parametrize("axis", ["u", "v"])
def test_render_decode_triangulate(scene: str, axis: str) -> None:
    from metrology.core.codecs.decode import decode_codec

    rig = look_at_rig(CAMERA, PROJECTOR, BASELINES[axis], (0.0, 0.0, Z0))
    truth = cast_truth(rig, PlacedScene(make_scene(scene), Z0))
    codec = _codec(axis)
    images = codecs.render_codec(codec, truth.u if axis == "u" else None, truth.v if axis == "v" else None)
    decoded = decode_codec(images, codec)
    coord = decoded.axes[axis].coordinate
    prep = rig.prepare(projector_size=(PROJ_W, PROJ_H))
    assert prep.axis == axis
    res = triangulate_frame(prep, coord if axis == "u" else None, coord if axis == "v" else None, heights=False)
    assert res.points_mm is not None
    valid = decoded.axes[axis].valid & truth.valid
    assert valid.mean() > 0.5
    err = np.linalg.norm(res.points_mm.astype(np.float64) - truth.points_mm, axis=-1)[valid]
    assert np.all(np.isfinite(err))
    coord_err = np.abs(coord[valid] - (truth.u if axis == "u" else truth.v)[valid])
    print(f"{scene} {axis}: {valid.sum()} px, coordinate error max {coord_err.max():.2e}, point error max "
          f"{err.max() * 1e3:.3f} um, median {np.median(err) * 1e3:.3f} um")  # fmt: skip
    assert err.max() < 1e-3
