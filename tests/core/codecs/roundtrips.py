"""Shared helpers of the codec round trips: smooth true (u, v) maps, codecs from specs, the check.

Noise-free renders must decode every lit pixel to within ``tol`` projector px of the truth.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metrology.core.codecs import Codec, codec_from_dict, render_codec
from metrology.core.codecs.decode import REASON_SLIP_REPAIRED, decode_codec

PROJ_W, PROJ_H = 256, 192
CAM_H, CAM_W = 72, 100


def truth_maps(
    height: int = CAM_H, width: int = CAM_W, proj_w: int = PROJ_W, proj_h: int = PROJ_H, shadow: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Smooth, slightly curved maps covering the projector, with a shadowed disc (NaN)."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    sx, sy = xx / (width - 1), yy / (height - 1)
    u = -0.45 + (proj_w - 0.1) * (0.97 * sx + 0.03 * sx**2) + 0.6 * np.sin(3 * sy)
    v = -0.45 + (proj_h - 0.1) * (0.96 * sy + 0.04 * sy * sx) + 0.4 * np.cos(2 * sx)
    u = np.clip(u, -0.45, proj_w - 0.55)
    v = np.clip(v, -0.45, proj_h - 0.55)
    if shadow:
        disc = (xx - 0.7 * width) ** 2 + (yy - 0.3 * height) ** 2 < (0.1 * width) ** 2
        u[disc] = np.nan
        v[disc] = np.nan
    return u, v


def axis_spec(
    first: int,
    steps: int | None,
    period: float,
    *,
    bits: int = 0,
    word: float | None = None,
    order: str = "msb_first",
    inverse: bool = False,
    inverted: bool = False,
    shift: int = 1,
    origin: float = -0.5,
    gray_origin: float = -0.5,
    waveform: str = "sine",
) -> tuple[dict[str, Any], int]:
    """An axis of one phase sequence (``steps`` frames, or none) + an optional gray code; frames from ``first``."""
    spec: dict[str, Any] = {}
    f = first
    if steps:
        spec["phase"] = [
            {
                "frames": list(range(f, f + steps)),
                "period": period,
                "shift": shift,
                "origin": origin,
                "waveform": waveform,
            }
        ]
        f += steps
    if bits:
        frames = list(range(f, f + bits))
        f += bits
        inverse_frames = None
        if inverse:
            inverse_frames = list(range(f, f + bits))
            f += bits
        spec["gray"] = {
            "frames": frames,
            "word": word if word is not None else period,
            "order": order,
            "origin": gray_origin,
            "inverse_frames": inverse_frames,
            "inverted": inverted,
        }
    return spec, f


def make_codec(u: dict[str, Any] | None, v: dict[str, Any] | None, frames: int, **extra: Any) -> Codec:
    axes = {name: spec for name, spec in (("u", u), ("v", v)) if spec is not None}
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": frames,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "axes": axes,
            **extra,
        }
    )


def bits_for(word: float, extent: int = PROJ_W) -> int:
    return max(1, math.ceil(math.log2((extent + 1) / word)))


def assert_round_trip(codec: Codec, u: np.ndarray, v: np.ndarray, tol: float = 0.01, **render: Any) -> None:
    images = render_codec(codec, u if "u" in codec.axes else None, v if "v" in codec.axes else None, **render)
    decoded = decode_codec(images, codec)
    for name, truth in (("u", u), ("v", v)):
        if name not in codec.axes:
            assert np.isnan(decoded.uv()[..., 0 if name == "u" else 1]).all()
            continue
        axis = decoded.axes[name]
        lit = np.isfinite(truth)
        valid = axis.valid
        assert not (valid & ~lit).any(), f"{name}: decoded pixels in the shadow"
        error = np.abs(axis.coordinate[valid] - truth[valid])
        assert error.max() < tol, f"{name}: max error {error.max():.4g} px"
        assert valid[lit].mean() > 0.999, f"{name}: only {valid[lit].mean():.4f} of the lit pixels decoded"
        assert axis.slips_repaired == 0 and not (axis.reason == REASON_SLIP_REPAIRED).any()


def affine_truth(
    height: int, width: int, supersample: int, offset: float, slope: float, tilt: float
) -> tuple[np.ndarray, np.ndarray]:
    """``u = offset + slope x + tilt y`` at the sub-pixel centres of an ``supersample``-times finer grid
    (what the renderer samples) and at the pixel centres (the truth a decoder should find: the
    camera blur and the area average of a linear map are unbiased)."""
    s = supersample
    yy, xx = np.mgrid[0 : height * s, 0 : width * s].astype(np.float64)
    xs, ys = (xx + 0.5) / s - 0.5, (yy + 0.5) / s - 0.5
    fine = offset + slope * xs + tilt * ys
    centre = offset + slope * np.arange(width)[None, :] + tilt * np.arange(height)[:, None]
    return fine, centre


def decode_inner(images: np.ndarray, codec: Codec, axis_name: str = "u", border: int = 3) -> tuple[Any, np.ndarray]:
    """Decode ``images``; the axis's decoding and its valid pixels at least ``border`` px from the
    image edge, of which more than 99.9 % must be decoded."""
    axis = decode_codec(images, codec).axes[axis_name]
    inner = np.zeros(axis.coordinate.shape, bool)
    inner[border:-border, border:-border] = True
    valid = axis.valid & inner
    assert valid[inner].mean() > 0.999, valid[inner].mean()
    return axis, valid


def multilevel_codec(
    levels: int,
    digits: int,
    word: float,
    *,
    period: float | None = 16.0,
    white_black: bool = True,
    order: str = "msb_first",
    axis: str = "u",
    **gray: Any,
) -> Codec:
    """One axis: a ``levels``-level gray code of ``digits`` frames, an optional 8-step phase, white/black."""
    spec: dict[str, Any] = {
        "gray": {"frames": list(range(digits)), "word": word, "origin": -0.5, "levels": levels, "order": order, **gray}
    }
    n = digits
    if period is not None:
        spec["phase"] = [{"frames": list(range(n, n + 8)), "period": period, "origin": -0.5}]
        n += 8
    extra: dict[str, Any] = {}
    if white_black:
        extra = {"white": [n], "black": [n + 1]}
        n += 2
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": n,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "axes": {axis: spec},
            **extra,
        }
    )
