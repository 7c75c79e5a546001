"""The pipeline's one measure on a pinhole rig (shared by `gcps measure --rig PINHOLE.json` and the job)."""

from __future__ import annotations

import numpy as np
import pytest

from metrology.core.codecs import codec_from_dict, render_codec
from metrology.pipeline.measure import MeasureOptions, measure
from tests.pinhole_stacks import CODEC, RIG, cast_scene


def test_pipeline_points_depth_heights_and_options():
    codec = codec_from_dict(CODEC)
    truth = cast_scene("sphere")
    plate = cast_scene("plane", z_mm=0.0)
    obj, ref = render_codec(codec, truth.u, None), render_codec(codec, plate.u, None)
    depth = measure(RIG, None, obj, codec=codec)
    ok = np.isfinite(depth.z_mm)
    assert ok.mean() > 0.5 and depth.measurement.z_meaning == "depth (camera Z)" and depth.sigma_mm is None
    assert depth.statistics()["z"] == "depth (camera Z)" and depth.statistics()["model"] == "pinhole"
    err = np.linalg.norm(depth.points_mm()[ok] - truth.points_mm[ok], axis=-1)
    assert np.mean(err < 1e-3) > 0.999  # noise-free 16-bit: within 1 um
    heights = measure(RIG, ref, obj, MeasureOptions(sigma=True), codec=codec)
    assert heights.measurement.z_meaning == "height above the reference plane"
    assert np.mean(np.abs(heights.z_mm[ok] - (600.0 - truth.points_mm[..., 2][ok])) < 1e-3) > 0.999
    assert heights.sigma_mm is not None and heights.statistics()["sigma_mm_median"] is not None
    data = heights.to_dict()
    assert data["options"]["sigma"] is True and data["reference_plane"]["points"] > 0
    assert MeasureOptions.from_dict(data["options"]) == heights.options
    for bad, words in (
        ({"triangulate": "w"}, "triangulate must be one of"),
        ({"method": "ray"}, "method must be one of"),
        ({"max_sigma_mm": 0}, "max_sigma_mm must be a positive number"),
        ({"sigma": 1}, "sigma must be true or false"),
        ({"sigmas": True}, "unknown measure option"),
    ):
        with pytest.raises(ValueError, match=words):
            MeasureOptions.from_dict(bad)
    with pytest.raises(ValueError, match="frames are 80x120 px but the rig's camera is 160x120 px"):
        measure(RIG, None, np.ascontiguousarray(obj[:, :, :80]), codec=codec)
