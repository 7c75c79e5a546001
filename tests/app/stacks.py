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


def render_images(rig: Rig, z_mm: float | np.ndarray, *, bit_depth: int = 8) -> np.ndarray:
    """Noise-free (11, H, W) camera images of a surface at ``z_mm`` (mm) for ``rig``."""
    codes = exact_codes(rig, np.broadcast_to(np.asarray(z_mm, dtype=float), rig.shape))
    full = 255 if bit_depth == 8 else 65535
    images = []
    for name in PATTERN_NAMES:
        intensity = np.where(np.isnan(codes), 0.0, 0.1 + 0.8 * pattern_intensity(np.nan_to_num(codes), name))
        images.append(np.round(intensity * full))
    return np.stack(images).astype(np.uint8 if bit_depth == 8 else np.uint16)


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
