"""Noise-free stacks of a codec other than gcps-v1 (docs/codecs.md) seen by SMALL_RIG, zipped in memory."""

from __future__ import annotations

import json

import numpy as np

from metrology.core.codecs import codec_from_dict, render_codec
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.synthetic import exact_codes
from tests.app.stacks import SMALL_RIG, png, zip_bytes

PROJ_W, PROJ_H = 1024, 768
CODEC = {
    "codec": "gcps-codec/1",
    "frames": 24,
    "projector": {"width": PROJ_W, "height": PROJ_H},
    "white": [22],
    "black": [23],
    "axes": {
        "u": {
            "phase": [{"frames": list(range(12)), "period": 32.0, "origin": -0.5}],
            "gray": {
                "frames": list(range(12, 17)),
                "word": 32.0,
                "origin": -0.5,
                "inverse_frames": list(range(17, 22)),
            },
        }
    },
}


def codec_images(z_mm: float | np.ndarray, codec: dict = CODEC) -> np.ndarray:
    """Noise-free 16-bit frames of ``codec`` for a surface at ``z_mm`` seen by SMALL_RIG (exact model)."""
    rig = Rig.from_dict(SMALL_RIG)
    codes = exact_codes(rig, np.broadcast_to(np.asarray(z_mm, dtype=float), rig.shape))
    u = codes * (PROJ_W / rig.nlp) - 0.5
    return render_codec(codec_from_dict(codec), u, None)


def codec_zip(images: np.ndarray, codec: dict | None = CODEC, extra: dict[str, bytes] | None = None) -> bytes:
    members = {f"frame{index:02d}.png": png(image) for index, image in enumerate(images)}
    if codec is not None:
        members["codec.json"] = json.dumps(codec).encode()
    members.update(extra or {})
    return zip_bytes(members)
