"""Shared by the acquisition tests: the repository's root (the agent's and the server's working
folder), how Chromium shows the projector page, and a phase + gray codec of any axes."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Chromium's arguments for the projector page (a fixed sRGB colour profile; tests/browser.py has the pages').
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--force-color-profile=srgb",
]
PROJ_W, PROJ_H = 1024, 768


def phase_gray_codec(axes: tuple[str, ...], steps: int = 4) -> dict:
    """``steps``-step phase (period 32 px) + 5-bit gray code (word 32 px) with inverse frames, per axis,
    then one white and one black frame: ``len(axes) * (steps + 10) + 2`` frames."""
    coded: dict[str, dict] = {}
    start = 0
    for axis in axes:
        phase = list(range(start, start + steps))
        gray = list(range(start + steps, start + steps + 5))
        inverse = list(range(start + steps + 5, start + steps + 10))
        coded[axis] = {
            "phase": [{"frames": phase, "period": 32.0, "origin": -0.5}],
            "gray": {"frames": gray, "word": 32.0, "origin": -0.5, "inverse_frames": inverse},
        }
        start += steps + 10
    return {
        "codec": "gcps-codec/1",
        "frames": start + 2,
        "projector": {"width": PROJ_W, "height": PROJ_H},
        "white": [start],
        "black": [start + 1],
        "axes": coded,
    }
