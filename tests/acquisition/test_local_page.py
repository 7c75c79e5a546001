"""``gcps capture --projector page``: the command serves the projector page itself (no application);
headless Chromium shows it; the virtual camera renders what the page reports; the stack is the
direct simulation's."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import read_stack
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, render_stack
from tests.acquisition.helpers import CHROMIUM_ARGS, ROOT
from tests.app.stacks import SMALL_RIG
from tests.browser import CHROMIUM

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is not installed"),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_gcps_capture_serves_the_projector_page(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api")
    rig_path, out = tmp_path / "rig.json", tmp_path / "plane.zip"
    rig_path.write_text(json.dumps(SMALL_RIG))
    command = [
        sys.executable, "-c", "import sys; from metrology.cli import main; sys.exit(main())",
        "capture", "--camera", "virtual", "--projector", "page", "--port", str(free_port()), "--rig", str(rig_path),
        "--scene", '{"name": "plane", "z_mm": 20}', "--sim-options", '{"bit_depth": 8, "noise_grey": 1.0}',
        "--settle", "0.02", "--exposure", "10", "--inject-faults", "latency=5,saturate=9", "--out", str(out),
    ]  # fmt: skip
    process = subprocess.Popen(
        command,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = process.stdout.readline()
        assert line.startswith("projector page: http://127.0.0.1:"), line + process.stderr.read()
        url = line.split()[2]
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1024, "height": 768})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(url)
            out_text, err = process.communicate(timeout=120)
            browser.close()
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, err
    assert errors == []
    assert json.loads(out_text)["regrabs"] > 0
    rig = Rig.from_dict(SMALL_RIG)
    direct = render_stack(rig, make_scene("plane", rig=rig, z_mm=20.0), SimulationOptions(bit_depth=8, noise_grey=1.0))
    np.testing.assert_array_equal(read_stack(out, rig=rig).images, direct.images)
