"""Test capture stacks made from the core's exact model (no simulator needed), zipped in memory."""

from __future__ import annotations

import io
import zipfile

import cv2
import numpy as np

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity
from metrology.core.synthetic import exact_codes

# A small rig with the paper's geometry: fast to decode in tests.
SMALL_RIG = {
    "L_mm": 1022.0,
    "d_mm": 352.0,
    "alpha_rad": 0.332,
    "fw_mm": 500.0,
    "nlp": 128,
    "width_px": 160,
    "height_px": 120,
}


def intensities(rig: Rig, z_mm: float | np.ndarray) -> np.ndarray:
    """Noise-free (11, H, W) float64 intensities, 0..0.9, of a surface at ``z_mm`` (mm) for ``rig``."""
    codes = exact_codes(rig, np.broadcast_to(np.asarray(z_mm, dtype=float), rig.shape))
    return np.stack(
        [
            np.where(np.isnan(codes), 0.0, 0.1 + 0.8 * pattern_intensity(np.nan_to_num(codes), name))
            for name in PATTERN_NAMES
        ]
    )


def render_images(rig: Rig, z_mm: float | np.ndarray, *, bit_depth: int = 8) -> np.ndarray:
    """Noise-free (11, H, W) camera images of a surface at ``z_mm`` (mm) for ``rig``."""
    full = 255 if bit_depth == 8 else 65535
    return np.round(intensities(rig, z_mm) * full).astype(np.uint8 if bit_depth == 8 else np.uint16)


HDR_EXPOSURES_US = {"short": 1000.0, "long": 10000.0}
"""The two exposures of :func:`hdr_members`: the long one saturates the bright half."""


def hdr_members(rig: Rig, z_mm: float | np.ndarray) -> dict[str, bytes]:
    """The files of a 16-bit noise-free multi-exposure capture (docs/exposures.md) of heights ``z_mm``
    on a part whose left half reflects 1 and right half 0.05, exposed 1 and 10 ms: the long
    exposure saturates the left half (its white frame reaches 9 x 65535), the short one sees the
    right half at a twentieth of the left's modulation. Keys: ``exposures.json``, ``short/GC_0.png``..."""
    from metrology.core.io.exposures import Exposure, exposures_json

    base = intensities(rig, z_mm)
    reflectance = np.where(np.arange(rig.shape[1]) < rig.shape[1] // 2, 1.0, 0.05)
    members = {"exposures.json": exposures_json([Exposure(name, us) for name, us in HDR_EXPOSURES_US.items()]).encode()}
    for name, us in HDR_EXPOSURES_US.items():
        images = np.clip(np.round(base * reflectance * (us / 1000.0) * 65535), 0, 65535).astype(np.uint16)
        members.update(
            {f"{name}/{pattern}.png": png(image) for pattern, image in zip(PATTERN_NAMES, images, strict=True)}
        )
    return members


def png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image)
    assert ok
    return data.tobytes()


def zip_bytes(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def stack_zip(images: np.ndarray, names: tuple[str, ...] = PATTERN_NAMES) -> bytes:
    """A zip holding ``images[i]`` as ``names[i] + '.png'``."""
    return zip_bytes({f"{name}.png": png(image) for name, image in zip(names, images, strict=True)})


def plane_zip(rig_values: dict = SMALL_RIG, z_mm: float = 0.0, *, bit_depth: int = 8) -> bytes:
    return stack_zip(render_images(Rig.from_dict(rig_values), z_mm, bit_depth=bit_depth))


def block_heights() -> np.ndarray:
    """SMALL_RIG's heights (mm) of a block 25 mm high on the reference plane."""
    z = np.zeros((SMALL_RIG["height_px"], SMALL_RIG["width_px"]))
    z[30:90, 40:120] = 25.0
    return z
