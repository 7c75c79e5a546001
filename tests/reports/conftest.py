"""For the report tests: a quick stage range (the users, the rig and the media root are tests/conftest.py's)."""

from __future__ import annotations

# Three positions, two repeats: a report in about a second on the 160 x 120 rig.
QUICK = {"z_start_mm": 0.0, "z_stop_mm": 16.0, "z_step_mm": 8.0, "repeats": 2}
