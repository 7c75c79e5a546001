"""Ideal crossed-axes capture stacks rendered from exact codes, for the decoding and measurement tests."""

import numpy as np

from metrology.core.geometry.crossed_axes import Rig, codes_from_abscissa
from metrology.core.patterns import PATTERN_NAMES, pattern_intensity

RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=320, height_px=24)


def plane_codes(rig: Rig, z_mm: float) -> np.ndarray:
    """Exact light codes seen by every pixel when a plane at height z_mm is in front of R."""
    x_a = np.broadcast_to(rig.column_x_mm(), rig.shape)
    x_h = rig.d_mm + (1 - z_mm / rig.L_mm) * (x_a - rig.d_mm)
    return codes_from_abscissa(rig, x_h * rig.L_mm / (rig.L_mm - z_mm))


def ideal_stack(codes: np.ndarray, bits: int = 16, noise: float = 0.0, seed: int = 0, nlp: int = 128) -> np.ndarray:
    full = 2**bits - 1
    lit = (codes >= 0) & (codes <= nlp)
    images = np.stack([0.05 + 0.8 * pattern_intensity(codes, name) * lit for name in PATTERN_NAMES]) * full
    images += np.random.default_rng(seed).normal(0, noise, images.shape)
    return np.clip(np.round(images), 0, full).astype(np.uint16 if bits == 16 else np.uint8)
