"""The pairs map of a stereo measurement (docs/stereo.md): which pairs of devices measured each point."""

from __future__ import annotations

import numpy.typing as npt
import plotly.graph_objects as go

from metrology.core.geometry.stereo_fusion import pair_combination
from metrology.figures.capture import category_figure

PAIRS_COLOURS = ("#d0d0d0", "#3b528b", "#f89540", "#21918c", "#cc4778", "#5ec962", "#7e03a8", "#fde725")
"""Colours of the pairs-map values 0 (not measured) to 7 (every pair)."""


def pairs_figure(pairs: npt.ArrayLike, title: str = "Pairs that measured each point") -> go.Figure:
    """Categorical heatmap of a stereo measurement's pairs map (docs/stereo.md): ``pairs`` (H, W)
    uint8 bits (:data:`~metrology.core.geometry.stereo_fusion.PAIR_NAMES`), 0 where not measured;
    the pixels of each combination in the legend."""
    categories = {value: (pair_combination(value), PAIRS_COLOURS[value]) for value in range(8)}
    return category_figure(pairs, categories, title, "pairs")
