"""The crossed-axes rig of the command-line tests: the paper's geometry on a 320 x 240 camera."""

from metrology.core.geometry.crossed_axes import Rig

RIG = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=320, height_px=240)
